"""Compile brdftab's numba kernels once, before the test processes start (see ``conftest.py``).

numba keeps compiled kernels on disk, next to their source, but a process that needs a kernel
before another one has written it compiles it as well. On a fresh checkout every pytest worker
and every CLI subprocess started in the suite's first minutes compiled the table interpolation
kernel again (``brdftab._interp_kernels.table_eval``: about 26 s per value type, float64 and
float32), and the RGL kernels after it: ``.ci/run`` in a fresh clone took 641 s where the same
suite with the kernels on disk took 477 s. Here each kernel is compiled once, by the commands
that need it, in three processes at a time that share as few kernels as they can.

Run as ``python tests/_warm.py PART FOLDER`` from the checkout (``python -m brdftab`` imports
the brdftab of its working folder first). PART is ``f64`` (a float64 table tabulated, with its
checks, then resampled by ``convert`` onto a coarse grid, written although it misrepresents the
table: the table kernel for float64 values), ``f32`` (a float32 table evaluated, then
validated: the table kernel for float32 values) or ``rgl`` (a model tabulated into an RGL
``.bsdf`` file and validated: the RGL writer and reader). Every command must exit 0: a failed
check would be a change in brdftab that the tests report, not a warm-up's business.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SPEC = """\
[model]
name = "microfacet"
distribution = "ggx"
alpha = 0.3
fresnel = "schlick"
f0 = [0.9, 0.6, 0.3]

[grid]
type = "rusinkiewicz"
n_theta_h = 16
n_theta_d = 16
n_phi_d = 32

[[output]]
path = "{output}"
"""

COARSE = '{type = "rusinkiewicz", n_theta_h = 8, n_theta_d = 8, n_phi_d = 16}'

#: A float32 table made and evaluated without a check, so that this process compiles the table
#: kernel for float32 values and not the float64 one (the checks of ``tabulate`` evaluate the
#: float64 table in memory, which the f64 part compiles at the same time).
FLOAT32 = """\
import sys, numpy as np, brdftab
from brdftab import models
from brdftab.grids import RusinkiewiczGrid
brdftab.save(models.create("lambert", albedo=0.5), sys.argv[1], grid=RusinkiewiczGrid(16, 16, 32), dtype="float32")
w = np.array([[0.0, 0.6, 0.8]])
brdftab.open(sys.argv[1]).eval(w, w[:, [1, 0, 2]])
"""


def commands(part: str, folder: Path) -> list:
    """The commands of ``part``, as argument lists."""
    cli = [sys.executable, "-m", "brdftab"]
    if part == "f64":
        (folder / "warm.toml").write_text(SPEC.format(output="warm.nc"))
        return [cli + ["tabulate", str(folder / "warm.toml"), "--overwrite"],
                cli + ["convert", str(folder / "warm.nc"), str(folder / "warm-coarse.nc"), "--grid", COARSE,
                       "--overwrite", "--allow-invalid"]]  # (the coarse grid misrepresents the table)
    if part == "rgl":
        (folder / "warm.toml").write_text(SPEC.format(output="warm.bsdf"))
        return [cli + ["tabulate", str(folder / "warm.toml"), "--overwrite"],
                cli + ["validate", str(folder / "warm.bsdf")]]
    nc = folder / "warm-f32.nc"
    return [[sys.executable, "-c", FLOAT32, str(nc)], cli + ["validate", str(nc)]]


def main(part: str, folder: str) -> int:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for args in commands(part, folder):
        proc = subprocess.run(args, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.stderr.write(f"{' '.join(args[1:])}: exit {proc.returncode}: {proc.stderr.strip()[-500:]}\n")
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
