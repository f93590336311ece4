"""brdftab's speed in one table: the kernels every job rides on, against the numpy floor and Mitsuba 3.

Run from the repository root (standalone; not part of the test suite)::

    python benchmarks/run.py                  # every row, 6-9 min on a busy 2-core machine
    python benchmarks/run.py --quick          # fewer pairs and rounds
    python benchmarks/run.py --only "ggx|start-up"

Rows (1 M random upper-hemisphere pairs, uniform in solid angle, float64 ``(N, 3)`` arrays):

* **model.eval** of GGX α 0.3 + conductor Fresnel (gold, RGB), and of every registered seed
  model with the parameters of its shipped spec (``brdftab.from_spec``; the first spec per
  model name). Slow models evaluate fewer pairs (about one second's worth, at least 20 k) and
  are compared by rate. Anchor: Mitsuba 3 ``llvm_ad_rgb`` ``roughconductor`` (GGX, the same α,
  η and k) on the 1 M pairs, numpy arrays in and out as a Python user calls it.
* **RGL .bsdf eval**: ``brdftab.open(f).eval`` of a ``.bsdf`` file (the GGX model exported by
  ``brdftab.save``, or ``--bsdf FILE``); **Table.eval** of the GGX model tabulated on the MERL
  grid. Anchor: Mitsuba's ``measured`` plugin on the same file and pairs.
* **tabulate**: ``brdftab.tabulate`` of the GGX model on the MERL grid, and of every spec in
  ``specs/`` on its own grid (tabulation only: no checks, no file).
* **validate**: ``brdftab validate FILE`` (default checks, a subprocess) of an anisotropic
  45 × 90 × 45 × 90 (θh × φh × θd × φd) float32 grey table of GGX (αx 0.2, αy 0.4,
  dielectric Fresnel, n 1.5): 16.4 M samples.
* **start-up**: ``python -m brdftab --version`` and ``--help`` against
  ``python -c "import numpy"`` (subprocesses, bytecode cached by a warm-up run).

Columns: ``× floor`` = our time / the numpy floor's time over as many pairs (the floor is
``h = normalize(wi + wo)``; for start-up rows, the bare numpy import): lower is better.
``× Mitsuba`` = our pairs/s / Mitsuba's pairs/s: higher is better. Each ratio is the median of
the rounds' ratios; a round times ours, then each anchor, in turn, so load changes hit both
sides (ratios swing about ±25 % with the machine's load). ``target`` is the goal for the row
and whether this run meets it.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's brdftab, not an installed one
sys.path.insert(0, str(Path(__file__).resolve().parent))

import brdftab  # noqa: E402  (after the sys.path lines above)
from _timing import GOLD, hemisphere_pairs  # noqa: E402
from brdftab.grids import RusinkiewiczGrid, merl_grid  # noqa: E402

SPECS = ROOT / "specs"
LLVM = "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
ALPHA = 0.3
#: Seed specs whose model another row already times (GGX) or that time nothing (Lambert).
NOT_SEEDS = ("microfacet", "lambert")


@dataclass
class Side:
    """One timed call and the pairs it evaluates (None: not a pair kernel)."""
    fn: Callable[[], object]
    pairs: int | None = None


@dataclass
class Row:
    label: str
    prepare: Callable[[], Side]    # builds the fixtures (untimed), returns our timed call
    anchors: tuple = ("floor",)    # names in Bench.anchor: "floor", "mitsuba-ggx", "mitsuba-measured", "numpy"
    target: tuple | None = None    # (anchor, "<" or ">=", value)


@dataclass
class Result:
    row: Row
    ours: list = field(default_factory=list)     # seconds per round
    pairs: int | None = None
    ratio: dict = field(default_factory=dict)    # anchor -> median ratio (None: anchor not available)
    error: str = ""


def ggx_model():
    return brdftab.models.create("microfacet", distribution="ggx", alpha=ALPHA, fresnel="conductor", **GOLD)


def timed(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def python(*args):
    """A subprocess of this interpreter that must succeed, as a timed call's body."""
    path = [str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(path))
    return lambda: subprocess.run([sys.executable, *args], check=True, capture_output=True, env=env)


