"""The loop's envelope on the 6-ridge FEM pad, and the tick cost of the default law.

    python bench/loop_envelope.py --out bench-out/loop            # nominal, 10 paths per class, 4 laws
    python bench/loop_envelope.py --out bench-out/loop --robustness --robustness-laws default
    python bench/loop_envelope.py --tick                          # the tick cost only
    python bench/loop_envelope.py --quick --out DIR               # one 1.5 s path per law, 5 mm/s

Resumable: rows go to ``OUT/loop_envelope.json`` after every run, and a rerun skips
the rows already there (run it in the background, interrupt it, run it again).
``--workers N`` or ``--scheduler ADDRESS`` runs the rows on those workers (the same file). Writes
``OUT/loop_envelope.png`` and prints the table (markdown) with the CPU model.

Reported paths: :data:`tactile_mirror.lab.loop.envelope.REPORT_PATHS` (seeds 0.., 10 mm rms,
2 Hz band, scaled to the class's peak speed and <= 0.5 m/s^2). Every choice made while
developing the law used :data:`~tactile_mirror.lab.loop.envelope.TUNING_PATHS` (seeds 1000..,
8 mm rms, 1.5 Hz band) or :data:`~tactile_mirror.lab.loop.envelope.TUNING_FAST_PATHS` (seeds
3000.., 8 mm rms, 4 Hz): disjoint seeds and generator settings (``--paths tuning`` runs them).
``--paths report-fast`` (seeds 100.., 12 mm rms, 5 Hz band) reports paths whose acceleration
limit binds (up to 0.5 m/s^2 at 20 mm/s).

The laws: open loop, the paper's, the default law on the strips, and the same design on a
load cell's force under the pad (``load cell``: ``MirrorPipeline(force_input=True)``).

``--tick``: ns per tick of the full 6-ridge float64 pipeline inside C++
(``MirrorPipeline.time_step_ns``, best of 5) with the previous velocity law, with
the default (designed) law, and with the default law's design on a load cell's force, in
the same process (``--quick``: one round of short runs). ``main`` returns the gross slips of all the
envelope's rows printed (``--tick``: the default law's ns per tick).
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from tactile_mirror.cli.arguments import add_workers_options, open_workers


def tick_table(n_iter: int = 200_000, rounds: int = 4) -> dict:
    from tactile_mirror.circuit import PVDFCircuit
    from tactile_mirror.estimator import StressRateEstimator
    from tactile_mirror.lab.loop.experiment import default_weights, weights_dict
    from tactile_mirror.lab.measure import cpu_model
    from tactile_mirror.loop.design import design_loop
    from tactile_mirror.loop.stage import StageLimits
    from tactile_mirror.pipeline import MirrorPipeline

    w = weights_dict(default_weights("fem"))
    old = VelocityControllerOld()
    new = design_loop(StageLimits(-0.02, 0.02, 0.03, 1.0), (1.0, 4.78e7), 1000.0, stage_delay=0.001,
                      stage_lag=0.002).controller
    cell = design_loop(StageLimits(-0.02, 0.02, 0.03, 1.0), (1.0, 7.6e4), 1000.0, stage_delay=0.001,
                       stage_lag=0.002, sensor="force").controller
    res = {"cpu": cpu_model()}
    for _ in range(rounds):  # interleaved, best of four rounds (a VM's tick moves by tens of ns between runs)
        for name, c, force in (("previous velocity law", old, False), ("default (designed) law", new, False),
                               ("default law on a load cell (force_input)", cell, True)):
            est = StressRateEstimator(PVDFCircuit(), 1000.0, 12, order=2, bandwidth=100.0)
            p = MirrorPipeline(w, 1000.0, 6, estimator=est, controller=c, activation="fast", max_hold_ticks=50,
                               force_input=force)
            ns = p.time_step_ns(n_iter, 5)
            res[name] = min(res.get(name, np.inf), ns)
    return res


def VelocityControllerOld():
    from tactile_mirror.pipeline.controller import VelocityController

    return VelocityController(threshold=0.2, y_full=0.7, v_max=0.004, a_max=1.0, ramp_gain=0.0, pred_boost=1.5,
                              shear_gain=1.25e-6, slip_hold=0.1, direction_sign=1.0, asym_tau=20.0, x_min=-0.02,
                              x_max=0.02, arm_delay=0.5)


def _windows(data, conditions, paths: str, duration: float) -> None:
    """Gross slips per time window of the runs, for conditions with a friction change: before it,
    its first 1.25 s, and the rest in two halves (does the loop settle on the new contact?)."""
    from tactile_mirror.lab.loop.envelope import CONDITIONS

    print("\n| condition | law | peak speed mm/s | paths | gross slips per window (s) | paths still slipping in "
          "the last window |\n|---|---|---|---|---|---|")
    for c in conditions:
        t0 = CONDITIONS[c].get("mu_change", (0.5,))[0]
        mid = t0 + 1.25 + 0.5 * max(0.0, duration - t0 - 1.25)
        edges = [0.0, t0, t0 + 1.25, mid, duration]
        rows = [r for r in data["rows"] if r["condition"] == c and r["paths"] == paths and "gross_slip_starts_s" in r]
        for law, v in sorted({(r["law"], r["speed"]) for r in rows}):
            sel = [r for r in rows if r["law"] == law and r["speed"] == v]
            counts = [sum(sum(a <= t < b for t in r["gross_slip_starts_s"]) for r in sel)
                      for a, b in zip(edges[:-1], edges[1:])]
            late = sum(any(edges[-2] <= t for t in r["gross_slip_starts_s"]) for r in sel)
            win = ", ".join(f"[{a:g}, {b:g}): {n}" for a, b, n in zip(edges[:-1], edges[1:], counts))
            print(f"| {c} | {law} | {v * 1e3:g} | {len(sel)} | {win} | {late} |")


def main(argv=None) -> float:
    from tactile_mirror.lab.loop.envelope import (
        CONDITIONS,
        LAWS,
        PATH_SETS,
        envelope_figure,
        run_envelope,
    )
    from tactile_mirror.lab.measure import cpu_model

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import on

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench-out/loop")
    ap.add_argument("--seeds", type=int, default=None, help="paths per class (default 10; --quick: 1)")
    ap.add_argument("--speeds", default=None, help="mm/s (default 2,5,10,20; --quick: 5)")
    ap.add_argument("--laws", default=",".join(LAWS))
    ap.add_argument("--robustness", action="store_true", help="also the robustness conditions")
    ap.add_argument("--robustness-laws", default="default")
    ap.add_argument("--robustness-seeds", type=int, default=None, help="paths per class (default: --seeds)")
    ap.add_argument("--paths", choices=sorted(PATH_SETS), default="report")
    ap.add_argument("--tick", action="store_true", help="only the tick cost table")
    ap.add_argument("--conditions", default=None,
                    help="comma-separated conditions to run instead of nominal (+ --robustness), e.g. "
                         "'sweat mu 0.45'; with --duration, the slips are also counted per window after the change")
    ap.add_argument("--duration", type=float, default=None,
                    help="s of each run (the finger moves from 0.5 s; default 3, --quick: 1.5)")
    ap.add_argument("--quick", action="store_true",
                    help="one path per law at 5 mm/s, 1.5 s (with --tick: one round of short runs): a smoke "
                         "run")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    if args.seeds is None:
        args.seeds = 1 if args.quick else 10
    if args.speeds is None:
        args.speeds = "5" if args.quick else "2,5,10,20"
    if args.duration is None:
        args.duration = 1.5 if args.quick else 3.0
    if args.tick:
        t = tick_table(*((20_000, 1) if args.quick else ()))
        print(f"CPU: {t.pop('cpu')}\n\n| law | ns per tick (6 ridges, float64, inside C++) |\n|---|---|")
        for k, v in t.items():
            print(f"| {k} | {v:.0f} |")
        return t["default (designed) law"]
    os.makedirs(args.out, exist_ok=True)
    out = os.path.join(args.out, "loop_envelope.json")
    paths = PATH_SETS[args.paths]
    speeds = [float(v) * 1e-3 for v in args.speeds.split(",")]
    with open_workers(args) as executor:
        if args.conditions:
            conds = tuple(c.strip() for c in args.conditions.split(","))
            data = run_envelope(out, speeds=speeds, n_seeds=args.seeds, conditions=conds,
                                laws=tuple(args.laws.split(",")), paths=paths, duration=args.duration, **on(executor))
            print(f"CPU: {cpu_model()}; paths: {paths}; {args.duration:g} s per run")
            _windows(data, conds, paths.name, args.duration)
            # the figure of these conditions alone (e.g. sweat: open loop, the default law, a load cell)
            envelope_figure({**data, "rows": [r for r in data["rows"] if r["condition"] in conds]},
                            os.path.join(args.out, "loop_envelope_conditions.png"), paths=paths.name)
            return sum(t["gross_slips"] for t in data["table"]
                       if t["paths"] == paths.name and t["condition"] in conds)
        data = run_envelope(out, speeds=speeds, n_seeds=args.seeds, conditions=("nominal",),
                            laws=tuple(args.laws.split(",")), paths=paths, duration=args.duration, **on(executor))
        if args.robustness:
            laws_r = args.robustness_laws.split(",")
            # (the cell's noise acts on the load cell's law alone: for the others it is the nominal run again)
            conds = tuple(c for c in CONDITIONS if c != "nominal" and (not c.startswith("cell") or "load cell" in laws_r))
            data = run_envelope(out, speeds=speeds, n_seeds=args.robustness_seeds or args.seeds, conditions=conds,
                                laws=tuple(args.robustness_laws.split(",")), paths=paths, duration=args.duration,
                                **on(executor))
    envelope_figure(data, os.path.join(args.out, "loop_envelope.png"), paths=paths.name)
    print(f"CPU: {cpu_model()}; paths: {paths}")
    print("\n| condition | law | peak speed mm/s | paths | gross slips | runs with slip | tracking rms mm mean / max "
          "| max settle after slip s | second slips < 100 ms |\n|---|---|---|---|---|---|---|---|---|")
    slips = 0
    for t in data["table"]:
        if t["paths"] == paths.name:
            slips += t["gross_slips"]
            print(f"| {t['condition']} | {t['law']} | {t['speed_mm_s']:g} | {t['runs']} | {t['gross_slips']} | "
                  f"{t['runs_with_slip']} | {t['tracking_rms_mm_mean']:.4f} / {t['tracking_rms_mm_max']:.4f} | "
                  f"{t['settle_s_max']:.3f} | {t['second_slips']} |")
    return slips


if __name__ == "__main__":
    main()
