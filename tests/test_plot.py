"""brdftab.plot and ``brdftab plot``: every kind renders for an isotropic table, an anisotropic
model and a spectral table, and the figures hold the BRDF's values (read back from the
artists and compared with the BRDF evaluated at directions computed here)."""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import numpy as np
import pytest
from _cli import cli, names, one_error, partials

import brdftab
from brdftab import models, plot
from brdftab.table import tabulate

ROOT = Path(__file__).resolve().parents[1]
GALLERY = ROOT / "docs" / "gallery"
PNG = b"\x89PNG\r\n\x1a\n"


def direction(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack(np.broadcast_arrays(np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)), axis=-1)


def in_plane_pair(theta_i, theta_o, phi_i=0.0):
    """θo > 0 on the specular side (φo = φi + 180°), θo < 0 on the source's side."""
    return direction(theta_i, phi_i), direction(abs(theta_o), phi_i + (180.0 if theta_o >= 0 else 0.0))


@pytest.fixture(scope="module")
def iso_table(tmp_path_factory):
    path = tmp_path_factory.mktemp("plot") / "ggx.nc"
    model = models.create("microfacet", alpha=0.3, fresnel="schlick", f0=[0.9, 0.6, 0.3])
    brdftab.save(tabulate(model, brdftab.grids.RusinkiewiczGrid(16, 16, 32), progress=False), path)
    return brdftab.open(path)


@pytest.fixture(scope="module")
def aniso():
    return models.create("microfacet", alpha_x=0.1, alpha_y=0.4)


@pytest.fixture(scope="module")
def spectral_table(tmp_path_factory):
    path = tmp_path_factory.mktemp("plot") / "spectral.nc"
    spectrum = {"wavelengths_nm": [400, 550, 700]}
    model = models.create("microfacet", alpha=0.25, fresnel="conductor", n={**spectrum, "values": [0.5, 0.9, 1.6]},
                          k={**spectrum, "values": [4.8, 6.0, 7.5]})
    brdftab.save(tabulate(model, brdftab.grids.RusinkiewiczGrid(10, 10, 20), wavelengths=[400, 500, 600, 700],
                          progress=False), path)
    return brdftab.open(path)


def _options(kind, brdf):
    return {"compare": {"other": brdf}, "albedo": {"theta_i_deg": [0, 40, 80]}}.get(kind, {})


@pytest.mark.parametrize("kind", [k for k in plot.KINDS if k != "mueller"])  # mueller: polarized BRDFs only
@pytest.mark.parametrize("which", ["iso_table", "aniso", "spectral_table"])      # (tests/test_mueller_checks.py)
def test_every_kind_renders(kind, which, request):
    brdf = request.getfixturevalue(which)
    fig = plot.figure(kind, brdf, **_options(kind, brdf))
    png = plot.to_png_bytes(fig, dpi=40)
    assert png.startswith(PNG) and len(png) > 2000
    drawn = plot.artists(fig)
    data = [a for gid, a in drawn.items() if "channel=" in gid]
    assert data, drawn
    expected = ({"400 nm", "500 nm", "600 nm", "700 nm"} if which == "spectral_table" else
                {"R", "G", "B"} if which == "iso_table" else {"mono"})
    shown = {gid.rsplit("channel=", 1)[1] for gid in drawn if "channel=" in gid}
    assert shown <= expected and (shown == expected or kind in ("slice", "hemisphere"))
    for a in data:
        values = a.get_ydata() if hasattr(a, "get_ydata") else a.get_array()
        assert np.isfinite(np.asarray(values, float)).any()
    assert fig.axes[0].get_title() or fig._suptitle is not None


# --------------------------------------------------------------------------------------------
# in-plane and polar curves hold the BRDF's values


@pytest.mark.parametrize("theta_o", [-60.0, -0.1, 0.0, 29.9, 45.3, 89.9])
def test_in_plane_curves_are_the_table_s_values(iso_table, theta_o):
    fig = plot.in_plane(iso_table, theta_i_deg=[0, 30, 60])
    for t in (0, 30, 60):
        for c, name in enumerate("RGB"):
            line = plot.artists(fig)[f"theta_i={t}|channel={name}"]
            x, y = line.get_xdata(), line.get_ydata()
            assert x[0] == -89.9 and x[-1] == 89.9 and len(x) == 1799
            (j,) = np.flatnonzero(np.isclose(x, theta_o, atol=1e-9))
            f = iso_table.eval(*in_plane_pair(t, theta_o))[c]
            assert y[j] == pytest.approx(f, rel=1e-12)
            assert line.get_color() == {"R": "red", "G": "green", "B": "blue"}[name]
    ax = fig.axes[0]
    assert "sr⁻¹" in ax.get_ylabel() and "θo [deg]" in ax.get_xlabel()
    assert "ggx.nc: table of microfacet" in ax.get_title() and "alpha=0.3" in ax.get_title()


