"""Declared model parameters (brdftab.params) and the values they accept: numpy scalars and
arrays accepted, complex and non-finite values refused, spectral terms kept to their common
wavelength range; the module itself imports nothing of brdftab's models."""

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from brdftab import models
from brdftab.errors import ParameterError
from brdftab.geometry import sph_to_vec

ROOT = Path(__file__).resolve().parents[1]


def test_params_module_imports_nothing_of_brdf():
    tree = ast.parse((ROOT / "brdftab" / "params.py").read_text())
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert not [n for n in names if "brdf" in n.split(".")[-1] and n != "brdftab"], names


@pytest.mark.parametrize("albedo", [np.array(0.5), np.float32(0.5), np.array([0.5])])
def test_numpy_values_are_accepted(albedo):
    assert models.create("lambert", albedo=albedo).eval(sph_to_vec(0.1, 0), sph_to_vec(0.2, 1))[0] == \
        pytest.approx(0.5 / np.pi)


@pytest.mark.parametrize("albedo", [np.complex128(0.5), [0.5, float("nan")], {"wavelengths_nm": [400, float("inf")],
                                                                           "values": [0.1, 0.2]}])
def test_bad_values_are_refused(albedo):
    with pytest.raises(ParameterError):
        models.create("lambert", albedo=albedo)


def test_spectral_terms_keep_their_common_range():
    m = models.create("microfacet", alpha=0.3, fresnel="conductor",
                      n={"wavelengths_nm": [400, 550, 700], "values": [1.0, 1.1, 1.2]},
                      k={"wavelengths_nm": [300, 800], "values": [2.0, 2.0]})
    assert list(m.wavelengths) == [400, 550, 700]
    with pytest.raises(ParameterError):
        models.create("microfacet", alpha=0.3, fresnel="conductor",
                      n={"wavelengths_nm": [400, 500], "values": [1.0, 1.0]},
                      k={"wavelengths_nm": [600, 700], "values": [2.0, 2.0]})


HUGE = 9 * 10 ** 400  # an integer TOML and Python hold but float64 cannot


@pytest.mark.parametrize("name, kwargs, key", [
    ("microfacet", {"alpha": HUGE}, "alpha"),                                   # float
    ("pyramid-microfacet", {"max_bounces": HUGE}, "max_bounces"),               # int
    ("pyramid-microfacet", {"max_bounces": -HUGE}, "max_bounces"),
    ("pyramid-microfacet", {"phi0": HUGE}, "phi0"),                             # float, an angle
    ("lambert", {"albedo": [0.5, HUGE, 0.5]}, "albedo"),                        # channel
])
def test_integers_beyond_float_range_are_a_parameter_error(name, kwargs, key):
    with pytest.raises(ParameterError) as info:
        models.create(name, **kwargs)
    assert info.value.key == key and "expected" in info.value.detail, str(info.value)
    assert len(str(info.value)) < 300  # the value is shortened, not printed in full


def test_float_lists_refuse_integers_beyond_float_range():
    from brdftab.params import Param

    p = Param("xs", "floats", "numbers", minimum=0.0)
    assert p.convert([1, 2]) == (1.0, 2.0)
    with pytest.raises(ParameterError, match="expected finite numbers >= 0"):
        p.convert([1, HUGE])


def test_toml_value_reads_back_the_same():
    """The one TOML writer of spec values (fitted specs, sweep members): tomllib reads back what
    it wrote, bit for bit for floats; a fitted spec refuses non-finite values."""
    import tomllib

    from brdftab.params import toml_value

    values = [0.1, 1e-300, 2.0 ** -1074, 3, True, 'quote " backslash \\ é', [1, 2.5, False],
              {"wavelengths_nm": [400.0, 700.0], "values": [0.1, 0.2]}, {"a b": "c"}, float("inf")]
    for v in values:
        assert tomllib.loads("x = " + toml_value(v))["x"] == v, v
    assert math.isnan(tomllib.loads("x = " + toml_value(float("nan")))["x"])
    with pytest.raises(ValueError, match="non-finite"):
        toml_value([1.0, float("nan")], finite=True)
