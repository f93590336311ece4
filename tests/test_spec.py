"""Spec files that are valid: nesting, spectral sampling, grids, paths, a byte-order mark."""

import json

import numpy as np
import pytest

import brdftab
from brdftab.pipeline import run
from brdftab.spec import load_spec
from _cli import spec as _spec, cli as _cli


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_sum_of_terms_and_scale(tmp_path):
    p = write(tmp_path, """
[model]
name = "sum"
[[model.terms]]
name = "lambert"
albedo = [0.1, 0.2, 0.3]
[[model.terms]]
name = "scale"
factor = 0.5
[model.terms.term]
name = "microfacet"
distribution = "beckmann"
alpha = 0.2
fresnel = "dielectric"
n = 1.5
[grid]
type = "merl"
[[output]]
path = "out/a.nc"
""")
    spec = load_spec(p)
    m = spec.model
    assert m.name == "sum" and m.channels == ("R", "G", "B")
    ref = brdftab.models.create("sum", terms=[
        brdftab.models.create("lambert", albedo=[0.1, 0.2, 0.3]),
        brdftab.models.create("scale", factor=0.5, term=brdftab.models.create(
            "microfacet", distribution="beckmann", alpha=0.2, fresnel="dielectric", n=1.5))])
    wi, wo = brdftab.geometry.sph_to_vec(0.3, 0.0), brdftab.geometry.sph_to_vec(0.4, 3.0)
    assert np.array_equal(m.eval(wi, wo), ref.eval(wi, wo))
    assert spec.outputs[0].path == tmp_path / "out" / "a.nc"   # relative to the spec's folder
    assert m.parameters["terms"][1]["parameters"]["term"]["parameters"]["alpha"] == 0.2


def test_spectral_spec_samples_wavelengths(tmp_path):
    p = write(tmp_path, """
[model]
name = "microfacet"
alpha = 0.3
fresnel = "conductor"
n = {wavelengths_nm = [400, 500, 600, 700], values = [1.4, 0.9, 0.3, 0.16]}
k = {wavelengths_nm = [400, 500, 600, 700], values = [1.9, 1.9, 2.9, 3.9]}
[grid]
type = "rusinkiewicz"
n_theta_h = 8
n_theta_d = 8
n_phi_d = 8
wavelengths_nm = [450, 550, 650]
[[output]]
path = "spectral.nc"
""")
    spec = load_spec(p)
    assert spec.model.spectral and list(spec.wavelengths) == [450, 550, 650]
    result = run(spec, progress=False)
    t = brdftab.open(result.written[0])
    assert t.spectral and list(t.wavelengths) == [450, 550, 650]
    wi, wo = t.grid.directions(100, 101)
    assert np.allclose(t.eval(wi, wo), spec.model.eval(wi, wo, [450, 550, 650]), rtol=1e-12)


def test_wavelengths_take_ranges_like_angle_lists(tmp_path):
    p = write(tmp_path, """
[model]
name = "lambert"
albedo = {wavelengths_nm = [380, 780], values = [0.2, 0.6]}
[grid]
type = "rusinkiewicz"
wavelengths_nm = [380, {start = 400, stop = 700, step = 100}, {start = 750, stop = 780, num = 2}]
[[output]]
path = "spectral.nc"
""")
    assert load_spec(p).wavelengths.tolist() == [380, 400, 500, 600, 700, 750, 780]


def test_spectral_model_without_wavelengths_uses_its_own(tmp_path):
    p = write(tmp_path, """
[model]
name = "lambert"
albedo = {wavelengths_nm = [400, 700], values = [0.2, 0.9]}
[grid]
type = "merl"
[[output]]
path = "x.nc"
""")
    assert list(load_spec(p).model.wavelengths) == [400, 700]


def test_spherical_grid_and_out_dir(tmp_path):
    p = write(tmp_path, """
description = "gonio sweep"
[model]
name = "microfacet"
alpha = 0.1
[grid]
type = "spherical"
theta_i_deg = [0, 30, 60]
phi_i_deg = [0]
theta_o_deg = [{start = 0, stop = 80, step = 10}, {start = 28, stop = 32, step = 0.5}]
phi_o_deg = {start = 0, stop = 360, num = 36, endpoint = false}
[[output]]
path = "g.nc"
dtype = "float32"
""")
    out = tmp_path / "elsewhere"
    out.mkdir()
    result = run(load_spec(p), out_dir=out, progress=False)
    assert result.written == [out / "g.nc"] and not (tmp_path / "g.nc").exists()
    t = brdftab.open(out / "g.nc")
    assert t.values.dtype == np.float32
    assert t.grid.shape == (3, 1, 17, 36)
    assert t.ds.attrs["comment"] == "gonio sweep"


def test_angle_parameters_in_degrees():
    # models with angle parameters take <name>_deg in specs; the API takes radians
    from brdftab.brdf import Model
    from brdftab.params import Param
    from brdftab.spec import build_model
    from brdftab import models

    class Tilted(Model):
        name = "tilted-test"
        params = (Param("tilt", "float", "tilt angle", units="rad", default=0.0, angle=True),)

        def _setup(self, tilt):
            self.tilt = tilt

    models.register(Tilted)
    try:
        m = build_model({"name": "tilted-test", "tilt_deg": 30}, "model", "x.toml")
        assert m.tilt == pytest.approx(np.pi / 6)
        with pytest.raises(brdftab.BrdftabError, match="tilt_deg"):
            build_model({"name": "tilted-test", "tilt": 0.5}, "model", "x.toml")
    finally:
        del models.MODELS["tilted-test"]


def test_utf8_bom_is_accepted(tmp_path):
    spec = _spec(tmp_path, output="bom.nc")
    spec.write_bytes(b"\xef\xbb\xbf" + spec.read_bytes())
    result = _cli("eval", spec, "--wi-deg", "30,0", "--wo-deg", "30,180", "--json")
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["channels"]["mono"] == pytest.approx(0.5 / np.pi)
    result = _cli("tabulate", spec)
    assert result.exit_code == 0, result.stderr
    assert (tmp_path / "bom.nc").is_file()
