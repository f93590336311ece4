"""Fuzzing the MERL, EXR and netCDF readers: random bytes and mutated valid files give a table or a
brdftab error (a ``BrdftabError`` subclass, one line naming the file), never another
exception type.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import brdftab
from brdftab import models
from brdftab.errors import BrdftabError
from brdftab.grids import RusinkiewiczGrid
from brdftab.table import Table, tabulate

MERL_SIZE = 12 + 3 * 90 * 90 * 180 * 8
EXR_MAGIC = b"\x76\x2f\x31\x01"
FUZZ = settings(deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _read_ok_or_brdftab_error(path):
    try:
        table = brdftab.open(path)
    except BrdftabError as exc:
        msg = str(exc)
        assert "\n" not in msg and str(path) in msg, msg
        return None
    assert isinstance(table, Table)
    table.values  # loading the samples must not fail either
    return table


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


# --- MERL --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def merl_bytes(folder):
    rng = np.random.default_rng(3)
    raw = rng.uniform(-1, 3000, 3 * 90 * 90 * 180)
    return struct.pack("<3i", 90, 90, 180) + raw.astype("<f8").tobytes()


@settings(FUZZ, max_examples=60)
@given(data=st.binary(max_size=64), header=st.booleans(), suffix=st.sampled_from([".binary", ".dat"]))
def test_merl_random_bytes(folder, data, header, suffix):
    path = folder / f"random{suffix}"
    path.write_bytes((struct.pack("<3i", 90, 90, 180) if header else b"") + data)
    with pytest.raises(BrdftabError) as info:
        brdftab.open(path)
    assert "\n" not in str(info.value)


@settings(FUZZ, max_examples=25)
@given(kind=st.sampled_from(["truncate", "header", "append"]), cut=st.integers(0, MERL_SIZE - 1),
       flips=st.lists(st.tuples(st.integers(0, 11), st.integers(1, 255)), min_size=1, max_size=4,
                      unique_by=lambda t: t[0]),
       extra=st.binary(min_size=1, max_size=16))
def test_merl_mutated_file(folder, merl_bytes, kind, cut, flips, extra):
    data = bytearray(merl_bytes)
    if kind == "truncate":
        data = data[:cut]
    elif kind == "header":
        for pos, x in flips:
            data[pos] ^= x
    else:
        data += extra
    path = folder / "mutated.binary"
    path.write_bytes(bytes(data))
    with pytest.raises(BrdftabError) as info:
        brdftab.open(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_merl_changed_samples_are_still_a_valid_file(folder, merl_bytes):
    data = bytearray(merl_bytes)
    for pos in (12, 1000, len(data) // 2, len(data) - 1):
        data[pos] ^= 0xFF
    path = folder / "samples.binary"
    path.write_bytes(bytes(data))
    assert _read_ok_or_brdftab_error(path) is not None


# --- EXR ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def exr_files(folder):
    ggx = models.create("microfacet", alpha=0.3, fresnel="schlick", f0=[0.9, 0.6, 0.3])
    multi = folder / "multi-src.exr"
    brdftab.save(tabulate(ggx, RusinkiewiczGrid(12, 10, 3, theta_h_spacing="merl"), progress=False), multi)
    single = folder / "single-src.exr"
    brdftab.save(ggx, single, grid=RusinkiewiczGrid(9, 7, 4), phi_d_deg=[90])
    return {"multi": multi.read_bytes(), "single": single.read_bytes()}


@settings(FUZZ, max_examples=60)
@given(data=st.binary(max_size=512), magic=st.booleans())
def test_exr_random_bytes(folder, data, magic):
    path = folder / "random.exr"
    path.write_bytes((EXR_MAGIC if magic else b"") + data)
    _read_ok_or_brdftab_error(path)


@settings(FUZZ, max_examples=300)
@given(which=st.sampled_from(["multi", "single"]), kind=st.sampled_from(["truncate", "header", "anywhere"]),
       cut=st.floats(0, 1), spots=st.lists(st.tuples(st.floats(0, 1), st.integers(1, 255)), min_size=1,
                                           max_size=8))
def test_exr_mutated_file(folder, exr_files, which, kind, cut, spots):
    data = bytearray(exr_files[which])
    if kind == "truncate":
        data = data[:int(cut * len(data))]
    else:
        span = min(len(data), 6000) if kind == "header" else len(data)  # the headers come first
        for pos, x in spots:
            data[min(int(pos * span), len(data) - 1)] ^= x
    path = folder / "mutated.exr"
    path.write_bytes(bytes(data))
    _read_ok_or_brdftab_error(path)


# --- netCDF ------------------------------------------------------------------------------------
# Random bytes behind the HDF5/CDF magic numbers, truncations anywhere, and corrupted sample
# data. (Arbitrary corruption of HDF5's own metadata is left out: that tests the HDF5 library,
# whose C code, not brdftab, would be on trial.)
NC_MAGICS = [b"\x89HDF\r\n\x1a\n", b"CDF\x01", b"CDF\x02", b""]


@pytest.fixture(scope="module")
def nc_bytes(folder):
    t = tabulate(models.create("microfacet", alpha=0.3), RusinkiewiczGrid(16, 16, 32), progress=False)
    path = folder / "valid.nc"
    brdftab.save(t, path)
    return path.read_bytes()


def _use(path):
    table = _read_ok_or_brdftab_error(path)
    if table is not None:
        table.statistics()
        table.eval([0.3, 0.1, 0.9], [-0.2, 0.0, 0.95])


@settings(FUZZ, max_examples=40)
@given(magic=st.sampled_from(NC_MAGICS), data=st.binary(max_size=512))
def test_netcdf_random_bytes(folder, magic, data):
    path = folder / "random.nc"
    path.write_bytes(magic + data)
    with pytest.raises(BrdftabError) as info:
        brdftab.open(path)
    assert "\n" not in str(info.value)


@settings(FUZZ, max_examples=30)
@given(cut=st.floats(0.0, 0.999), data_flip=st.floats(0.6, 0.99), n=st.integers(1, 4000),
       kind=st.sampled_from(["truncate", "corrupt-data"]))
def test_netcdf_mutated_file(folder, nc_bytes, cut, data_flip, n, kind):
    data = bytearray(nc_bytes)
    if kind == "truncate":
        data = data[:int(cut * len(data))]
    else:  # the compressed samples sit after HDF5's metadata, in the second half of the file
        start = int(data_flip * len(data))
        for i in range(start, min(len(data), start + n)):
            data[i] ^= 0xA5
    path = folder / "mutated.nc"
    path.write_bytes(bytes(data))
    try:
        _use(path)
    except BrdftabError as exc:
        assert "\n" not in str(exc)