class Mitsuba:
    """Mitsuba 3's LLVM variant as an anchor, or the reason it is not available."""

    def __init__(self):
        self.mi, self.why = None, ""
        if Path(LLVM).exists():
            os.environ.setdefault("DRJIT_LIBLLVM_PATH", LLVM)
        try:
            import mitsuba as mi

            mi.set_variant("llvm_ad_rgb")
            self.mi, self.version = mi, mi.__version__
        except Exception as exc:  # not installed, no LLVM variant, no libLLVM: the columns say n/a
            self.why = f"{type(exc).__name__}: {exc}".splitlines()[0]

    def roughconductor(self):
        return self.mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": ALPHA,
                                  "eta": {"type": "rgb", "value": GOLD["n"]},
                                  "k": {"type": "rgb", "value": GOLD["k"]}})

    def measured(self, path):
        return self.mi.load_dict({"type": "measured", "filename": str(path)})

    def eval(self, bsdf, wi, wo):
        """f·cosθo at the pairs, numpy in and out (waits for Dr.Jit's asynchronous result)."""
        mi = self.mi
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])
        return np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2])))

    def agreement(self, bsdf, brdf, wi, wo, max_theta_o=np.pi / 2):
        """How Mitsuba's f (its f·cosθo / cosθo) and ``brdf``'s differ, both at the
        float32-rounded directions Mitsuba sees, over pairs with θo ≤ ``max_theta_o``:
        a sentence giving the median and the largest relative difference (where ours is not 0)
        and the largest difference over the peak of f."""
        wi, wo = (w.astype(np.float32).astype(np.float64) for w in (wi, wo))
        keep = wo[:, 2] >= np.cos(max_theta_o)
        ours = brdf.eval(wi, wo)[keep]
        diff = np.abs(self.eval(bsdf, wi, wo).T[keep] / wo[keep, 2:] - ours)
        rel = diff[ours > 0] / ours[ours > 0]
        return (f"relative difference median {np.median(rel):.1e}, max {rel.max():.1e}; "
                f"max difference / peak {diff.max() / ours.max():.1e}")


class Bench:
    """The fixtures the rows share, each built on first use."""

    def __init__(self, args, tmp: Path):
        self.args = args
        self.n = args.pairs
        self.tmp = tmp                 # the files the rows write (removed at the end)
        self.notes = []

    @functools.cached_property
    def pool(self):
        return hemisphere_pairs(self.n)

    @functools.cached_property
    def mitsuba(self):
        m = Mitsuba()
        self.notes.append(f"Mitsuba {m.version}, llvm_ad_rgb" if m.mi else f"Mitsuba: n/a ({m.why})")
        return m

    @functools.cached_property
    def ggx(self):
        return ggx_model()

    @functools.cached_property
    def bsdf_path(self):
        if self.args.bsdf:
            return Path(self.args.bsdf)
        path = self.tmp / "ggx.bsdf"
        brdftab.save(self.ggx, path)
        return path

    @functools.cached_property
    def mi_ggx(self):
        m = self.mitsuba
        if not m.mi:
            return None
        bsdf = m.roughconductor()
        self.notes.append(f"Mitsuba roughconductor vs brdftab GGX conductor, f at {self.n:,} pairs: "
                          + m.agreement(bsdf, self.ggx, *self.pool))
        return bsdf

    @functools.cached_property
    def mi_measured(self):
        m = self.mitsuba
        if not m.mi:
            return None
        bsdf = m.measured(self.bsdf_path)
        ours = brdftab.open(self.bsdf_path)
        hold = ours.theta_hold
        self.notes.append(f"Mitsuba measured vs brdftab's reader of {self.bsdf_path.name}, f at θo ≤ "
                          f"{np.degrees(hold):.4g}° (beyond, the reader holds f: formats/rgl-bsdf.md): "
                          + m.agreement(bsdf, ours, *self.pool, max_theta_o=hold))
        return bsdf

    def floor(self, pairs):
        """normalize(wi + wo) over ``pairs`` pairs in one pass (the pool's, repeated when
        ``pairs`` exceeds it): per pair, a large pass costs more than a cached one."""
        wi, wo = (w[:pairs] if pairs <= self.n else np.resize(w, (pairs, 3)) for w in self.pool)

        def run():
            h = wi + wo
            h /= np.sqrt(np.einsum("ij,ij->i", h, h))[:, None]
        return run

    def anchor(self, name, pairs):
        """The anchor's timed call over ``pairs`` pairs (at least the pool's: a model row that
        evaluates fewer pairs is compared by rate), or None if the anchor is not available."""
        if name == "floor":
            n = max(pairs, self.n)
            return Side(self.floor(n), n)
        if name == "numpy":
            return Side(python("-c", "import numpy"))
        bsdf = self.mi_ggx if name == "mitsuba-ggx" else self.mi_measured
        if bsdf is None:
            return None
        return Side(functools.partial(self.mitsuba.eval, bsdf, *self.pool), self.n)

    # --- our calls -------------------------------------------------------------------------

    def model_eval(self, model):
        """``model.eval`` over the pool, or over about a second's worth of it for a slow model."""
        wi, wo = self.pool
        probe = min(self.n, 20_000)
        model.eval(wi[:probe], wo[:probe])  # first use: compiled kernels load (or compile) here
        rate = probe / timed(lambda: model.eval(wi[:probe], wo[:probe]))
        n = int(min(self.n, max(probe, rate * self.args.seconds)))
        return Side(lambda: model.eval(wi[:n], wo[:n]), n)

    def pair_eval(self, brdf):
        wi, wo = self.pool
        return Side(lambda: brdf.eval(wi, wo), self.n)

    def tabulation(self, model, grid, wavelengths=None):
        return Side(lambda: brdftab.tabulate(model, grid, wavelengths, progress=False), grid.size)

    @functools.cached_property
    def merl_table(self):
        return brdftab.tabulate(self.ggx, merl_grid(), progress=False)

    def validate(self):
        grid = RusinkiewiczGrid(45, 45, 90, 90)   # θh, θd, φd, φh
        model = brdftab.models.create("microfacet", alpha_x=0.2, alpha_y=0.4, fresnel="dielectric", n=1.5)
        path = self.tmp / "aniso.nc"
        brdftab.save(model, path, grid=grid, dtype="float32")
        run = python("-m", "brdftab", "validate", "--quiet", str(path))

        def call():  # exit 1 (a check failed) is still a validation; 2 is not
            try:
                run()
            except subprocess.CalledProcessError as exc:
                if exc.returncode != 1:
                    raise
        return Side(call, grid.size)


