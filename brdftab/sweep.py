"""Parameter sweeps: a ``[sweep]`` table expands one spec file into many.

::

    [sweep]
    "model.alpha" = [0.1, 0.2, 0.3]
    "model.n" = [1.3, 1.4, 1.5, 1.6]
    mode = "product"                  # every combination (default), or "zip": the i-th values together
    # summary = "ggx-sweep.csv"       # default: <spec stem>-sweep.csv beside the outputs (.csv or .nc)

    [[output]]
    path = "ggx-{model.alpha}-{model.n}.nc"

A swept key is the dotted path of a key of the spec: ``model.alpha``, ``grid.n_theta_h``,
``grid.wavelengths_nm``, ``validation.energy.tolerance``; the terms of a ``sum`` (``[[model.terms]]``)
and the outputs (``[[output]]``) are numbered from 0: ``model.terms[1].alpha`` (or
``model.terms.1.alpha``), ``output[0].dtype``. Each member is the spec with the swept keys set to
one combination of values, checked as any spec is: a misspelt key gives the spec's own error.

Output paths name the members: ``{KEY}`` in an ``[[output]]`` path is the member's value of the
swept key KEY, written so that file names are stable and safe (:func:`name_value`); ``{member}``
is the member's index. Two members writing the same file, or a placeholder that names no swept
key, are refused before any work.
"""

from __future__ import annotations

import copy
import itertools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from .errors import BrdftabError, SpecError
from .params import suggest, toml_value

__all__ = ["Sweep", "Member", "load", "member_spec", "count", "name_value", "parse_key", "MODES", "MAX_MEMBERS"]

MODES = ("product", "zip")
#: The most members a sweep may describe: each is a table of its own, and the members are
#: listed before the first is made (25 million took 7.6 GB before it ran out of memory).
MAX_MEMBERS = 100_000
#: Keys of ``[sweep]`` that are settings, not swept keys.
SETTINGS = ("mode", "summary")
_PLACEHOLDER = re.compile(r"\{([^{}]*)\}")
_INDEX = re.compile(r"^(.*?)\[(\d+)\]$")


@dataclass
class Member:
    """One combination of swept values: its index, ``values`` (key as spelt in ``[sweep]`` →
    value), the spec it gives (``spec``), or the error that spec raised (``error``)."""

    index: int
    values: dict
    spec: object = None
    error: BrdftabError | None = None
    outputs: list = field(default_factory=list)  # the [[output]] paths as this member writes them

    def describe(self) -> str:
        """``model.alpha = 0.1, model.n = 1.3``."""
        return ", ".join(f"{k} = {toml_value(v)}" for k, v in self.values.items())


@dataclass
class Sweep:
    """A spec file with a ``[sweep]`` table: the swept keys, the mode, the summary path and the members."""

    path: Path
    sha256: str
    keys: list
    mode: str
    summary: str | None
    members: list

    def summary_target(self, out_dir=None) -> Path:
        """Where the summary table goes: ``[sweep] summary`` (relative to the spec's folder, or
        placed in ``out_dir``), else ``<spec stem>-sweep.csv`` in the outputs' folder."""
        rel = Path(self.summary) if self.summary else Path(f"{self.path.stem}-sweep.csv")
        if rel.is_absolute():
            return rel
        return (Path(out_dir) if out_dir is not None else self.path.parent) / rel


def _fail(path, key, message):
    return SpecError(f"{path}: {key}: {message}" if key else f"{path}: {message}")


