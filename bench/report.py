"""Run time against error of every kernel: ``tactile-mirror bench`` from a source tree.

    python bench/report.py [--quick] [--kernels filters,detector] [--out DIR]

Writes ``bench_report.md`` (tables), ``bench_pareto.png`` (one panel per kernel, error
against run time, Pareto-optimal variants highlighted) and ``bench_report.json`` into
DIR; see :mod:`tactile_mirror.lab.benchmark` for what is measured.
"""
from __future__ import annotations

import os
import sys

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from tactile_mirror.cli import main  # after the thread settings

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
