"""The ``bench`` command: run time against error of every kernel (markdown table, Pareto plot)."""
from __future__ import annotations

import argparse

from tactile_mirror.cli.arguments import add_command, out_folder

__all__ = ["add_parser", "cmd_bench"]


def _bench_kernels(text):
    from tactile_mirror.lab.benchmark import KERNELS

    names = [k.strip() for k in text.split(",") if k.strip()]
    if names == ["all"]:
        return list(KERNELS)
    bad = [k for k in names if k not in KERNELS]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(KERNELS)} (or all), "
                                         f"got {text!r}")
    return names


def cmd_bench(args) -> int:
    """``tactile-mirror bench``: time every kernel's variants against their error; the report
    (markdown, plot, JSON) in ``--out``. Returns the exit status."""
    from tactile_mirror.lab.benchmark import JSON_NAME, MD_NAME, PNG_NAME, bench_report

    out = out_folder(args.out)
    print(f"tactile-mirror bench: {', '.join(args.kernels)} ({'quick' if args.quick else 'full'} run); "
          f"output folder {out}/")
    report = bench_report(out, kernels=args.kernels, quick=args.quick, progress=True)
    for k in report.kernels.values():
        best = "; ".join(v.label for v in k.variants if v.pareto)
        print(f"{k.name}: {len(k.variants)} variants, Pareto-optimal: {best}")
    print(f"wrote {out / MD_NAME}, {out / PNG_NAME}, {out / JSON_NAME} ({report.seconds:.0f} s)")
    return 0


def add_parser(sub) -> None:
    """Add ``bench`` to the ``tactile-mirror`` subcommands ``sub``."""
    p = add_command(sub, "bench", cmd_bench,
                    help="run time against error of every kernel: markdown table and Pareto plot",
                    description="Time every kernel (filters, stress-rate estimator, slip detector, contact "
                                "model) in several variants and measure each variant's error against a "
                                "reference computed in the same run; write bench_report.md, "
                                "bench_pareto.png and bench_report.json. The full run takes a few minutes "
                                "(set OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 on small machines).")
    p.add_argument("--out", default="bench-report", help="output folder (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="small sizes, fewer mesh sizes: a smoke run (~20 s)")
    p.add_argument("--kernels", type=_bench_kernels, default="all",
                   help="comma-separated subset of filters,estimator,detector,contact (default: all)")