def name_value(v) -> str:
    """A swept value as it appears in a file name: stable (the shortest text that reads back
    as the same number: 0.1 → ``0.1``, 1e-05 → ``1e-05``, 2 → ``2``) and safe on every file
    system (lists joined by ``_``, characters other than letters, digits, ``.``, ``+``, ``-``
    and ``=`` replaced by ``_``).

    >>> name_value(0.1), name_value(1.5e-5), name_value([0.14, 0.37, 1.44]), name_value("a/b c")
    ('0.1', '1.5e-05', '0.14_0.37_1.44', 'a_b_c')
    """
    if isinstance(v, bool):
        text = "true" if v else "false"
    elif isinstance(v, float):
        text = repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    elif isinstance(v, int):
        text = str(v)
    elif isinstance(v, list):
        text = "_".join(name_value(x) for x in v)
    elif isinstance(v, dict):
        text = "_".join(f"{k}={name_value(x)}" for k, x in v.items())
    else:
        text = str(v)
    text = re.sub(r"[^A-Za-z0-9.+=-]", "_", text)
    return "_" + text[1:] if text.startswith(".") else text


def parse_key(key: str) -> list:
    """The path of a dotted key: ``"model.terms[1].alpha"`` (or ``"model.terms.1.alpha"``) →
    ``["model", "terms", 1, "alpha"]``."""
    parts = []
    for seg in key.split("."):
        idx = []
        m = _INDEX.match(seg)
        while m:
            idx.insert(0, int(m.group(2)))
            seg = m.group(1)
            m = _INDEX.match(seg)
        if seg:
            parts.append(int(seg) if seg.isdigit() else seg)
        elif not idx:
            return []
        parts += idx
    return parts


def _canonical(parts) -> str:
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _set(raw: dict, parts: list, value, key: str, path) -> None:
    """Set ``raw[parts...] = value``: missing tables are created (the spec's checks then name
    a misspelt key); a list is indexed by number."""
    node = raw
    for i, p in enumerate(parts):
        last = i == len(parts) - 1
        where = _canonical(parts[:i]) or "the spec"
        if isinstance(node, list):
            if not isinstance(p, int):
                raise _fail(path, f"sweep.{key}", f"{where} is a list of tables ([[{where}]]): number its entries, "
                            f"e.g. {where}[0].{p}")
            if p >= len(node):
                raise _fail(path, f"sweep.{key}", f"{where} has {len(node)} entr{'y' if len(node) == 1 else 'ies'} "
                            f"(numbered from 0), not {p + 1}")
            if last:
                node[p] = value
            else:
                node = node[p]
        elif isinstance(node, dict):
            if isinstance(p, int):
                raise _fail(path, f"sweep.{key}", f"{where} is a table, not a list: it has no entry [{p}]")
            if last:
                node[p] = value
            else:
                if p not in node:
                    node[p] = {}
                node = node[p]
        else:
            raise _fail(path, f"sweep.{key}", f"{where} is a value, not a table: it has no key '{p}'")


def _settings(raw, path):
    """(keys with their parsed paths and values, mode, summary) of ``raw["sweep"]``."""
    table = raw["sweep"]
    if not isinstance(table, dict):
        raise _fail(path, "sweep", 'expected a table [sweep] of dotted keys and their lists of values, e.g. '
                    '"model.alpha" = [0.1, 0.2]')
    mode = table.get("mode", "product")
    if mode not in MODES:
        raise _fail(path, "sweep.mode", f"expected one of {', '.join(MODES)}, got {toml_value(mode)}")
    summary = table.get("summary")
    if summary is not None:
        if not isinstance(summary, str) or not summary or "\x00" in summary:
            raise _fail(path, "sweep.summary", "expected a file path (.csv or .nc)")
        if Path(summary).suffix.lower() not in (".csv", ".nc"):
            raise _fail(path, "sweep.summary", f"a summary is written as CSV (.csv) or netCDF (.nc), not {summary}")
    keys, seen = [], {}
    for key, values in table.items():
        if key in SETTINGS:
            continue
        parts = parse_key(key)
        if not parts or (len(parts) == 1 and parts[0] not in ("description",)):
            raise _fail(path, f"sweep.{key}", f"unknown key{suggest(key, SETTINGS)}; [sweep] holds mode, summary and "
                        "dotted keys of the spec (model.…, grid.…, output[i].…, validation.…) with their lists of "
                        "values")
        if parts[0] == "sweep":
            raise _fail(path, f"sweep.{key}", "a sweep cannot sweep its own settings")
        canon = _canonical(parts)
        if canon in seen:
            raise _fail(path, f"sweep.{key}", f"the same key as {seen[canon]!r}")
        seen[canon] = key
        if not isinstance(values, list) or not values:
            raise _fail(path, f"sweep.{key}", "expected a non-empty list of values, one per member")
        keys.append((key, parts, values))
    if not keys:
        raise _fail(path, "sweep", 'no key to sweep: add one, e.g. "model.alpha" = [0.1, 0.2]')
    if mode == "zip":
        lengths = {len(v) for _, _, v in keys}
        if len(lengths) > 1:
            sizes = ", ".join(f"{k} has {len(v)}" for k, _, v in keys)
            raise _fail(path, "sweep", f'mode = "zip" takes lists of equal length: {sizes} values')
    members = _count(keys, mode)
    if members > MAX_MEMBERS:
        raise _fail(path, "sweep", f"{members} members; at most {MAX_MEMBERS} (split the sweep into several specs)")
    return keys, mode, summary


