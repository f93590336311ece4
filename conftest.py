"""pytest settings shared by the tests and the doctests of brdftab/ (both test paths)."""

import numpy as np
import pytest

_PRINT_OPTIONS = np.get_printoptions()


@pytest.fixture(autouse=True)
def _numpy_print_options():
    """Every test and doctest starts with numpy's default print options: a test that imports
    colour-science directly switches the process to numpy 1.13's legacy printing, which would
    change how the doctests' arrays print (brdftab itself imports it keeping the options)."""
    np.set_printoptions(**_PRINT_OPTIONS)
    yield
