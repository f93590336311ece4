"""Benchmark: start-up of the command line against a bare ``import numpy``.

Run from the repository root::

    python benchmarks/bench_startup.py [--repeat 10]

Each command is started as a new process (``sys.executable``, this checkout first on
``PYTHONPATH``, bytecode already cached by one warm-up run each) and timed from its start to
its exit, wall clock. The commands run in turn — numpy, then each brdftab command, round after
round — so that a change in the machine's load touches them alike; each command's ratio to the
numpy import is taken within its round, and the median over the rounds is printed.

Commands: ``brdftab --version``, ``brdftab --help``, ``brdftab convert --help`` (help that names
the formats) and ``brdftab models`` (a verb that loads its models), against
``python -c "import numpy"``. The target for ``--version`` and ``--help`` is < 3× the numpy
import.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

COMMANDS = {
    "brdftab --version": ["-m", "brdftab", "--version"],
    "brdftab --help": ["-m", "brdftab", "--help"],
    "brdftab convert --help": ["-m", "brdftab", "convert", "--help"],
    "brdftab models": ["-m", "brdftab", "models"],
}
NUMPY = ["-c", "import numpy"]


def _wall(args, env) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, *args], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                   check=True)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10, help="rounds (default 10)")
    repeat = parser.parse_args().repeat
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    for args in [NUMPY, *COMMANDS.values()]:  # warm-up: bytecode compiled and cached
        _wall(args, env)
    times = {name: [] for name in ["import numpy", *COMMANDS]}
    ratios = {name: [] for name in COMMANDS}
    for _ in range(repeat):
        base = _wall(NUMPY, env)
        times["import numpy"].append(base)
        for name, args in COMMANDS.items():
            t = _wall(args, env)
            times[name].append(t)
            ratios[name].append(t / base)
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores, {repeat} rounds; wall seconds per process")
    print(f"{'command':<28} {'median s':>9} {'min s':>7} {'ratio to import numpy (median)':>32}")
    for name, ts in times.items():
        ratio = f"{statistics.median(ratios[name]):.2f}x" if name in ratios else "1"
        print(f"{name:<28} {statistics.median(ts):>9.3f} {min(ts):>7.3f} {ratio:>32}")
    worst = max(statistics.median(ratios[n]) for n in ("brdftab --version", "brdftab --help"))
    print(f"target --version/--help < 3x import numpy: {'PASS' if worst < 3 else 'MISS'} ({worst:.2f}x)")


if __name__ == "__main__":
    main()