def test_anisotropic_model_is_plotted_in_the_chosen_plane(aniso):
    at_0 = plot.artists(plot.in_plane(aniso, theta_i_deg=[40]))["theta_i=40|channel=mono"].get_ydata()
    fig = plot.in_plane(aniso, theta_i_deg=[40], phi_i_deg=60.0)
    line = plot.artists(fig)["theta_i=40|channel=mono"]
    x, y = line.get_xdata(), line.get_ydata()
    assert line.get_color() == "black"
    for theta_o in (-50.0, 10.0, 40.0, 70.0):
        (j,) = np.flatnonzero(np.isclose(x, theta_o))
        assert y[j] == pytest.approx(aniso.eval(*in_plane_pair(40, theta_o, 60.0))[0], rel=1e-12)
    assert np.max(np.abs(y / at_0 - 1)) > 1.0          # another plane, another lobe
    assert "φi = 60°" in fig.axes[0].get_title() and "alpha_x=0.1" in fig.axes[0].get_title()


def test_spectral_table_is_plotted_per_wavelength(spectral_table):
    fig = plot.in_plane(spectral_table, theta_i_deg=[20])
    drawn = plot.artists(fig)
    assert set(drawn) == {f"theta_i=20|channel={lam} nm" for lam in (400, 500, 600, 700)}
    colours = {tuple(a.get_color()) for a in drawn.values()}
    assert len(colours) == 4                            # each wavelength its own hue
    for lam in (400, 600):
        line = drawn[f"theta_i=20|channel={lam} nm"]
        x, y = line.get_xdata(), line.get_ydata()
        for theta_o in (-30.0, 20.0, 55.5):
            (j,) = np.flatnonzero(np.isclose(x, theta_o))
            assert y[j] == pytest.approx(spectral_table.eval(*in_plane_pair(20, theta_o), [lam])[0], rel=1e-12)
    fig = plot.in_plane(spectral_table, theta_i_deg=[20], wavelengths=[550])
    assert set(plot.artists(fig)) == {"theta_i=20|channel=550 nm"}


def test_quantities_on_the_same_axes(iso_table):
    def curve(quantity):
        fig = plot.in_plane(iso_table, theta_i_deg=[30], quantity=quantity, log=False)
        line = plot.artists(fig)["theta_i=30|channel=G"]
        return line.get_xdata(), line.get_ydata(), fig.axes[0].get_ylabel()

    x, f, label = curve("brdf")
    xb, brf, label_b = curve("brf")
    xc, fcos, label_c = curve("brdf-cos")
    xr, rel, label_r = curve("relative")
    assert np.array_equal(x, xb) and np.array_equal(x, xc) and np.array_equal(x, xr)
    np.testing.assert_array_equal(brf, np.pi * f)                       # BRF = π f_r, exactly
    np.testing.assert_allclose(fcos, f * np.cos(np.radians(np.abs(x))), rtol=1e-12)
    mirror = iso_table.eval(*in_plane_pair(30, 30.0))[1]
    np.testing.assert_allclose(rel, f / mirror, rtol=1e-12)
    (j,) = np.flatnonzero(np.isclose(x, 30.0))
    assert rel[j] == pytest.approx(1.0, rel=1e-12)
    assert "sr⁻¹" in label and "f_r" in label
    assert "sr⁻¹" in label_c and "cos θo" in label_c
    assert "π f_r" in label_b and "dimensionless" in label_b and "sr" not in label_b
    assert "dimensionless" in label_r


def test_log_scale_on_request_and_for_peaked_lobes(iso_table):
    assert plot.in_plane(iso_table, log=True).axes[0].get_yscale() == "log"
    assert plot.in_plane(iso_table, log=False).axes[0].get_yscale() == "linear"
    lambert = models.create("lambert", albedo=0.5)
    assert plot.in_plane(lambert).axes[0].get_yscale() == "linear"            # a flat curve
    glossy = models.create("microfacet", alpha=0.05)
    assert plot.in_plane(glossy).axes[0].get_yscale() == "log"                # spans decades


