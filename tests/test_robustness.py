"""Edge cases: the horizon, azimuth wrapping, signals during writes, odd inputs."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

import brdftab
from brdftab import models
from brdftab._signals import held_signals
from brdftab.errors import BrdftabError, FormatError, ParameterError
from brdftab.geometry import sph_to_vec
from brdftab.grids import RusinkiewiczGrid, SphericalGrid, grid_from_config
from brdftab.models.fresnel import fresnel_conductor, fresnel_dielectric
from brdftab.table import tabulate

GGX = models.create("microfacet", alpha=0.3)


# --- the horizon ----------------------------------------------------------------------------
@pytest.mark.parametrize("shadowing", ["none", "v-groove", "smith-height-correlated"])
def test_exactly_ninety_degrees_is_the_horizon(shadowing):
    m = models.create("microfacet", alpha=0.3, shadowing=shadowing)
    at90 = sph_to_vec(np.pi / 2, 0.0)
    assert at90[2] > 0  # cos(π/2) is 6e-17 in floating point ...
    assert np.all(m.eval(at90, sph_to_vec(0.5, 1.0)) == 0)  # ... but it is the horizon
    assert np.all(m.eval(sph_to_vec(0.5, 1.0), at90) == 0)
    assert np.all(models.create("lambert").eval(at90, at90) == 0)


def test_table_with_horizon_nodes_interpolates_sanely():
    m = models.create("microfacet", alpha=0.3, shadowing="v-groove")
    g = SphericalGrid(np.radians([80, 85, 90]), [0.0], np.radians([80, 85, 90]), [np.pi])
    t = tabulate(m, g, progress=False)
    assert np.all(np.isfinite(t.values)) and t.values.max() < 1e3
    wi, wo = sph_to_vec(np.radians(87.5), 0.0), sph_to_vec(np.radians(87.5), np.pi)
    assert t.eval(wi, wo)[0] < 10 * m.eval(wi, wo)[0]


# --- azimuth axes of spherical grids ----------------------------------------------------------
def test_partial_phi_axis_returns_its_own_nodes():
    m = models.create("microfacet", alpha_x=0.2, alpha_y=0.5)
    g = SphericalGrid(np.radians([30]), np.radians([10]), np.radians([20, 40]), np.radians([200, 220, 240]))
    t = tabulate(m, g, progress=False)
    wi, wo = g.directions()
    assert np.array_equal(t.eval(wi, wo), t.values.reshape(-1, 1))
    # queries in the uncovered arc go to the nearer end node
    g_ax = g.axes[3]
    assert g_ax.fractional_index(np.radians([250, 180, 0, 190])).tolist() == [2, 0, 2, 0]  # 0° is 120° from 240°
    assert g_ax.fractional_index(np.radians([-100, -140])).tolist() == [2, 1]  # 260° and 220°


def test_zero_to_360_inclusive_is_one_full_periodic_axis():
    g = grid_from_config({"type": "spherical", "theta_i_deg": [30], "phi_i_deg": [0], "theta_o_deg": [30, 40],
                          "phi_o_deg": {"start": 0, "stop": 360, "step": 30}})
    ax = g.axes[3]
    assert len(ax) == 12 and ax.period == pytest.approx(2 * np.pi)
    m = models.create("sum", terms=[models.create("lambert", albedo=0.3), models.create("microfacet", alpha=0.4)])
    t = tabulate(m, g, progress=False)
    wi, wo = sph_to_vec(np.radians(30), 0.0), sph_to_vec(np.radians(30), np.radians(210))
    assert t.eval(wi, wo)[0] == pytest.approx(m.eval(wi, wo)[0], rel=0.05)


def test_isotropic_table_rotates_phi_i_outside_its_nodes():
    m = models.create("lambert", albedo=0.5)
    m2 = models.create("sum", terms=[m, GGX])
    g = SphericalGrid(np.radians([20, 40]), np.radians([0, 10, 20]), np.radians(np.arange(0, 90, 5)),
                      np.radians(np.arange(0, 360, 10)))
    t = tabulate(m2, g, progress=False)
    wi, wo = sph_to_vec(np.radians(40), np.radians(100)), sph_to_vec(np.radians(40), np.radians(280))
    # φi = 100° is not covered; rotated onto φi = 0 it is the mirror configuration, a node
    assert t.eval(wi, wo)[0] == pytest.approx(m2.eval(wi, wo)[0], rel=1e-9)


# --- signals during a write ---------------------------------------------------------------------
def test_deferred_signals_hold_sigint_until_the_block_ends():
    reached_end = False
    with pytest.raises(KeyboardInterrupt):
        with held_signals():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            reached_end = True
    assert reached_end


SLOW_WRITER = textwrap.dedent("""
    import sys, time
    from brdftab import formats
    from brdftab.cli import main

    def slow(table, path, **kw):
        with open(path, "wb") as fh:
            fh.write(b"partial")
            fh.flush()
            time.sleep(3)
            fh.write(b" and the rest")

    fmt = formats.FileFormat(name="slow", extensions=(".slow",), description="test", read=None, write=slow)
    formats.register(fmt)
    main(["tabulate", sys.argv[1]], prog_name="brdftab")
