"""One registry helper for every kind of plug-in: names, lookup and one error wording; what the
registries of models, components, grids and checks hold, and the references their members cite."""

import pytest
from click.testing import CliRunner

import brdftab
from brdftab import models
from brdftab.checks import CHECKS, configure, run_checks
from brdftab.cli import main
from brdftab.errors import ParameterError
from brdftab.formats import FORMATS, format_for
from brdftab.grids import GRIDS, grid_from_config
from brdftab.models import MODELS, components
from brdftab.models.components import COMPONENTS
from brdftab.references import REFERENCES, keys_in
from brdftab.registry import Registry, UnknownName

WORDING = r"unknown {kind} '{bad}' \(did you mean '{good}'\?\); valid: "


@pytest.mark.parametrize("lookup, kind, bad, good", [
    (lambda n: brdftab.models.create(n), "model", "microfacte", "microfacet"),
    (lambda n: components.get("distribution", n), "distribution", "gxg", "ggx"),
    (lambda n: components.get("fresnel", n), "fresnel", "conductr", "conductor"),
    (lambda n: grid_from_config({"type": n}), "grid type", "merll", "merl"),
    (lambda n: format_for("x.nc", n), "format", "netcfd", "netcdf"),
    (lambda n: configure({n: {"level": "warn"}}), "check", "energi", "energy"),
])
def test_every_registry_gives_the_same_wording(lookup, kind, bad, good):
    with pytest.raises(ParameterError, match=WORDING.format(kind=kind, bad=bad, good=good)):
        lookup(bad)


@pytest.mark.parametrize("args, kind, bad, good", [
    (["models", "microfacte"], "model", "microfacte", "microfacet"),
    (["grids", "merll"], "grid type", "merll", "merl"),
    (["formats", "netcfd"], "format", "netcfd", "netcdf"),
    (["validate", "--level", "energi=warn", "x.nc"], "check", "energi", "energy"),
])
def test_the_cli_says_it_in_one_line_with_exit_2(args, kind, bad, good):
    import re

    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2
    assert re.search(WORDING.format(kind=kind, bad=bad, good=good), r.output), r.output


def test_registries_are_registries_and_members_register_themselves():
    for reg, kind in ((MODELS, "model"), (GRIDS, "grid type"), (FORMATS, "format"), (CHECKS, "check"),
                      (components.COMPONENTS["shadowing"], "shadowing")):
        assert isinstance(reg, Registry) and reg.kind == kind and reg.names() == list(reg)
    # names and summaries under one attribute name for every kind
    for reg in (MODELS, GRIDS, FORMATS, CHECKS):
        assert all(isinstance(m.summary, str) and m.summary for m in reg.values())
        assert all(m.name == key for key, m in reg.items())
    # a model module registers its own classes (no central list)
    from brdftab.models import small2021

    assert MODELS["solar-cell-small2021"] is small2021.SolarCellSmall2021


def test_a_new_registry_member_and_a_missing_one():
    shapes = Registry("shape")

    @shapes.register
    class Disk:
        name = "disk"

    assert shapes.get("disk") is Disk and shapes.get("square", None) is None
    with pytest.raises(UnknownName, match="unknown shape 'dsik' \\(did you mean 'disk'\\?\\); valid: disk"):
        shapes.get("dsik")


# -- what the registries hold -----------------------------------------------------------------------

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
    assert set(GRIDS) == {"rusinkiewicz", "merl", "spherical", "specular-polar", "speos", "klems", "tensor-tree",
                          "scattered"}
    g = grid_from_config({"type": "rusinkiewicz", "n_theta_h": 5, "theta_d_deg": [0, 45, 90], "n_phi_d": 4})
    assert g.shape == (5, 3, 4)
    with pytest.raises(brdftab.errors.ParameterError, match="did you mean 'n_theta_d'"):
        grid_from_config({"type": "rusinkiewicz", "n_theta_dd": 5})


def test_checks_are_registered_parts():
    assert {"finite", "non-negative", "missing"} <= set(CHECKS)
    t = brdftab.tabulate(models.create("lambert", albedo=0.5), brdftab.grids.RusinkiewiczGrid(4, 4, 4),
                         progress=False)
    assert run_checks(t).passed


def test_every_format_says_what_quantity_it_holds():
    """`brdftab formats NAME` (the format's description) says which quantity its files hold:
    f_r, or what of it (RGL: f_r cosθo 4σ/D at its warped samples)."""
    from brdftab import formats

    for name in formats.usable():
        assert "f_r" in formats.FORMATS[name].description, name
