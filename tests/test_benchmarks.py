"""The benchmark harness keeps running (speed itself is never asserted here)."""

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_run_prints_its_table_and_says_na_without_mitsubas_llvm_variant():
    # Two cheap rows, one round; a libLLVM that does not exist stands for a machine without
    # Mitsuba's LLVM variant: its column must say n/a, not crash.
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=str(ROOT / "no-such-libLLVM.so"))
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "run.py"), "--quick", "--rounds", "1",
                           "--pairs", "20000", "--only", "lambert-white|torrance-sparrow-1967"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in proc.stdout.splitlines() if line.startswith("| ") and "kernel" not in line}
    assert set(rows) == {"tabulate lambert-white.toml",
                         "model.eval torrance-sparrow-1967 (torrance-sparrow-aluminum.toml)"}, proc.stdout
    number = re.compile(r"^\d[\d.e+-]*$")
    for label, (pairs, seconds, rate, floor, mitsuba, target) in rows.items():
        assert all(number.match(x) for x in (seconds, rate, floor)), (label, proc.stdout)
    assert rows["tabulate lambert-white.toml"][0] == "1,458,000"   # the spec's MERL grid
    ts = rows["model.eval torrance-sparrow-1967 (torrance-sparrow-aluminum.toml)"]
    assert ts[4] == "n/a" and ts[5] == "≥ 0.3× Mitsuba", proc.stdout
    assert "- Mitsuba: n/a (" in proc.stdout
