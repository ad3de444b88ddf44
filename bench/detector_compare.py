"""Filter-bank nets side by side on validation scenes that chose nothing: detection, false alarms and latency.

A training recipe is compared with the bundled net on a part of the build's validation
scenes (seed ``build_options.VALIDATION_SEED``) that neither the recipe's selection and calibration
nor the bundled net's used (the bundled net was kept and calibrated on scenes 1-120 and
1-480; a study build made with ``--n-validation 240`` saw scenes 1-240, so the default part
here is 241-480). For each net and sensor condition (noise-free, 1 mV rms white), it prints:

- at the net's own decision point, ``y_slip >= 0.8``: detection, false alarms, gradual
  onsets found and their mean latency;
- along the threshold sweep, at 1 / 2 / 3 % false alarms: detection, all (gradual), and the
  gradual onsets' mean latency;
- the gradual onsets' latency on the onsets *every* net finds at 2 % false alarms (a net that
  finds more of the hard, late onsets has a longer mean latency over its own detections; over
  the common ones the nets are compared on the same slips).

The held-out seed is not used. Run: ``python bench/detector_compare.py --cache out/scenes
--weights out/study/a.npz [b.npz ...] [--part 241 480]`` (``--quick``: validation scenes 1-8, simulated
here, a smoke run of a few seconds). ``main`` returns the bundled net's detection rate at 2 % false
alarms, noise-free.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from tactile_mirror.cli.arguments import add_workers_options, open_workers


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes", help="directory of cached simulated scenes")
    ap.add_argument("--weights", nargs="+", required=True, help="filter-bank weights files to compare")
    ap.add_argument("--part", nargs=2, type=int, default=None, metavar=("FIRST", "LAST"),
                    help="validation scenes reported on, 1-based and inclusive (default: 241 480; "
                         "--quick: 1 8)")
    ap.add_argument("--quick", action="store_true", help="validation scenes 1-8 simulated here (a smoke run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    first, last = args.part or ((1, 8) if args.quick else (241, 480))
    if not 1 <= first <= last:
        ap.error(f"--part must be FIRST <= LAST, both >= 1, got {first} {last}")
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

    from common import bank_validation_conditions, header, simulated
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.lab.detector import build_options
    from tactile_mirror.lab.detector.thresholds import roc

    t0 = time.perf_counter()
    header(f"filter-bank nets on validation scenes {first}-{last} (seed {build_options.VALIDATION_SEED})")
    with open_workers(args) as executor:
        val = simulated(last, build_options.VALIDATION_SEED, build_options.TEST_KWARGS, args.cache, quick=args.quick,
                        executor=executor)[first - 1:]
    nets = {"bundled net": SlipDetector.default()}
    for path in args.weights:
        nets[os.path.basename(path)] = SlipDetector.load(path)
    est = nets["bundled net"].metadata.get("estimator")
    conds = bank_validation_conditions(val, est)
    kinds = conds["noise-free"][2]
    print(f"# {len(val)} scenes: {kinds.count('release')} release, {kinds.count('gradual')} gradual onsets")

    curves = {name: {cond: roc([det.run(x[:, :4], fs=1000.0)[0] for x in feats], rr, kk)
                     for cond, (feats, rr, kk) in conds.items()}
              for name, det in nets.items()}

    def ms(v):
        return "-" if not np.isfinite(v) else f"{v:.1f}"

    print("\n| net | condition | at y_slip >= 0.8: detection / false alarms, gradual (latency ms) "
          "| at 1 % | at 2 % | at 3 % (all (gradual), gradual latency ms) |")
    print("|---|---|---|---|---|---|")
    for name, cc in curves.items():
        for cond, c in cc.items():
            p = c.at_threshold(0.8)
            cells = [(f"{100 * p['detection_rate']:.1f} / {100 * p['false_alarm_rate']:.1f} %, "
                      f"{100 * p['detection_gradual']:.1f} % ({ms(p['latency_gradual_ms'])})")]
            for fa in (0.01, 0.02, 0.03):
                q = c.at_false_alarm(fa)
                cells.append(f"{100 * q['detection_rate']:.1f} ({100 * q['detection_gradual']:.1f}) %, "
                             f"{ms(q['latency_gradual_ms'])}")
            print(f"| {name} | {cond} | " + " | ".join(cells) + " |")

    print("\n| gradual onsets found by every net at 2 % false alarms | condition | onsets | "
          + " | ".join(f"{n}: mean / median latency ms" for n in curves) + " |")
    print("|---|---|---|" + "---|" * len(curves))
    for cond in conds:
        lats = {}
        for name, cc in curves.items():
            c = cc[cond]
            lat = c.latencies(c.at_false_alarm(0.02)["threshold"]) * 1e3
            lats[name] = lat[np.asarray(c.slip_kinds) == "gradual"]
        common = np.all([np.isfinite(v) for v in lats.values()], axis=0)
        cells = [f"{np.mean(v[common]):.1f} / {np.median(v[common]):.1f}" if common.any() else "-"
                 for v in lats.values()]
        print(f"| | {cond} | {int(common.sum())} | " + " | ".join(cells) + " |")
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return curves["bundled net"]["noise-free"].at_false_alarm(0.02)["detection_rate"]


if __name__ == "__main__":
    main()
