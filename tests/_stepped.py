"""A run that writes for 10 s in 0.1 s steps, reporting each step: started as a real
subprocess (a small script that registers the test format ``stepped`` and then runs the
command line), to be signalled or raced while it writes."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from pathlib import Path

TINY_GRID = '[grid]\ntype = "rusinkiewicz"\nn_theta_h = 3\nn_theta_d = 3\nn_phi_d = 4\n'

STEPPED_WRITER = textwrap.dedent("""
    import sys, time
    from brdftab import formats
    from brdftab._progress import write_step
    from brdftab.cli import main

    def stepped(table, path, **kw):
        # 10 s of writing in 0.1 s steps, reporting each step
        with open(path, "wb") as fh:
            for i in range(100):
                fh.write(b"x" * 1000)
                fh.flush()
                time.sleep(0.1)
                write_step(i + 1, 100)

    formats.register(formats.FileFormat(name="stepped", extensions=(".stepped",), description="test",
                                        read=None, write=stepped))
    main(sys.argv[1:], prog_name="brdftab")
""")


def start_stepped(tmp_path: Path, *args):
    """``brdftab tabulate s.toml --no-progress ARGS`` in ``tmp_path``, writing ``x.stepped`` (the
    spec ``s.toml`` is written unless it exists)."""
    (tmp_path / "stepped.py").write_text(STEPPED_WRITER)
    if not (tmp_path / "s.toml").exists():
        (tmp_path / "s.toml").write_text(f'[model]\nname = "lambert"\nalbedo = 0.5\n{TINY_GRID}[[output]]\n'
                                         'path = "x.stepped"\n')
    return subprocess.Popen([sys.executable, "stepped.py", "tabulate", "s.toml", "--no-progress", *args],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(tmp_path: Path, marker: str, proc, timeout=60):
    """Wait until a file whose name contains ``marker`` appears in ``tmp_path`` (``proc`` running)."""
    deadline = time.time() + timeout
    while not any(marker in p.name for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.time() < deadline, proc.communicate()
        time.sleep(0.02)
