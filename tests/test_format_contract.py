"""One contract over every registered file format (and every format registered later).

For each format that writes: a BRDF is written; the file is recognised by its content (under a
name with a foreign extension) and by its extension; it reads back within the format's stated
precision (``FileFormat.precision``: the largest relative difference from what was written);
truncated and corrupted files (for a store, a folder: its metadata and a chunk of samples
truncated, corrupted or missing) give one brdftab error line and exit 2 from the command line,
never a traceback; unknown options are refused with did-you-mean. For every format: unknown
options are refused. A deliberately broken toy format proves the suite can fail. Per-format
test files keep only what is specific to each format.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import brdftab
from brdftab import formats
from brdftab.brdf import BRDF
from brdftab.errors import BrdftabError, ParameterError
from brdftab.geometry import sph_to_vec
from brdftab.grids import RusinkiewiczGrid

SMALL = RusinkiewiczGrid(16, 16, 32, theta_h_spacing="merl")


def source():
    """An RGB, isotropic, reciprocal BRDF every writer can hold."""
    m = brdftab.models
    return m.create("sum", terms=[m.create("lambert", albedo=[0.1, 0.2, 0.3]),
                                  m.create("microfacet", alpha=0.3, fresnel="conductor", n=[0.2, 0.4, 1.4],
                                           k=[3.9, 2.4, 1.6])])


def polarized_source():
    """A spectral, polarized BRDF (five wavelengths) for the formats that hold a Mueller matrix."""
    from _polarized import GGXConductor

    return GGXConductor(0.3)


def pairs(n=300, seed=0):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(np.cos(np.radians(80.0)), 1.0, (2, n))
    phi = rng.uniform(0, 2 * np.pi, (2, n))
    return sph_to_vec(np.arccos(mu[0]), phi[0]), sph_to_vec(np.arccos(mu[1]), phi[1])


def written_brdf(payload):
    """What a writer reports it wrote, as a BRDF (a table, or an RGL payload's reader view)."""
    return payload if isinstance(payload, BRDF) else payload.bsdf


def cli(*args):
    return subprocess.run([sys.executable, "-m", "brdftab", *map(str, args)], capture_output=True, text=True,
                          timeout=120)


def check_format_contract(fmt, folder: Path):
    """Assert the contract on ``fmt`` (AssertionError naming the broken clause)."""
    ext = fmt.extensions[0]
    path = folder / f"contract{ext}"
    payload = brdftab.save(polarized_source() if fmt.polarized else source(), path, grid=SMALL, format=fmt.name)
    assert path.exists(), f"{fmt.name}: nothing written"
    # recognised by extension, and by content under a foreign name
    assert formats.format_for(path).name == fmt.name or any(
        f.name == fmt.name for f in formats.FORMATS.values() if ext in f.extensions), f"{fmt.name}: extension"
    alias = folder / "contract.data"
    if path.is_dir():  # a store (a folder): copied whole
        shutil.copytree(path, alias)
    else:
        alias.write_bytes(path.read_bytes())
    assert formats.detect(alias).name == fmt.name, f"{fmt.name}: not recognised by its content"
    # read back within the stated precision, from both names
    wi, wo = pairs()
    expect = written_brdf(payload).eval(wi, wo)
    for p in (path, alias):
        got = brdftab.open(p).eval(wi, wo)
        big = np.abs(expect) > 1e-6
        rel = np.abs(got[big] - expect[big]) / np.abs(expect[big])
        assert rel.max() <= fmt.precision, (f"{fmt.name}: read back differs by {rel.max():.3g} (stated precision "
                                           f"{fmt.precision:g})")
    # truncated and corrupted files: one brdftab error line, exit 2 (or a readable table), no traceback
    for what, bad in damaged_copies(path, folder, ext):
        try:
            t = brdftab.open(bad)
            t.eval(wi[:5], wo[:5])
        except BrdftabError as exc:
            assert "\n" not in str(exc).strip(), f"{fmt.name}: {what}: more than one line"
        proc = cli("info", bad)
        assert "Traceback" not in proc.stderr, f"{fmt.name}: {what}: traceback"
        assert proc.returncode in (0, 2), f"{fmt.name}: {what}: exit {proc.returncode}: {proc.stderr}"
        if proc.returncode == 2:
            assert len(proc.stderr.strip().splitlines()) == 1, f"{fmt.name}: {what}: {proc.stderr}"
    check_options_refused(fmt)


def damaged_copies(path: Path, folder: Path, ext: str):
    """``(what, path)`` of damaged copies of ``path``: truncated, cut to its head, corrupted; for
    a store (a folder), its metadata cut short and one of its largest files (a chunk of samples)
    truncated, corrupted or missing."""
    def damage(data):
        return {"truncated": data[: len(data) // 2], "head-only": data[:40],
                "corrupted": data[:16] + bytes(b ^ 0x5A for b in data[16:200]) + data[200:]}

    if not path.is_dir():
        for what, content in damage(path.read_bytes()).items():
            bad = folder / f"{what}{ext}"
            bad.write_bytes(content)
            yield what, bad
        return
    files = sorted((p for p in path.rglob("*") if p.is_file()), key=lambda p: (-p.stat().st_size, str(p)))
    meta = next(p for p in (path / "zarr.json", path / ".zgroup") if p.exists())
    for name, victim in (("metadata", meta), ("chunk", files[0])):
        cut = damage(victim.read_bytes())
        for what, content in (("truncated", cut["truncated"]), ("corrupted", cut["corrupted"]), ("missing", None)):
            bad = folder / f"{name}-{what}{ext}"
            shutil.copytree(path, bad)
            target = bad / victim.relative_to(path)
            if content is None:
                target.unlink()
            else:
                target.write_bytes(content)
            yield f"{name} {what}", bad


def check_options_refused(fmt):
    names = list(fmt.options)
    with pytest.raises(ParameterError, match="unknown option for format"):
        fmt.validate_options({"no_such_option": 1})
    if names:
        typo = names[0][:-1] + ("x" if names[0][-1] != "x" else "y")
        with pytest.raises(ParameterError, match=f"did you mean '{names[0]}'"):
            fmt.validate_options({typo: 1})


WRITERS = sorted(n for n, f in formats.FORMATS.items() if f.write is not None)


@pytest.mark.parametrize("name", WRITERS)
def test_every_writable_format_keeps_the_contract(name, tmp_path):
    check_format_contract(formats.FORMATS[name], tmp_path)


@pytest.mark.parametrize("name", sorted(formats.FORMATS))
def test_every_format_declares_its_options_and_refuses_unknown_ones(name):
    fmt = formats.FORMATS[name]
    check_options_refused(fmt)
    assert isinstance(fmt.summary, str) and fmt.summary and fmt.extensions


# -- the suite can fail ----------------------------------------------------------------------------

def _toy_format(lossy: bool):
    """A toy text format: the header, then the table's values; ``lossy`` drops every other value
    when reading (a broken reader the contract must catch)."""
    from brdftab.table import make_table

    magic = b"TOYBRDF\n"

    def write(table, path, **options):
        np.savetxt(path, table.values.reshape(-1), header="TOYBRDF", comments="")

    def read(path):
        try:
            values = np.loadtxt(path, skiprows=1)
            values = values.reshape(SMALL.shape + (3,))
        except (ValueError, OSError) as exc:
            raise brdftab.errors.FormatError(f"{path}: not a toy table ({exc})") from None
        if lossy:
            values = values.copy()
            values.reshape(-1)[::2] = 0.0
        return make_table(values, SMALL, source().layout)

    return formats.FileFormat(name="toy", extensions=(".toy",), description="a toy text format", read=read,
                              write=write, magic=(magic,), precision=1e-6)


def test_the_contract_passes_a_sound_toy_format_and_catches_a_broken_one(monkeypatch, tmp_path):
    monkeypatch.setitem(formats.FORMATS, "toy", _toy_format(lossy=False))
    check_format_contract(formats.FORMATS["toy"], tmp_path)   # a format registered later is covered
    monkeypatch.setitem(formats.FORMATS, "toy", _toy_format(lossy=True))
    again = tmp_path / "again"
    again.mkdir()
    with pytest.raises(AssertionError, match="read back differs"):
        check_format_contract(formats.FORMATS["toy"], again)