def test_polar_curves_hold_the_values_with_theta_o_as_the_angle(aniso):
    fig = plot.polar(aniso, theta_i_deg=[50], phi_i_deg=90.0)
    line = plot.artists(fig)["theta_i=50|channel=mono"]
    angle, r = line.get_xdata(), line.get_ydata()
    assert fig.axes[0].name == "polar"
    for theta_o in (-45.0, 50.0, 80.0):
        (j,) = np.flatnonzero(np.isclose(angle, math.radians(theta_o)))
        assert r[j] == pytest.approx(aniso.eval(*in_plane_pair(50, theta_o, 90.0))[0], rel=1e-12)


# --------------------------------------------------------------------------------------------
# slices, hemisphere maps, albedo, comparison


def test_slice_of_a_rusinkiewicz_table_shows_its_stored_samples(iso_table):
    axes = {a.name: np.asarray(a.values) for a in iso_table.grid.axes}
    k = 12
    fig = plot.slice_image(iso_table, phi_d_deg=math.degrees(axes["phi_d"][k]), quantity="brdf")
    for c, name in enumerate("RGB"):
        img = np.asarray(plot.artists(fig)[f"slice|channel={name}"].get_array(), float)  # rows θd, columns θh
        stored = iso_table.values[:, :, k, c].T
        th, td = np.meshgrid(axes["theta_h"], axes["theta_d"])
        # below the horizon: wi or wo has z <= 0 (cosθi = cosθh cosθd − sinθh sinθd cosφd, ...)
        cos_pd = math.cos(axes["phi_d"][k])
        zi = np.cos(th) * np.cos(td) - np.sin(th) * np.sin(td) * cos_pd
        zo = np.cos(th) * np.cos(td) + np.sin(th) * np.sin(td) * cos_pd
        above = (zi > 1e-9) & (zo > 1e-9)
        assert img.shape == stored.shape and (~above).any() and above.any()
        assert np.all(np.isnan(img[~above]))
        np.testing.assert_allclose(img[above], stored[above], rtol=1e-9)
    assert "θh [deg]" in fig.axes[0].get_xlabel() and "θd [deg]" in fig.axes[0].get_ylabel()


def test_slice_of_a_model_is_evaluated_on_1_degree_cells(aniso):
    fig = plot.slice_image(aniso, phi_d_deg=90.0, phi_h_deg=30.0)
    img = np.asarray(plot.artists(fig)["slice|channel=mono"].get_array(), float)
    assert img.shape == (90, 90)
    for i, j in ((5, 3), (40, 20), (70, 10)):                       # (θd index, θh index)
        th, td = math.radians(j + 0.5), math.radians(i + 0.5)
        h = direction(j + 0.5, 30.0)
        # wi = Rz(φh) Ry(θh) d, with d = (sinθd cosφd, sinθd sinφd, cosθd) and φd = 90°
        d = np.array([0.0, math.sin(td), math.cos(td)])
        ry = np.array([[math.cos(th), 0, math.sin(th)], [0, 1, 0], [-math.sin(th), 0, math.cos(th)]])
        p = math.radians(30.0)
        rz = np.array([[math.cos(p), -math.sin(p), 0], [math.sin(p), math.cos(p), 0], [0, 0, 1]])
        wi = rz @ ry @ d
        wo = 2 * (wi @ h) * h - wi
        assert img[i, j] == pytest.approx(aniso.eval(wi, wo)[0], rel=1e-9)


def test_equal_area_projection_places_directions_by_the_formula():
    theta, phi = np.radians([0.0, 30.0, 60.0, 90.0]), np.radians([0.0, 45.0, 200.0, 270.0])
    x, y = plot.equal_area(theta, phi)
    r = 2 * np.sin(theta / 2) / math.sqrt(2)                 # horizon at r = 1
    np.testing.assert_allclose(x, r * np.cos(phi), atol=1e-15)
    np.testing.assert_allclose(y, r * np.sin(phi), atol=1e-15)
    t2, p2 = plot.equal_area_inverse(x, y)
    np.testing.assert_allclose(t2, theta, atol=1e-12)
    # equal area: the cap θ < 60° holds half the hemisphere's solid angle (1 − cos 60°), half the disc
    _, _, t, _ = plot.hemisphere_grid(400)
    inside = np.isfinite(t)
    assert np.mean(t[inside] < math.radians(60.0)) == pytest.approx(0.5, abs=2e-3)