def count(raw: dict, path) -> int:
    """How many members the ``[sweep]`` of ``raw`` describes."""
    keys, mode, _ = _settings(raw, path)
    return _count(keys, mode)


def _count(keys, mode) -> int:
    return len(keys[0][2]) if mode == "zip" else math.prod(len(v) for _, _, v in keys)


def _combinations(keys, mode):
    lists = [v for _, _, v in keys]
    return list(zip(*lists)) if mode == "zip" else list(itertools.product(*lists))


def _templates(raw, keys, path) -> list:
    """``[(output index, path template)]``, every placeholder checked against the swept keys."""
    outs = raw.get("output")
    if not isinstance(outs, list):
        return []
    known = {_canonical(parts): key for key, parts, _ in keys}
    found = []
    for i, item in enumerate(outs):
        if not isinstance(item, dict) or not isinstance(item.get("path"), str):
            continue
        for name in _PLACEHOLDER.findall(item["path"]):
            parts = parse_key(name.strip())
            if name.strip() == "member" or (parts and _canonical(parts) in known):
                continue
            names = [k for k, _, _ in keys]
            raise _fail(path, f"output[{i}].path", f"{{{name}}} names no swept key{suggest(name, names)}; the "
                        f"placeholders are {', '.join('{' + k + '}' for k in names)} and {{member}}")
        found.append((i, item["path"]))
    return found


def _fill(template: str, member: Member, keys) -> str:
    by = {_canonical(parts): key for key, parts, _ in keys}

    def value(m):
        name = m.group(1).strip()
        if name == "member":
            return str(member.index)
        key = by.get(_canonical(parse_key(name)))
        return m.group(0) if key is None else name_value(member.values[key])  # unknown: refused by _templates

    return _PLACEHOLDER.sub(value, template)


def _expand(raw, path, sha):
    """(Sweep without parsed specs, [member's raw spec]), and a function that refuses output
    path templates naming unknown keys or giving two members the same file."""
    keys, mode, summary = _settings(raw, path)
    outs = raw.get("output") if isinstance(raw.get("output"), list) else []
    templates = [(i, item["path"]) for i, item in enumerate(outs)
                 if isinstance(item, dict) and isinstance(item.get("path"), str)]
    base = {k: v for k, v in raw.items() if k != "sweep"}
    members, raws = [], []
    for index, combo in enumerate(_combinations(keys, mode)):
        m = Member(index, {key: value for (key, _, _), value in zip(keys, combo)})
        r = copy.deepcopy(base)
        for (key, parts, _), value in zip(keys, combo):
            _set(r, parts, copy.deepcopy(value), key, path)
        outs = r.get("output")
        for i, template in templates:
            if isinstance(outs, list) and i < len(outs) and isinstance(outs[i], dict):
                outs[i]["path"] = _fill(template, m, keys)
                m.outputs.append(outs[i]["path"])
        members.append(m)
        raws.append(r)
    sweep = Sweep(Path(path), sha, [k for k, _, _ in keys], mode, summary, members)
    return sweep, raws, lambda: _distinct(sweep, raw, keys, templates, path)


