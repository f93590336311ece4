"""The plug-in shape: registries for models, components, grids, formats and checks; formats
that state their native grid and optional library; one tabulation per target grid."""

import ast
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import brdftab
from brdftab import formats, models
from brdftab.checks import CHECKS, run_checks
from brdftab.grids import GRIDS, grid_from_config, merl_grid
from brdftab.models.components import COMPONENTS
from brdftab.references import REFERENCES, keys_in
from brdftab.spec import load_spec

ROOT = Path(__file__).resolve().parents[1]


def test_params_module_imports_nothing_of_brdf():
    tree = ast.parse((ROOT / "brdftab" / "params.py").read_text())
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert not [n for n in names if "brdf" in n.split(".")[-1] and n != "brdftab"], names


def test_every_cited_reference_key_exists():
    cited = [(m.name, m.reference) for m in models.MODELS.values()]
    cited += [(c.name, c.reference) for kind in COMPONENTS.values() for c in kind.values()]
    assert cited
    for owner, ref in cited:
        for key in keys_in(ref):
            assert key in REFERENCES, f"{owner} cites unknown reference {key!r}"


def test_components_compose_microfacet_and_did_you_mean():
    assert set(COMPONENTS["distribution"]) >= {"beckmann", "ggx"}
    assert set(COMPONENTS["fresnel"]) >= {"none", "schlick", "dielectric", "conductor"}
    m = models.create("microfacet", distribution="beckmann", alpha=0.2, fresnel="dielectric", n=1.5)
    assert m.dist.name == "beckmann" and m.fres.name == "dielectric"
    with pytest.raises(brdftab.errors.ParameterError, match="only used with fresnel = 'conductor'"):
        models.create("microfacet", alpha=0.2, fresnel="dielectric", n=1.5, k=2.0)
    with pytest.raises(brdftab.errors.ParameterError, match="did you mean 'conductor'"):
        models.create("microfacet", alpha=0.2, fresnel="conductr")


def test_grid_registry_builds_from_declared_keys():
    assert set(GRIDS) == {"rusinkiewicz", "merl", "spherical"}
    g = grid_from_config({"type": "rusinkiewicz", "n_theta_h": 5, "theta_d_deg": [0, 45, 90], "n_phi_d": 4})
    assert g.shape == (5, 3, 4)
    with pytest.raises(brdftab.errors.ParameterError, match="did you mean 'n_theta_d'"):
        grid_from_config({"type": "rusinkiewicz", "n_theta_dd": 5})


def test_grids_command_lists_types_and_keys():
    out = subprocess.run([sys.executable, "-m", "brdftab", "grids", "--json"], capture_output=True, text=True)
    assert set(json.loads(out.stdout)) == set(GRIDS)
    out = subprocess.run([sys.executable, "-m", "brdftab", "grids", "rusinkiewicz", "--json"], capture_output=True,
                         text=True)
    keys = {r["key"]: r for r in json.loads(out.stdout)["keys"]}
    assert keys["phi_d_fold"]["default"] == "reciprocity" and keys["theta_h_spacing"]["default"] == "linear"
    assert keys["n_theta_h"]["default"] == 90 and "theta_h_deg" in keys


def test_checks_are_registered_parts():
    assert {"finite", "non-negative", "missing"} <= set(CHECKS)
    t = brdftab.tabulate(models.create("lambert", albedo=0.5), brdftab.grids.RusinkiewiczGrid(4, 4, 4),
                         progress=False)
    assert run_checks(t).passed


# -- one tabulation per target grid -------------------------------------------------------------

def _npz_write(table, path, **options):
    np.save(open(path, "wb"), table.values)


@pytest.fixture
def merl_grid_format():
    """A stand-in format whose native grid is the MERL grid (values in an .npy file)."""
    fmt = formats.FileFormat(name="merlgrid-test", extensions=(".mgt",), description="test", read=None,
                             write=_npz_write, native_grid=lambda requested, options: merl_grid())
    formats.register(fmt)
    yield fmt
    del formats.FORMATS[fmt.name]