def test_hemisphere_map_holds_the_values_and_puts_the_peak_at_the_mirror_direction():
    glossy = models.create("microfacet", alpha=0.03)
    n = 161
    fig = plot.hemisphere(glossy, theta_i_deg=[40], phi_i_deg=0.0, n=n)
    img = np.asarray(plot.artists(fig)["hemisphere|channel=mono"].get_array().filled(np.nan), float)
    assert img.shape == (n, n)
    centres = -1 + (np.arange(n) + 0.5) * 2 / n
    row, col = np.unravel_index(np.nanargmax(img), img.shape)
    # the mirror direction (40°, 180°): x = −√2 sin 20°, y = 0
    assert abs(centres[col] + math.sqrt(2) * math.sin(math.radians(20))) <= 1 / n + 1e-12
    assert abs(centres[row]) <= 1 / n + 1e-12
    wi = direction(40.0, 0.0)
    for i, j in ((80, 20), (30, 100), (140, 70)):
        x, y = centres[j], centres[i]
        r = math.hypot(x, y)
        theta, phi = 2 * math.asin(r / math.sqrt(2)), math.atan2(y, x)
        wo = direction(math.degrees(theta), math.degrees(phi))
        assert img[i, j] == pytest.approx(glossy.eval(wi, wo)[0], rel=1e-12)
    assert np.isnan(img[0, 0]) and np.isnan(img[-1, -1])          # corners: outside the disc
    bar = [a for a in fig.axes if a.get_ylabel().startswith("f_r")]
    assert bar and "sr⁻¹" in bar[0].get_ylabel()


def test_hemisphere_values_map_given_directions():
    d = direction(np.array([10.0, 50.0, 80.0]), np.array([0.0, 120.0, 250.0]))
    fig = plot.hemisphere_values(d, [1.0, 2.0, 3.0], label="asymmetry", title="where it fails", incident=d[0])
    dots = plot.artists(fig)["values"]
    x, y = plot.equal_area(np.radians([10.0, 50.0, 80.0]), np.radians([0.0, 120.0, 250.0]))
    np.testing.assert_allclose(dots.get_offsets(), np.stack([x, y], axis=1), atol=1e-12)
    np.testing.assert_array_equal(dots.get_array(), [1.0, 2.0, 3.0])
    assert plot.to_png_bytes(fig).startswith(PNG)


def _albedo_by_quadrature(brdf, theta_i_deg, n=400):
    """a(θi) by a midpoint rule in (μo = cosθo, φo): ∫ f μo dμo dφo."""
    mu = (np.arange(n) + 0.5) / n
    phi = (np.arange(2 * n) + 0.5) * np.pi / n
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - M * M)
    wo = np.stack([s * np.cos(P), s * np.sin(P), M], axis=-1).reshape(-1, 3)
    f = brdf.eval(direction(theta_i_deg, 0.0), wo)
    return (f * M.reshape(-1, 1)).sum(axis=0) * (1.0 / n) * (np.pi / n)


def test_albedo_curve_is_the_hemispherical_integral(iso_table):
    fig = plot.albedo(iso_table, theta_i_deg=[0, 30, 60])
    drawn = plot.artists(fig)
    for c, name in enumerate("RGB"):
        line = drawn[f"albedo|channel={name}"]
        np.testing.assert_array_equal(line.get_xdata(), [0, 30, 60])
        for j, t in enumerate((0.0, 30.0, 60.0)):
            assert line.get_ydata()[j] == pytest.approx(_albedo_by_quadrature(iso_table, t)[c], abs=2e-3)
    lambert = models.create("lambert", albedo=0.7)
    y = plot.artists(plot.albedo(lambert, theta_i_deg=[0, 45, 85]))["albedo|channel=mono"].get_ydata()
    np.testing.assert_allclose(y, 0.7, rtol=1e-9)
    assert "dimensionless" in fig.axes[0].get_ylabel()


