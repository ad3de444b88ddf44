"""Helpers of the benchmark scripts (run as ``python bench/<script>.py``).

The measuring functions themselves live in :mod:`tactile_mirror.measure`, shared with
``tactile-mirror bench``; this module only names them for the scripts and prints.
"""
from __future__ import annotations

from tactile_mirror.measure import best_time, best_times, environment_line, markdown_table, timed

__all__ = ["best_time", "best_times", "environment_line", "header", "table", "timed"]


def table(title: str, header, rows) -> None:
    """Print a markdown table under a heading."""
    print(markdown_table(title, header, rows))


def header(what: str) -> None:
    """Print what is measured and where (versions, SIMD path, CPU model, threads)."""
    print(f"# {what}\n# {environment_line()}")