def test_each_output_tabulates_the_model_on_its_own_grid(tmp_path, merl_grid_format, monkeypatch):
    spec = tmp_path / "two.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha = 0.3\nfresnel = "conductor"\nn = 0.2\nk = 3.0\n'
                    '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 30\nn_theta_d = 30\nn_phi_d = 60\n'
                    '[[output]]\npath = "rus.nc"\n[[output]]\npath = "merl.mgt"\n')
    from brdftab import pipeline

    calls = []
    real = pipeline.tabulate
    monkeypatch.setattr(pipeline, "tabulate", lambda brdf, grid, *a, **k: calls.append(grid) or real(brdf, grid, *a,
                                                                                                         **k))
    s = load_spec(spec)
    pipeline.run(s, progress=False)
    assert len(calls) == 2 and calls[1].equals(merl_grid())
    stored = np.load(tmp_path / "merl.mgt")
    # the model itself at MERL bin centres (from the formula), not an interpolated table
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    th = ((i + 0.5) / 90) ** 2 * np.pi / 2
    td, pd = np.radians(j + 0.5), np.radians(k + 0.5)
    wi, wo = brdftab.geometry.hd_to_io(th, 0.0, td, pd)
    expected = s.model.eval(wi.reshape(-1, 3), wo.reshape(-1, 3)).reshape(stored.shape)
    assert np.allclose(stored, expected, rtol=1e-12, atol=0)
    rus = brdftab.open(tmp_path / "rus.nc")
    assert rus.grid.shape == (30, 30, 60)


def test_import_and_other_formats_work_without_openexr(tmp_path):
    code = ("import sys; sys.modules['OpenEXR'] = None\n"
            "import brdftab, brdftab.formats as f\n"
            "print(sorted(n for n, x in f.FORMATS.items() if not x.available))\n"
            "t = brdftab.tabulate(brdftab.models.create('lambert'), brdftab.grids.RusinkiewiczGrid(3, 3, 3),"
            " progress=False)\n"
            f"brdftab.save(t, {str(tmp_path / 'a.nc')!r})\n"
            "try:\n"
            f"    brdftab.save(t, {str(tmp_path / 'a.exr')!r})\n"
            "except brdftab.BrdftabError as e:\n"
            "    print('ERR', e)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert "'exr'" in lines[0]
    assert lines[1].startswith("ERR") and "OpenEXR" in lines[1] and "not installed" in lines[1]
    assert (tmp_path / "a.nc").exists() and not (tmp_path / "a.exr").exists()


def test_average_combinator_closed_forms():
    from brdftab.brdf import BRDF
    from brdftab.geometry import sph_to_vec

    class Toy(BRDF):  # f = (0.2 + 0.3 cosθi + 0.1 sin²θi cos 2φi) / π: not reciprocal, not isotropic
        name = "toy"
        reciprocal = False
        isotropic = False

        def _eval(self, wi, wo, lam, n):
            phi = np.arctan2(wi[:, 1], wi[:, 0])
            f = (0.2 + 0.3 * wi[:, 2] + 0.1 * (1 - wi[:, 2] ** 2) * np.cos(2 * phi)) / np.pi
            return np.repeat(f[:, None], n, axis=1)

    rng = np.random.default_rng(2)
    wi = sph_to_vec(np.arccos(rng.uniform(0.1, 1, 200)), rng.uniform(0, 6.3, 200))
    wo = sph_to_vec(np.arccos(rng.uniform(0.1, 1, 200)), rng.uniform(0, 6.3, 200))
    iso = models.create("average", term=Toy(), rotations=8)  # 8 rotations cancel cos 2φ exactly
    assert iso.isotropic and not iso.reciprocal
    np.testing.assert_allclose(iso.eval(wi, wo)[:, 0], (0.2 + 0.3 * wi[:, 2]) / np.pi, rtol=1e-12)
    both = models.create("average", term=Toy(), rotations=8, swap=True)
    assert both.reciprocal
    np.testing.assert_allclose(both.eval(wi, wo)[:, 0], (0.2 + 0.15 * (wi[:, 2] + wo[:, 2])) / np.pi, rtol=1e-12)