def test_compare_shows_both_and_their_difference(iso_table):
    source = models.create("microfacet", alpha=0.3, fresnel="schlick", f0=[0.9, 0.6, 0.3])
    fig = plot.compare(source, iso_table, theta_i_deg=[45])
    drawn = plot.artists(fig)
    a = drawn["A: theta_i=45|channel=R"]
    b = drawn["B: theta_i=45|channel=R"]
    d = drawn["B−A: theta_i=45|channel=R"]
    assert b.get_linestyle() == "None" and b.get_marker() == "o"
    x = d.get_xdata()
    for theta_o in (-40.0, 10.0, 45.0, 80.0):
        (j,) = np.flatnonzero(np.isclose(x, theta_o))
        fa = source.eval(*in_plane_pair(45, theta_o))[0]
        fb = iso_table.eval(*in_plane_pair(45, theta_o))[0]
        assert a.get_ydata()[j] == pytest.approx(fa, rel=1e-12)
        assert d.get_ydata()[j] == pytest.approx(fb - fa, rel=1e-9, abs=1e-15)
    assert set(np.round(b.get_xdata(), 6)) <= set(np.round(x, 6))
    assert "sr⁻¹" in fig.axes[1].get_ylabel()
    fig = plot.compare(source, iso_table, theta_i_deg=[45], ratio=True)
    r = plot.artists(fig)["B/A: theta_i=45|channel=G"]
    (j,) = np.flatnonzero(np.isclose(r.get_xdata(), 20.0))
    assert r.get_ydata()[j] == pytest.approx(iso_table.eval(*in_plane_pair(45, 20.0))[1]
                                             / source.eval(*in_plane_pair(45, 20.0))[1], rel=1e-9)
    with pytest.raises(brdftab.BrdftabError, match="cannot compare channels"):
        plot.compare(iso_table, models.create("lambert", albedo=[0.1, 0.2]))


def test_figure_dispatch_refuses_unknown_kinds_and_options(aniso):
    with pytest.raises(brdftab.BrdftabError, match="unknown plot kind 'pie'"):
        plot.figure("pie", aniso)
    with pytest.raises(brdftab.BrdftabError, match="does not apply"):
        plot.figure("albedo", aniso, quantity="brf")
    with pytest.raises(brdftab.BrdftabError, match="second BRDF"):
        plot.figure("compare", aniso)


def test_the_command_line_s_static_lists_are_the_module_s():
    from brdftab import cli_plot

    assert cli_plot.KINDS == plot.KINDS
    assert cli_plot.QUANTITIES == tuple(plot.QUANTITIES)


# --------------------------------------------------------------------------------------------
# the command line


@pytest.fixture(scope="module")
def table_file(iso_table):
    return Path(iso_table.ds.encoding["source"])


def test_default_kind_just_works(table_file, tmp_path):
    out = tmp_path / "p.png"
    r = cli("plot", table_file, "-o", out)
    assert r.exit_code == 0, r.output
    assert out.read_bytes().startswith(PNG) and names(tmp_path) == ["p.png"]
    assert "in-plane" in r.output


def test_formats_by_extension(table_file, tmp_path):
    for name, head in (("p.svg", b"<?xml"), ("p.pdf", b"%PDF")):
        r = cli("plot", table_file, "--kind", "polar", "-o", tmp_path / name)
        assert r.exit_code == 0, r.output
        assert (tmp_path / name).read_bytes().startswith(head)


def test_a_spec_is_plotted_without_tabulating(tmp_path):
    spec = ROOT / "specs" / "lambert-white.toml"
    r = cli("plot", spec, "--kind", "albedo", "--theta-i-deg", "0,45", "-o", tmp_path / "a.png")
    assert r.exit_code == 0, r.output
    assert names(tmp_path) == ["a.png"]


@pytest.mark.parametrize("args, expected", [
    (["-o", "{d}/p.jpg"], "unknown plot format '.jpg'"),
    (["-o", "{d}/p"], "unknown plot format '(no extension)'"),
    (["--kind", "slice", "--theta-i-deg", "30", "-o", "{d}/p.png"], "--theta-i-deg does not apply to --kind slice"),
    (["--kind", "compare", "-o", "{d}/p.png"], "needs --against"),
    (["--theta-i-deg", "30,x", "-o", "{d}/p.png"], "--theta-i-deg expects angles"),
    (["--theta-i-deg", "95", "-o", "{d}/p.png"], "theta_i must lie in [0, 90)"),
    (["--channel", "Q", "-o", "{d}/p.png"], "channel 'Q' is not among R, G, B"),
    (["--kind", "pie", "-o", "{d}/p.png"], "'pie' is not one of"),
])
def test_bad_input_is_one_line_and_no_file(table_file, tmp_path, args, expected):
    r = cli("plot", table_file, *[a.format(d=tmp_path) for a in args])
    one_error(r.stderr, r.exit_code, expected)
    assert names(tmp_path) == []


