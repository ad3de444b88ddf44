"""Run time against error of every kernel: ``tactile-mirror bench`` from a source tree.

    python bench/report.py [--quick] [--kernels filters,detector] [--out DIR]

Writes ``bench_report.md`` (tables), ``bench_pareto.png`` (one panel per kernel, error
against run time, Pareto-optimal variants highlighted) and ``bench_report.json`` into
DIR; see :mod:`tactile_mirror.lab.benchmark` for what is measured. ``main`` returns the
smallest error among the first kernel's variants (from ``bench_report.json``).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from tactile_mirror.cli import main as cli_main  # after the thread settings
from tactile_mirror.lab.benchmark import JSON_NAME
from tactile_mirror.lab.measure import environment_line


def main(argv=None) -> float:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(add_help=False)  # only to know the folder; the command parses the rest
    ap.add_argument("--out", default="bench-report")
    known, _ = ap.parse_known_args(argv)
    print(f"# {environment_line()}")
    status = cli_main(["bench", *argv])
    if status:
        raise SystemExit(status)
    with open(os.path.join(known.out, JSON_NAME), encoding="utf-8") as fh:
        kernels = json.load(fh)["kernels"]
    first = next(iter(kernels.values()))
    return min(v["error"] for v in first["variants"])


if __name__ == "__main__":
    main()