""")


def test_sigterm_while_writing_removes_the_temporary_and_exits(tmp_path):
    (tmp_path / "slow.py").write_text(SLOW_WRITER)
    (tmp_path / "s.toml").write_text('[model]\nname = "lambert"\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\n'
                                     'n_theta_d = 3\nn_phi_d = 3\n[[output]]\npath = "x.slow"\n')
    proc = subprocess.Popen([sys.executable, "slow.py", "s.toml"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 30
    while not any(".partial-" in p.name for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.time() < deadline, "the writer never started"
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 143, err  # 128 + SIGTERM
    # this writer reports no steps, so the run says it finishes the write before it stops
    assert err.splitlines() == ["brdftab: finishing the write of x.slow before stopping...",
                                "brdftab: terminated; no output written"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml", "slow.py"]


# --- odd inputs ----------------------------------------------------------------------------------
def test_conductor_fresnel_index_matched_is_zero_not_negative():
    c = np.linspace(0, 1, 10001)
    f = fresnel_conductor(c, 1.0, 0.0)
    assert np.all(np.isfinite(f)) and np.all(f >= 0) and f[1:].max() < 1e-12
    assert f[0] == 1.0  # exactly grazing
    d = fresnel_dielectric(c, 1.0)
    assert np.all(np.isfinite(d)) and d[1:].max() < 1e-12


def test_spectral_terms_keep_their_common_range():
    m = models.create("microfacet", alpha=0.3, fresnel="conductor",
                      n={"wavelengths_nm": [400, 550, 700], "values": [1.0, 1.1, 1.2]},
                      k={"wavelengths_nm": [300, 800], "values": [2.0, 2.0]})
    assert list(m.wavelengths) == [400, 550, 700]
    with pytest.raises(ParameterError):
        models.create("microfacet", alpha=0.3, fresnel="conductor",
                      n={"wavelengths_nm": [400, 500], "values": [1.0, 1.0]},
                      k={"wavelengths_nm": [600, 700], "values": [2.0, 2.0]})


@pytest.mark.parametrize("albedo", [np.array(0.5), np.float32(0.5), np.array([0.5])])
def test_numpy_values_are_accepted(albedo):
    assert models.create("lambert", albedo=albedo).eval(sph_to_vec(0.1, 0), sph_to_vec(0.2, 1))[0] == \
        pytest.approx(0.5 / np.pi)


@pytest.mark.parametrize("albedo", [np.complex128(0.5), [0.5, float("nan")], {"wavelengths_nm": [400, float("inf")],
                                                                           "values": [0.1, 0.2]}])
def test_bad_values_are_refused(albedo):
    with pytest.raises(ParameterError):
        models.create("lambert", albedo=albedo)


def test_unsorted_table_wavelengths_are_refused():
    m = models.create("lambert", albedo={"wavelengths_nm": [400, 700], "values": [0.1, 0.2]})
    with pytest.raises(ParameterError, match="increase"):
        tabulate(m, RusinkiewiczGrid(2, 2, 2), wavelengths=[700, 400, 550], progress=False)


def test_output_that_is_a_folder_or_duplicate_is_refused(tmp_path):
    (tmp_path / "out.nc").mkdir()
    with pytest.raises(BrdftabError, match="is a folder"):
        brdftab.save(GGX, tmp_path / "out.nc", grid=RusinkiewiczGrid(2, 2, 2))
    from brdftab.pipeline import run
    from brdftab.spec import load_spec

    (tmp_path / "sub").mkdir()
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "lambert"\n[grid]\ntype = "rusinkiewicz"\nn_theta_h = 2\nn_theta_d = 2\n'
                    'n_phi_d = 2\n[[output]]\npath = "a.nc"\n[[output]]\npath = "sub/../a.nc"\n')
    with pytest.raises(BrdftabError, match="same file"):
        run(load_spec(spec), progress=False)
    assert not (tmp_path / "a.nc").exists()


def test_non_numeric_table_variable_is_refused(tmp_path):
    t = tabulate(GGX, RusinkiewiczGrid(2, 2, 2), progress=False)
    ds = t.ds.copy()
    ds["brdf"] = ds["brdf"].astype(str)
    ds.to_netcdf(tmp_path / "s.nc")
    with pytest.raises(FormatError, match="numeric"):
        brdftab.open(tmp_path / "s.nc")


def test_table_larger_than_memory_is_refused_before_allocating():
    g = RusinkiewiczGrid(1_000_000, 1_000_000, 1_000_000)
    with pytest.raises(BrdftabError, match="GiB"):
        tabulate(GGX, g, progress=False)