def test_unreadable_input_and_existing_output(tmp_path, table_file):
    bad = tmp_path / "bad.nc"
    bad.write_bytes(b"not a table")
    r = cli("plot", bad, "-o", tmp_path / "p.png")
    one_error(r.stderr, r.exit_code, "bad.nc")
    assert names(tmp_path) == ["bad.nc"]
    out = tmp_path / "p.png"
    out.write_bytes(b"old")
    r = cli("plot", table_file, "-o", out)
    one_error(r.stderr, r.exit_code, "already exists")
    assert out.read_bytes() == b"old" and partials(tmp_path) == []
    assert cli("plot", table_file, "-o", out, "--overwrite").exit_code == 0
    assert out.read_bytes().startswith(PNG)
    copy = tmp_path / "t.nc"
    copy.write_bytes(table_file.read_bytes())
    r = cli("plot", copy, "-o", tmp_path / "t.nc", "--overwrite")   # an unknown extension first ...
    one_error(r.stderr, r.exit_code, "unknown plot format")
    pdf = tmp_path / "same.pdf"
    pdf.write_bytes(copy.read_bytes())
    r = cli("plot", copy, "--kind", "compare", "--against", pdf, "-o", pdf, "--overwrite")
    one_error(r.stderr, r.exit_code, "same.pdf")                    # ... never the file it reads
    assert pdf.read_bytes() == copy.read_bytes()


def test_a_failed_render_leaves_no_file(table_file, tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    def broken(self, *a, **k):
        raise RuntimeError("renderer failed")

    monkeypatch.setattr(Figure, "savefig", broken)
    r = cli("plot", table_file, "-o", tmp_path / "p.png")
    assert r.exit_code == 1 and "renderer failed" in r.stderr
    assert names(tmp_path) == []


def test_malformed_points_file_names_the_line(table_file, tmp_path):
    pts = tmp_path / "pts.csv"
    pts.write_text("theta_i_deg,theta_o_deg,value\n10,13.3,1.0\n45,75\n")
    r = cli("plot", table_file, "--points", pts, "-o", tmp_path / "p.png")
    one_error(r.stderr, r.exit_code, "pts.csv, line 3")
    assert names(tmp_path) == ["pts.csv"]


# --------------------------------------------------------------------------------------------
# the README gallery


def _gallery_commands() -> list:
    import re

    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("### Gallery"):]
    section = section[:section.index("\n## ")] if "\n## " in section else section
    return [line.strip() for block in re.findall(r"^```sh\n(.*?)^```", section, flags=re.S | re.M)
            for line in block.splitlines() if line.strip().startswith("brdftab plot")]


def test_gallery_images_are_committed_small_and_made_by_the_readme_commands():
    cmds = _gallery_commands()
    assert len(cmds) >= 4
    for cmd in cmds:
        args = shlex.split(cmd)
        out = Path(args[args.index("-o") + 1])
        assert out.parent.as_posix() == "docs/gallery" and "--overwrite" in args
        image = ROOT / out
        assert image.is_file() and image.read_bytes().startswith(PNG), out
        assert image.stat().st_size < 60_000, (out, image.stat().st_size)
        assert f"]({out.as_posix()})" in (ROOT / "README.md").read_text(encoding="utf-8")


def test_gallery_torrance_sparrow_curves_pass_through_the_paper_s_points(monkeypatch, tmp_path):
    """The Fig. 8 reproduction: its command's curves pass through the printed values the
    paper-reproduction tests hold (test_torrance_sparrow: rel 1 %, the maxima at ±0.1°)."""
    (cmd,) = [c for c in _gallery_commands() if "torrance-sparrow" in c]
    figures = []
    monkeypatch.setattr(plot, "save", lambda fig, path, **kw: figures.append(fig))
    monkeypatch.chdir(ROOT)
    r = cli(*shlex.split(cmd)[1:])
    assert r.exit_code == 0, r.output
    (fig,) = figures
    drawn = plot.artists(fig)
    printed = np.loadtxt(GALLERY / "torrance-sparrow-fig8.csv", delimiter=",", skiprows=1, comments="#")
    np.testing.assert_allclose(drawn["points"].get_xydata(), printed[:, 1:])
    for theta_i, theta_o, value in printed:
        line = drawn[f"theta_i={theta_i:g}|channel=mono"]
        x, y = line.get_xdata(), line.get_ydata()
        # a value on the horizon is the limit θo → 90°: the curve's last node, 0.1° short of it
        j = y.size - 1 if theta_o >= 90.0 else None
        assert (y[j] if j is not None else np.interp(theta_o, x, y)) == pytest.approx(value, rel=0.01)
        if value == printed[printed[:, 0] == theta_i, 2].max():       # the curve's printed maximum
            assert x[np.argmax(y)] == pytest.approx(min(theta_o, x[-1]), abs=0.1)
    assert "dimensionless" in fig.axes[0].get_ylabel()