def seed_specs():
    """(spec path, model name): the first shipped spec of each registered seed model."""
    seen = {}
    for path in sorted(SPECS.glob("*.toml")):
        name = brdftab.load_spec(path).model.name
        if name not in NOT_SEEDS:
            seen.setdefault(name, path)
    return [(p, name) for name, p in seen.items()]


def rows(b: Bench):
    """Every row, kernels first; fixtures are built only for the rows selected."""
    out = [
        Row("model.eval microfacet GGX α0.3 conductor RGB", lambda: b.pair_eval(b.ggx),
            ("floor", "mitsuba-ggx"), ("mitsuba-ggx", ">=", 0.4)),
        Row("RGL .bsdf brdftab.open(f).eval", lambda: b.pair_eval(brdftab.open(b.bsdf_path)),
            ("floor", "mitsuba-measured"), ("mitsuba-measured", ">=", 0.4)),
        Row("Table.eval MERL grid RGB", lambda: b.pair_eval(b.merl_table),
            ("floor", "mitsuba-measured"), ("mitsuba-measured", ">=", 0.3)),
    ]
    targets = {"torrance-sparrow-1967": 0.3, "cook-torrance-alpha-theta": 0.3, "zernike-expansion": 0.1,
               "he-torrance-1991": 0.05, "he-torrance-modified": 0.05, "solar-cell-small2021": 0.05,
               "pyramid-microfacet": 0.015}   # × Mitsuba's GGX rate
    order = list(targets)
    for path, name in sorted(seed_specs(), key=lambda s: (order.index(s[1]) if s[1] in order else len(order))):
        out.append(Row(f"model.eval {name} ({path.name})",
                       lambda path=path: b.model_eval(brdftab.from_spec(path)),
                       ("floor", "mitsuba-ggx"), ("mitsuba-ggx", ">=", targets[name]) if name in targets else None))
    out.append(Row("tabulate GGX α0.3 conductor, MERL grid", lambda: b.tabulation(b.ggx, merl_grid()),
                   target=("floor", "<", 1.0)))
    for path in sorted(SPECS.glob("*.toml")):
        def spec_tabulation(path=path):
            spec = brdftab.load_spec(path)
            return b.tabulation(spec.model, spec.grid, spec.wavelengths)
        out.append(Row(f"tabulate {path.name}", spec_tabulation))
    out += [
        Row("brdftab validate aniso 45x90x45x90 float32", b.validate, target=("floor", "<", 10.0)),
        Row("start-up: brdftab --version", lambda: Side(python("-m", "brdftab", "--version")), ("numpy",),
            ("numpy", "<", 3.0)),
        Row("start-up: brdftab --help", lambda: Side(python("-m", "brdftab", "--help")), ("numpy",),
            ("numpy", "<", 3.0)),
    ]
    return out