def _distinct(sweep, raw, keys, templates, path) -> None:
    _templates(raw, keys, path)
    for i, template in templates:
        first = {}
        members = sweep.members
        for m in members:
            name = _fill(template, m, keys)
            if name in first:
                other = first[name]
                missing = [k for k, _, _ in keys if other.values[k] != m.values[k]]
                raise _fail(path, f"output[{i}].path", f"{template!r} gives the same file {name} to two members "
                            f"({other.describe()}; {m.describe()}): name {', '.join('{' + k + '}' for k in missing)} "
                            "in it")
            first[name] = m


def _member(sweep, member, raw):
    from .spec import parse_spec

    spec = parse_spec(raw, sweep.path, sweep.sha256)
    spec.sweep = {"member": member.index, "values": dict(member.values)}
    return spec


def load(path) -> Sweep:
    """Read the spec file at ``path`` and expand its ``[sweep]``: every member's spec parsed
    (``member.spec``) or its error kept (``member.error``). Errors of the sweep itself (an
    unknown setting, zip lists of unequal length, a path template that does not tell the
    members apart or names an unknown key) raise :class:`~brdftab.errors.SpecError`, and so does
    an error every member shares (a misspelt key: the spec's own message)."""
    from .spec import read_spec

    path = Path(path)
    raw, sha = read_spec(path)
    if "sweep" not in raw:
        raise _fail(path, "sweep", "no [sweep] table in this spec")
    sweep, raws, check_paths = _expand(raw, path, sha)
    for m, r in zip(sweep.members, raws):
        try:
            m.spec = _member(sweep, m, r)
        except BrdftabError as exc:
            m.error = exc
    if all(m.error is not None for m in sweep.members):
        raise sweep.members[0].error  # a misspelt key, or a spec error of every member: the spec's own line
    check_paths()
    return sweep


def member_spec(path, index: int, sha256: str | None = None):
    """The spec of member ``index`` of the sweep in ``path`` (what a worker process loads);
    ``sha256``: the file must still be the one the sweep was planned from."""
    from .spec import read_spec

    path = Path(path)
    raw, sha = read_spec(path)
    if sha256 is not None and sha != sha256:
        raise SpecError(f"{path}: the spec file changed while its sweep ran (SHA-256 {sha[:12]}…, planned from "
                        f"{sha256[:12]}…)")
    sweep, raws, _ = _expand(raw, path, sha)
    return _member(sweep, sweep.members[index], raws[index])


def is_sweep(path) -> bool:
    """Whether the spec file at ``path`` has a ``[sweep]`` table (False when unreadable: the
    spec loader then says why)."""
    from .spec import read_spec

    try:
        raw, _ = read_spec(Path(path))
    except BrdftabError:
        return False
    return "sweep" in raw


# --------------------------------------------------------------------------------------------
# the summary table

def _target(sweep, rel: str, out_dir) -> str:
    p = Path(rel)
    if p.is_absolute():
        return str(p)
    return str((Path(out_dir) if out_dir is not None else sweep.path.parent) / p)


