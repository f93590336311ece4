"""Session set-up for a run on several workers (pytest-xdist, ``-n 2`` in pyproject.toml).

Before the workers start, the table interpolation kernel
(:func:`brdftab._interp_kernels.table_eval`) is compiled into numba's on-disk cache for both of
its signatures (float64 and float32 values), in two processes at once. Each compile takes about
30 s (27 s here with both at once). Without this step, on a fresh checkout every worker compiles
both signatures itself within its first tests, because the workers start together and neither
finds the other's result in the cache yet. The step only fills a cache: the tests compile
whatever it misses, and a failure in it shows up in the tests, not here.
"""

from __future__ import annotations

import os
import subprocess
import sys

#: Tabulates a small Lambertian table with the value type given as argv[1] and interpolates it
#: once, which compiles the kernel for that type.
_WARM = """
import sys
import numpy as np
from brdftab.grids.rusinkiewicz import RusinkiewiczGrid
from brdftab.models import create
from brdftab.table import tabulate
table = tabulate(create("lambert", albedo=0.5), RusinkiewiczGrid(4, 4, 8), dtype=sys.argv[1], progress=False)
w = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 0.9539392014169456]])
table.eval(w, w)
"""


def pytest_configure(config):
    if hasattr(config, "workerinput"):  # a worker: the controller has done it
        return
    workers = getattr(config.option, "numprocesses", None)
    if not isinstance(workers, int) or workers < 2:
        return
    root = str(config.rootpath)
    env = dict(os.environ)
    # the brdftab the tests import (pyproject: pythonpath = ["."]); numba's cache is per file
    env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    procs = [subprocess.Popen([sys.executable, "-c", _WARM, dtype], cwd=root, env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for dtype in ("float64", "float32")]
    for p in procs:
        p.wait()