def test_readme_fig8_table_gives_the_plotted_curve():
    """The README's Fig. 8 table: its "plotted curve" column is the gallery figure's curve."""
    import re

    text = (ROOT / "README.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| (\d+)° \| [^|]+ \| ([\d.]+) at ([\d.]+)°[^|]* \|$", text, flags=re.M)
    assert len(rows) == 4
    model = brdftab.from_spec(ROOT / "specs" / "torrance-sparrow-aluminum.toml")
    drawn = plot.artists(plot.in_plane(model, theta_i_deg=[10, 45, 75], quantity="relative"))
    for psi, value, at in rows:
        line = drawn[f"theta_i={psi}|channel=mono"]
        (j,) = np.flatnonzero(np.isclose(line.get_xdata(), float(at)))
        assert line.get_ydata()[j] == pytest.approx(float(value), abs=0.6 * 10.0 ** -(len(value.split(".")[1])))


def test_a_spectral_spec_is_plotted_at_a_few_of_its_wavelengths(tmp_path, monkeypatch):
    spec = tmp_path / "s.toml"
    spec.write_text('[model]\nname = "microfacet"\nalpha = 0.3\nfresnel = "conductor"\n'
                    'n = {wavelengths_nm = [400, 700], values = [0.5, 1.5]}\n'
                    'k = {wavelengths_nm = [400, 700], values = [4.0, 7.0]}\n'
                    '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 4\nn_theta_d = 4\nn_phi_d = 8\n'
                    'wavelengths_nm = [400, 450, 500, 550, 600, 650, 700]\n[[output]]\npath = "s.nc"\n')
    figures = []
    monkeypatch.setattr(plot, "save", lambda fig, path, **kw: figures.append(fig))
    r = cli("plot", spec, "--theta-i-deg", "30", "-o", tmp_path / "p.png")
    assert r.exit_code == 0, r.output
    drawn = plot.artists(figures[0])
    assert set(drawn) == {f"theta_i=30|channel={lam} nm" for lam in (400, 500, 550, 600, 700)}
    model = brdftab.from_spec(spec)
    line = drawn["theta_i=30|channel=550 nm"]
    (j,) = np.flatnonzero(np.isclose(line.get_xdata(), 30.0))
    assert line.get_ydata()[j] == pytest.approx(model.eval(*in_plane_pair(30, 30.0), [550.0])[0], rel=1e-12)
    assert not (tmp_path / "s.nc").exists()          # plotted, not tabulated


def test_spectral_table_as_srgb(spectral_table):
    """``rgb=True``: the spectra at every wavelength of the table through
    :func:`brdftab.colorimetry.spectral_to_rgb` (D65, CIE 1931 2°), drawn as R, G, B."""
    from brdftab.colorimetry import spectral_to_rgb

    lam = spectral_table.wavelengths
    fig = plot.in_plane(spectral_table, theta_i_deg=[35], rgb=True)
    drawn = plot.artists(fig)
    assert set(drawn) == {f"theta_i=35|channel={c}" for c in "RGB"}
    for theta_o in (-20.0, 35.0, 70.0):
        spectrum = spectral_table.eval(*in_plane_pair(35, theta_o), lam)
        rgb = spectral_to_rgb(spectrum, lam)
        assert rgb.shape == (3,)
        for c, name in enumerate("RGB"):
            line = drawn[f"theta_i=35|channel={name}"]
            (j,) = np.flatnonzero(np.isclose(line.get_xdata(), theta_o))
            assert line.get_ydata()[j] == pytest.approx(rgb[c], rel=1e-12)
            assert line.get_color() == {"R": "red", "G": "green", "B": "blue"}[name]
    # the albedo in sRGB is the sRGB of the albedo spectrum (both are linear in f)
    from brdftab.integrate import directional_albedo

    y = plot.artists(plot.albedo(spectral_table, theta_i_deg=[0, 50], rgb=True))
    spectrum = directional_albedo(spectral_table, np.radians([0.0, 50.0]), 0.0, lam)
    expected = spectral_to_rgb(spectrum, lam)
    for c, name in enumerate("RGB"):
        np.testing.assert_allclose(y[f"albedo|channel={name}"].get_ydata(), expected[:, c], rtol=1e-9)
    with pytest.raises(brdftab.BrdftabError, match="sRGB needs a spectrum"):
        plot.in_plane(models.create("lambert", albedo=0.5), rgb=True)


