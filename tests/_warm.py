"""Compile brdftab's numba kernels once, before the test processes start (see ``conftest.py``).

numba keeps compiled kernels on disk, next to their source, but a process that needs a kernel
before another one has written it compiles it as well. On a fresh checkout every pytest worker
and every CLI subprocess started in the suite's first minutes compiled the table interpolation
kernel again (``brdftab._interp_kernels.table_eval``: about 26 s per value type, float64 and
float32), and the RGL kernels after it: ``.ci/run`` in a fresh clone took 641 s where the same
suite with the kernels on disk took 477 s. Here each kernel is compiled once, by the CLI
commands that need it, in two processes at a time (one per value type).

Run as ``python tests/_warm.py PART FOLDER`` from the checkout (``python -m brdftab`` imports
the brdftab of its working folder first): PART is ``f64`` (a float64 table, its checks, the
RGL writer and reader) or ``f32`` (a float32 table, its checks and resampling from it).
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
path = "warm-{part}.nc"
dtype = "{dtype}"
"""

COARSE = '{type = "rusinkiewicz", n_theta_h = 8, n_theta_d = 8, n_phi_d = 16}'


def commands(part: str, folder: Path) -> list:
    nc = folder / f"warm-{part}.nc"
    first = ["tabulate", str(folder / f"warm-{part}.toml"), "--overwrite"]
    if part == "f64":
        return [first, ["convert", str(nc), str(folder / "warm.bsdf"), "--overwrite"],
                ["validate", str(folder / "warm.bsdf")]]
    return [first, ["convert", str(nc), str(folder / "warm-coarse.nc"), "--grid", COARSE, "--overwrite"]]


def main(part: str, folder: str) -> int:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"warm-{part}.toml").write_text(SPEC.format(part=part, dtype="float64" if part == "f64" else "float32"))
    for args in commands(part, folder):
        proc = subprocess.run([sys.executable, "-m", "brdftab", *args], capture_output=True, text=True)
        if proc.returncode not in (0, 1):  # 1: a check failed, the kernels ran all the same
            sys.stderr.write(f"brdftab {' '.join(args)}: exit {proc.returncode}: {proc.stderr.strip()[-500:]}\n")
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
