"""Helpers shared by the benchmark scripts (run as ``python bench/<script>.py``)."""
from __future__ import annotations

import time

import numpy as np


def best_time(fn, repeat: int = 5) -> float:
    """Shortest wall time of ``repeat`` calls of ``fn``, s."""
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def timed(fn, repeat: int = 3, clock=time.perf_counter):
    """``(shortest time, last result)`` of ``repeat`` calls of ``fn``; ``clock`` is
    wall time by default, ``time.process_time`` for this process's CPU time (robust
    on a shared machine)."""
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = clock()
        out = fn()
        best = min(best, clock() - t0)
    return best, out


def table(title: str, header, rows) -> None:
    """Print a markdown table under a heading."""
    print(f"\n### {title}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---" for _ in header) + "|")
    for r in rows:
        print("| " + " | ".join(str(c) for c in r) + " |")