def test_albedo_values_draws_a_given_curve_with_its_limit():
    theta = [0.0, 30.0, 60.0, 85.0]
    values = np.array([[0.5, 0.4], [0.52, 0.41], [0.6, 0.45], [1.2, 0.5]])
    fig = plot.albedo_values(theta, values, ["R", "550 nm"], limit=1.01, title="from a check")
    drawn = plot.artists(fig)
    np.testing.assert_array_equal(drawn["albedo|channel=R"].get_ydata(), values[:, 0])
    np.testing.assert_array_equal(drawn["albedo|channel=550 nm"].get_xdata(), theta)
    assert drawn["albedo|channel=R"].get_color() == "red"
    assert np.allclose(drawn["limit"].get_ydata(), 1.01)
    assert fig.axes[0].get_title() == "from a check"
    with pytest.raises(brdftab.BrdftabError, match="4 incidence angles but 3"):
        plot.albedo_values(theta, values[:3])
    with pytest.raises(brdftab.BrdftabError, match="1 channel names for 2"):
        plot.albedo_values(theta, values, ["R"])
    # a tolerance is a bound above 1; several azimuths: one line style each; many channels: five
    per_phi = np.stack([values, values + 0.1], axis=1)
    drawn = plot.artists(plot.albedo_values(theta, per_phi, ["R", "G"], phi_i_deg=[0, 90], limit=0.01))
    assert np.allclose(drawn["limit"].get_ydata(), 1.01)
    np.testing.assert_array_equal(drawn["albedo|phi_i=90|channel=G"].get_ydata(), values[:, 1] + 0.1)
    assert drawn["albedo|phi_i=90|channel=G"].get_linestyle() != drawn["albedo|phi_i=0|channel=G"].get_linestyle()
    spectrum = np.linspace(0.1, 0.9, 4 * 31).reshape(4, 31)
    names = [f"{lam} nm" for lam in range(400, 710, 10)]
    drawn = plot.artists(plot.albedo_values(theta, spectrum, names))
    assert sorted(drawn) == sorted(f"albedo|channel={lam} nm" for lam in (400, 480, 550, 620, 700))


def test_a_gonio_table_is_drawn_at_its_own_incidence_angles(tmp_path):
    from brdftab.grids import SphericalGrid

    grid = SphericalGrid(np.radians([20.0, 40.0, 90.0]), np.radians([0.0]), np.radians(np.arange(0.0, 41.0, 5.0)),
                         np.radians(np.arange(0.0, 360.0, 30.0)))
    brdftab.save(tabulate(models.create("lambert", albedo=0.5), grid, progress=False), tmp_path / "g.nc")
    table = brdftab.open(tmp_path / "g.nc")
    with pytest.warns(brdftab.errors.BrdftabWarning, match="outside the domain"):   # θo beyond 40°: one warning
        drawn = plot.artists(plot.in_plane(table))
    assert set(drawn) == {"theta_i=20|channel=mono", "theta_i=40|channel=mono"}    # not 0, 30, 60; 90 is grazing
    x, y = drawn["theta_i=20|channel=mono"].get_xdata(), drawn["theta_i=20|channel=mono"].get_ydata()
    np.testing.assert_allclose(y[np.abs(x) <= 40.0], 0.5 / np.pi, rtol=1e-12)        # inside its θo domain
    assert np.all(np.isnan(y[np.abs(x) > 40.0 + 1e-9]))                             # outside: a gap, not 0
    line = plot.artists(plot.albedo(table))["albedo|channel=mono"]
    np.testing.assert_array_equal(line.get_xdata(), [20.0, 40.0])