def summary_rows(sweep, results: dict, out_dir=None) -> tuple:
    """(columns, rows) of the summary: one row per member and output — the member's index and
    swept values, the output's path, its status (``written``, ``written, checks failed``,
    ``refused`` by a check, ``error``), the largest directional albedo a(θi) with its θi and
    channel, the white-sky albedo per channel, each check's verdict, and the error. Output paths
    are relative to the summary's folder when they lie below it."""
    import os

    from .checks import CHECKS

    folder = os.path.abspath(sweep.summary_target(out_dir).parent)

    def shown(p):  # relative to the summary's folder when it lies below it (the table moves with the files)
        if not p:
            return ""
        a = os.path.abspath(p)
        return os.path.relpath(a, folder) if a.startswith(folder + os.sep) else a

    rows, checks = [], []
    for m in sweep.members:
        res = results.get(m.index) or {"error": "not run", "code": 2, "outputs": []}
        outs = list(res.get("outputs") or [])
        if res.get("error") is not None:  # nothing written: one row per output it would have written
            figures = outs[0] if outs else {}
            status = "refused" if res.get("code") == 1 and outs else "error"
            outs = [{**figures, "path": _target(sweep, rel, out_dir), "status": status} for rel in m.outputs] or \
                [{**figures, "path": "", "status": status}]
        for o in outs:
            row = {"member": m.index}
            row.update({k: m.values[k] for k in sweep.keys})
            row.update({"output": shown(o.get("path")), "status": o["status"],
                        "albedo_max": o.get("albedo_max"), "albedo_max_theta_i_deg": o.get("albedo_max_theta_i_deg"),
                        "albedo_max_channel": o.get("albedo_max_channel"),
                        "white_sky": o.get("white_sky"), "error": res.get("error") or ""})
            verdicts = o.get("verdicts") or {}
            row["verdicts"] = verdicts
            checks += [c for c in verdicts if c not in checks]
            rows.append(row)
    order = [c for c in CHECKS if c in checks] + [c for c in checks if c not in CHECKS]
    columns = (["member", *sweep.keys, "output", "status", "albedo_max", "albedo_max_theta_i_deg",
                "albedo_max_channel", "white_sky"] + [f"check_{c}" for c in order] + ["error"])
    for row in rows:
        verdicts = row.pop("verdicts")
        for c in order:
            row[f"check_{c}"] = verdicts.get(c, "")
    return columns, rows


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, dict)):
        return " ".join(_cell(x) for x in v) if isinstance(v, list) and all(
            isinstance(x, (int, float)) or x is None for x in v) else toml_value(v)
    return str(v)


def write_summary(sweep, results: dict, out_dir=None, overwrite: bool = False) -> Path:
    """Write the summary table of a finished sweep (CSV, or netCDF for a ``.nc`` path) atomically;
    returns its path. Numbers as the shortest text that reads back the same (CSV); lists (the
    white-sky albedo per channel) space-separated."""
    from ._atomic import atomic_path
    from ._locks import claim

    target = sweep.summary_target(out_dir)
    columns, rows = summary_rows(sweep, results, out_dir)
    inputs = [(sweep.path, "the spec file")]
    with claim([target], overwrite, inputs), atomic_path(target, overwrite=overwrite, inputs=inputs) as tmp:
        if target.suffix.lower() == ".nc":
            _write_nc(tmp, sweep, columns, rows)
        else:
            import csv

            with open(tmp, "w", newline="", encoding="utf-8") as fh:
                w = csv.writer(fh)
                w.writerow(columns)
                for row in rows:
                    w.writerow([_cell(row[c]) for c in columns])
    return target


def _write_nc(tmp, sweep, columns, rows) -> None:
    import numpy as np
    import xarray as xr

    data = {}
    for c in columns:
        values = [r[c] for r in rows]
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) or v is None for v in values) and \
                any(v is not None for v in values):
            data[c] = ("row", np.array([np.nan if v is None else float(v) for v in values]))
        else:
            data[c] = ("row", np.array([_cell(v) for v in values], dtype=object))
    ds = xr.Dataset(data, attrs={"title": f"brdftab sweep summary: {sweep.path.name}", "spec_file": sweep.path.name,
                                 "spec_sha256": sweep.sha256, "sweep_mode": sweep.mode,
                                 "sweep_keys": " ".join(sweep.keys)})
    ds.to_netcdf(tmp, format="NETCDF4")
