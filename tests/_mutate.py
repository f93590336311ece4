"""Damaged copies of a text file for parser fuzz tests: words replaced by junk tokens, lines
deleted or duplicated at random (1–3 edits a copy)."""

from __future__ import annotations

import numpy as np


def mutations(lines, junk, n, seed=7, head=None):
    """``n`` mutated texts of ``lines``; with ``head``, six edits in ten fall on the first
    ``head`` lines (where a header's counts and flags are)."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        mutated = list(lines)
        for _ in range(rng.integers(1, 4)):
            if head is None:
                k = int(rng.integers(len(mutated)))
            else:
                k = int(rng.integers(min(len(mutated), head)) if rng.random() < 0.6 else rng.integers(len(mutated)))
            words = mutated[k].split()
            if words:
                words[int(rng.integers(len(words)))] = str(rng.choice(junk))
            op = rng.integers(3)
            if op == 0:
                mutated[k] = " ".join(words)
            elif op == 1:
                del mutated[k]
            else:
                mutated.insert(k, " ".join(words))
        yield "\n".join(mutated)
