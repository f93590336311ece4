"""Docs that name code: every ``brdftab.…`` a docstring or a format document points at exists."""

import importlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REF = re.compile(r":(?:mod|func|class|data|meth|attr):`~?(brdftab(?:\.\w+)+)`|``(brdftab(?:\.\w+)+)``")


def resolves(name: str) -> bool:
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        try:
            for a in parts[k:]:
                obj = getattr(obj, a)
        except AttributeError:
            return False
        return True
    return False


def test_every_named_module_and_object_exists():
    sources = list((ROOT / "brdftab").rglob("*.py")) + list((ROOT / "formats").glob("*.md")) + [ROOT / "README.md"]
    missing = []
    for path in sources:
        for m in REF.finditer(path.read_text(encoding="utf-8")):
            name = m.group(1) or m.group(2)
            if not resolves(name):
                missing.append(f"{path.relative_to(ROOT)}: {name}")
    assert not missing, "docs name what does not exist:\n" + "\n".join(missing)
    # the test can fail: a made-up name does not resolve
    assert not resolves("brdftab.models.shadowing") and resolves("brdftab.models.components")
