"""The spec -> table -> validate -> write pipeline: refusal of invalid tables."""

import numpy as np
import pytest

from brdftab.brdf import BRDF
from brdftab.errors import ValidationError
from brdftab.grids import RusinkiewiczGrid
from brdftab.pipeline import run
from brdftab.spec import Output, Spec


class Broken(BRDF):
    """Returns NaN where wi is steeper than 45° and −1 elsewhere in a small patch."""

    name = "broken"

    def _eval(self, wi, wo, lam, n):
        f = np.full((wi.shape[0], n), 0.1)
        f[wi[:, 2] > np.cos(np.radians(45))] = np.nan
        f[(wo[:, 2] < 0.2)] = -1.0
        return f


def make_spec(tmp_path, allow=False):
    return Spec(path=tmp_path / "s.toml", sha256="", model=Broken(), grid=RusinkiewiczGrid(6, 6, 6),
                wavelengths=None, outputs=[Output(tmp_path / "x.nc", "netcdf", {})],
                validation={"allow_invalid": allow}, raw={"output": [{"path": "x.nc"}]})


def test_invalid_table_is_refused_with_counts(tmp_path):
    with pytest.raises(ValidationError) as exc:
        run(make_spec(tmp_path), progress=False)
    msg = str(exc.value)
    assert "finite" in msg and "NaN" in msg and "negative" in msg and "of 216 samples" in msg
    assert "lowest -1 sr-1" in msg
    assert list(tmp_path.iterdir()) == []


def test_invalid_table_written_when_allowed(tmp_path):
    result = run(make_spec(tmp_path), allow_invalid=True, progress=False)
    assert not result.report.passed
    assert (tmp_path / "x.nc").exists()
    result = run(make_spec(tmp_path, allow=True), overwrite=True, progress=False)
    assert not result.report.passed
