"""The BRDF protocol (brdftab.brdf): one input rule for every BRDF, model or table — θ = 90°
exactly is the horizon, a non-finite direction gives NaN (never 0), and directions are
normalized on entry (a zero vector is an error)."""

import numpy as np
import pytest

from brdftab import models
from brdftab.errors import ParameterError
from brdftab.geometry import sph_to_vec
from brdftab.grids import merl_grid
from brdftab.table import tabulate

GGX = models.create("microfacet", alpha=0.3)


def sph(theta_deg, phi_deg):
    return sph_to_vec(np.radians(theta_deg), np.radians(phi_deg))


# -- the horizon -------------------------------------------------------------------------------

@pytest.mark.parametrize("shadowing", ["none", "v-groove", "smith-height-correlated"])
def test_exactly_ninety_degrees_is_the_horizon(shadowing):
    m = models.create("microfacet", alpha=0.3, shadowing=shadowing)
    at90 = sph_to_vec(np.pi / 2, 0.0)
    assert at90[2] > 0  # cos(π/2) is 6e-17 in floating point ...
    assert np.all(m.eval(at90, sph_to_vec(0.5, 1.0)) == 0)  # ... but it is the horizon
    assert np.all(m.eval(sph_to_vec(0.5, 1.0), at90) == 0)
    assert np.all(models.create("lambert").eval(at90, at90) == 0)


# -- NaN and non-unit directions -----------------------------------------------------------------

def test_nan_in_gives_nan_out_for_model_and_table():
    t = tabulate(GGX, merl_grid(), progress=False)
    for b in (GGX, t):
        assert np.isnan(b.eval([0.1, 0.2, np.nan], [0, 0, 1])).all()
        assert np.isnan(b.eval([np.nan, 0.2, 0.9], [0, 0, 1])).all()
        assert np.isnan(b.eval([0, 0, 1], [np.inf, 0, 1])).all()
        with pytest.raises(ParameterError, match="zero length"):
            b.eval([0, 0, 0], [0, 0, 1])


def test_directions_are_normalized_on_entry():
    t = tabulate(GGX, merl_grid(), progress=False)
    w1, w2 = sph(35, 10), sph(50, 200)
    for b in (GGX, t):
        assert b.eval(2 * w1, 0.3 * w2) == pytest.approx(b.eval(w1, w2), rel=1e-12)
    assert t.eval(2 * w1, w2) == pytest.approx(GGX.eval(w1, w2), rel=5e-3)


def test_wavelengths_on_an_rgb_brdf_are_refused_by_model_and_table_alike():
    """An RGB BRDF has no spectrum: eval(wi, wo, [550]) is the same ParameterError for the model
    and for a table of it (a grey one broadcasts, both alike)."""
    import brdftab
    from brdftab.errors import ParameterError
    from brdftab.grids import RusinkiewiczGrid

    wi, wo = [0.3, 0.0, 0.95], [-0.3, 0.1, 0.95]
    for albedo in ([0.2, 0.5, 0.8], 0.5):
        model = brdftab.models.create("lambert", albedo=albedo)
        table = brdftab.tabulate(model, RusinkiewiczGrid(4, 4, 8), progress=False)
        if np.ndim(albedo):
            messages = []
            for brdf in (model, table):
                with pytest.raises(ParameterError) as info:
                    brdf.eval(wi, wo, [550])
                messages.append(str(info.value))
            assert messages[0] == messages[1] and "not a spectrum" in messages[0]
        else:
            assert np.allclose(model.eval(wi, wo, [550, 650]), table.eval(wi, wo, [550, 650]), rtol=1e-12)
            assert np.allclose(model.eval(wi, wo, [550, 650]), 0.5 / np.pi, rtol=1e-12)