def measure(b: Bench, row: Row) -> Result:
    """Rounds that time ours and then each anchor; ratios are medians over the rounds."""
    res = Result(row)
    ours = row.prepare()
    res.pairs = ours.pairs
    anchors = {name: b.anchor(name, ours.pairs or 0) for name in row.anchors}
    live = {name: a for name, a in anchors.items() if a is not None}
    for side in (ours, *live.values()):   # warm-up: first-use set-up, caches, compilation
        side.fn()
    rounds, times = b.args.rounds, {name: [] for name in live}
    r = 0
    while r < rounds:
        res.ours.append(timed(ours.fn))
        for name, side in live.items():
            times[name].append(timed(side.fn))
        if r == 0:  # a row gets at most its time budget (at least one round)
            spent = res.ours[0] + sum(t[0] for t in times.values())
            rounds = max(1, min(rounds, int(b.args.budget // spent)))
        r += 1
    for name in row.anchors:
        if name not in live:
            res.ratio[name] = None
        elif name.startswith("mitsuba"):   # speed ratio: our pairs/s over Mitsuba's
            res.ratio[name] = statistics.median(
                (ours.pairs / t) / (live[name].pairs / a) for t, a in zip(res.ours, times[name]))
        else:                              # time ratio: our time over the anchor's, per pair
            per = (ours.pairs / live[name].pairs) if ours.pairs else 1.0
            res.ratio[name] = statistics.median(t / (a * per) for t, a in zip(res.ours, times[name]))
    return res


def fmt_target(row: Row, res: Result):
    if not row.target:
        return ""
    anchor, op, value = row.target
    what = {"floor": "floor", "numpy": "numpy", "mitsuba-ggx": "Mitsuba", "mitsuba-measured": "Mitsuba"}[anchor]
    text = f"{'≥' if op == '>=' else '<'} {value:g}× {what}"
    got = res.ratio.get(anchor)
    if got is None:
        return text
    met = got >= value if op == ">=" else got < value
    return f"{text}: {'yes' if met else 'no'}"


def table(results):
    head = ("kernel", "pairs", "ours s", "M pairs/s", "× floor", "× Mitsuba", "target")
    lines = []
    for res in results:
        row = res.row
        if res.error:
            lines.append((row.label, "", "", "", "", "", f"error: {res.error}"))
            continue
        t = statistics.median(res.ours)
        rate = f"{res.pairs / t / 1e6:.3g}" if res.pairs else ""
        floor = res.ratio.get("floor", res.ratio.get("numpy"))
        mits = [v for k, v in res.ratio.items() if k.startswith("mitsuba")]
        lines.append((row.label, f"{res.pairs:,}" if res.pairs else "", f"{t:.3g}", rate,
                      "" if floor is None else f"{floor:.3g}",
                      ("n/a" if mits[0] is None else f"{mits[0]:.3g}") if mits else "",
                      fmt_target(row, res)))
    widths = [max(len(str(x)) for x in col) for col in zip(head, *lines)]
    out = ["| " + " | ".join(h.ljust(w) for h, w in zip(head, widths)) + " |",
           "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    out += ["| " + " | ".join(str(c).ljust(w) for c, w in zip(line, widths)) + " |" for line in lines]
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="100 k pairs, 3 rounds, ~5 s per row")
    ap.add_argument("--only", metavar="PATTERN", help="rows whose label matches this regular expression")
    ap.add_argument("--bsdf", metavar="FILE", help="the .bsdf file of the RGL rows (default: GGX exported)")
    ap.add_argument("--pairs", type=int, help="pairs per model row (default 1,000,000)")
    ap.add_argument("--rounds", type=int, help="rounds per row (default 5)")
    ap.add_argument("--budget", type=float, help="seconds per row: fewer rounds beyond it (default 60)")
    args = ap.parse_args(argv)
    quick = {"pairs": 100_000, "rounds": 3, "budget": 5.0, "seconds": 0.25}
    full = {"pairs": 1_000_000, "rounds": 5, "budget": 60.0, "seconds": 1.0}
    for key, value in (quick if args.quick else full).items():
        if getattr(args, key, None) is None:
            setattr(args, key, value)
    warnings.simplefilter("ignore")   # the models' own warnings (e.g. fit ranges) are not the benchmark's

    try:
        only = re.compile(args.only or "", re.IGNORECASE)
    except re.error as exc:
        ap.error(f"--only: {exc}")
    with tempfile.TemporaryDirectory(prefix="brdftab-bench-") as tmp:
        b = Bench(args, Path(tmp))
        selected = [r for r in rows(b) if only.search(r.label)]
        if not selected:
            ap.error(f"no row matches {args.only!r}")
        import numba

        start = os.getloadavg()
        print(f"brdftab {brdftab.__version__}, numpy {np.__version__}, numba {numba.__version__}, "
              f"Python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} CPUs, "
              f"{args.pairs:,} pairs, {args.rounds} rounds, {args.budget:g} s per row", flush=True)
        results = []
        for row in selected:
            print(f"  {row.label} ...", file=sys.stderr, flush=True)
            try:
                results.append(measure(b, row))
            except Exception as exc:  # one broken row does not hide the others
                results.append(Result(row, error=f"{type(exc).__name__}: {exc}".splitlines()[0]))
    print(table(results))
    for note in b.notes:
        print(f"- {note}")
    end = os.getloadavg()
    print(f"- load average (1, 5, 15 min) at start {start[0]:.2f} {start[1]:.2f} {start[2]:.2f}, "
          f"at end {end[0]:.2f} {end[1]:.2f} {end[2]:.2f}")
    return 1 if any(r.error for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
