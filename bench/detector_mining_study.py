"""Does hard-example mining lift the filter-bank net's curve? A study on validation scenes.

The net is judged per scene: one excursion of ``y_slip`` over the threshold outside a slip
is a false alarm, and a slip is found or missed in the first 50 ms after its onset. The
training loss is per sample, and most of its weight lies on samples any net gets right
(a quiet contact, steady sliding). Boosted trees, which reach further along the same
inputs' threshold sweep, re-weight their errors round after round. This study trains the
Jordan net by the bundled recipe (kind ``"jordan_bank"``: the build's training scenes plus
the extra scenes from the held-out ranges, two noise copies each, random gains; negative
weight 30, ``pred_weight`` 4, 300 L-BFGS-B iterations) and against it the same net trained
in rounds: the recipe for the first ``--first`` iterations, then rounds of ``--round``
iterations, each warm-started from the last, with the y_slip loss of the hard examples
multiplied by ``--factor`` (:func:`tactile_mirror.lab.detector.training.hard_example_weights`: the
no-slip samples where the net's output is at or above ``--level``, and the onset windows of
the slips it misses), the same number of iterations in all.

Every variant's checkpoints (every 25 iterations, per initial seed) are scored on one half of
the build's validation scenes (seed ``build_options.VALIDATION_SEED``, detection at 2 % false alarms,
noise-free and 1 mV rms averaged); the one kept is reported on the other half, which chose
nothing; then the halves swap (both directions from the same trainings). The held-out seeds
are not used.

Run: ``python bench/detector_mining_study.py --cache out/scenes [--seeds 2] [--factor 4] [--level 0.5]``
(``--quick``: 6 + 4 training and 8 validation scenes simulated here, one seed of 20 iterations, mining
from 10 in rounds of 5, checkpoints every 5: a smoke run of a few seconds). ``main`` returns the bundled
net's detection rate at 2 % false alarms on half B, noise-free.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from tactile_mirror.cli.arguments import add_workers_options, open_workers


def run_net(w, feats):
    """y_slip of weights ``w`` on a list of (n_ridges, n_inputs, n) feature arrays (the numpy recurrence)."""
    from tactile_mirror.detector.network import forward

    return [forward(w.params, (x - w.input_mean[None, :, None]) / w.input_scale[None, :, None])[0] for x in feats]


def training_outputs(w, ts):
    """y_slip of ``w`` on the padded training set (n_seq, n)."""
    from tactile_mirror.detector.network import forward

    xn = (ts.x - w.input_mean[None, :, None]) / w.input_scale[None, :, None]
    return forward(w.params, xn * ts.mask[:, None, :])[0]


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes")
    ap.add_argument("--extra", type=int, default=None, help="extra training scenes (default 240; --quick: 4)")
    ap.add_argument("--n-validation", type=int, default=None,
                    help="validation scenes (default 480; --quick: 8)")
    ap.add_argument("--seeds", type=int, default=None,
                    help="initial seeds per variant (default 2; --quick: 1)")
    ap.add_argument("--maxiter", type=int, default=None,
                    help="iterations in all, per variant (default 300; --quick: 20)")
    ap.add_argument("--first", type=int, default=None,
                    help="mining: iterations before the first re-weighting (default 150; --quick: 10)")
    ap.add_argument("--round", type=int, default=None,
                    help="mining: iterations per round (default 50; --quick: 5)")
    ap.add_argument("--factor", type=float, nargs="+", default=[4.0],
                    help="mining factors (one variant each)")
    ap.add_argument("--level", type=float, default=0.5,
                    help="mining: no-slip outputs at or above this are hard")
    ap.add_argument("--negative-weight", type=float, default=30.0)
    ap.add_argument("--no-recipe", action="store_true", help="skip the plain recipe")
    ap.add_argument("--json", default=None, help="write the tables' figures here")
    ap.add_argument("--quick", action="store_true",
                    help="6 training scenes and few others, simulated here; short trainings (a smoke run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    quick = args.quick
    for name, full, small in (("extra", 240, 4), ("n_validation", 480, 8), ("seeds", 2, 1),
                              ("maxiter", 300, 20), ("first", 150, 10), ("round", 50, 5)):
        if getattr(args, name) is None:
            setattr(args, name, small if quick else full)
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

    from common import bank_training_set, bank_validation_conditions, study_scenes, write_json
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.lab.detector import build_options
    from tactile_mirror.lab.detector.thresholds import roc
    from tactile_mirror.lab.detector.training import hard_example_weights, train_detector
    from tactile_mirror.lab.measure import cpu_model

    t0 = time.perf_counter()
    with open_workers(args) as executor:
        train, val = study_scenes(args.cache, args.extra, args.n_validation, executor=executor,
                                  **({"n_train": 6, "quick": True} if quick else {}))
    half = len(val) // 2
    halves = {"A": (val[:half], f"1-{half}"), "B": (val[half:], f"{half + 1}-{len(val)}")}
    print(f"# CPU: {cpu_model()}; {len(train)} training scenes; validation seed {build_options.VALIDATION_SEED}, "
          f"halves A = scenes {halves['A'][1]}, B = {halves['B'][1]}")
    ts = bank_training_set(train)
    print(f"# {ts.n_seq} training sequences, {int(ts.mask.sum())} samples", flush=True)

    bundled = SlipDetector.default()
    est = bundled.metadata.get("estimator")
    conds = {part: bank_validation_conditions(res, est) for part, (res, _) in halves.items()}

    def curves(part, w):
        return {name: roc(run_net(w, feats), rr, kinds) for name, (feats, rr, kinds) in conds[part].items()}

    def score(c):
        return float(np.mean([c[n].at_false_alarm(0.02)["detection_rate"] for n in c]))

    opts = {"n_hidden": 16, "negative_weight": args.negative_weight, "pred_weight": 4.0, "normalisation": "rms",
            "features": "stress_rate_bank", "progress": False, "callback_every": 5 if quick else 25}
    variants = ([] if args.no_recipe else [("recipe", None)]) + [(f"mining x{f:g}", f) for f in args.factor]
    kept = {}  # (variant, selecting half) -> (score, weights, label)
    for name, factor in variants:
        t1 = time.perf_counter()
        cands = []
        for seed in range(args.seeds):
            if factor is None:
                got = []
                w = train_detector(ts, seed=seed, maxiter=args.maxiter, callback=lambda it, w: got.append((it, w)),
                                   **opts)
                got.append((w.metadata["training"]["iterations"], w))
            else:
                got, done, sw = [], 0, None
                w = None
                while done < args.maxiter:
                    n_it = args.first if w is None else min(args.round, args.maxiter - done)
                    base = done
                    w = train_detector(ts, seed=seed, maxiter=n_it, sample_weight=sw, init=w,
                                       callback=lambda it, ww, base=base: got.append((base + it, ww)), **opts)
                    done += n_it
                    if not got or got[-1][0] != done:
                        got.append((done, w))
                    sw = hard_example_weights(training_outputs(w, ts), ts, factor=factor, negative_level=args.level,
                                              previous=sw)
            cands += [(seed, it, w) for it, w in got]
        for seed, it, w in cands:
            cs = {part: curves(part, w) for part in halves}
            for part in halves:
                s = score(cs[part])
                if s > kept.get((name, part), (-1.0,))[0]:
                    kept[(name, part)] = (s, w, f"seed {seed}, {it} it")
        print(f"# {name}: {len(cands)} checkpoints, {time.perf_counter() - t1:.0f} s; kept on A: "
              f"{kept[(name, 'A')][2]} ({100 * kept[(name, 'A')][0]:.1f} %), on B: {kept[(name, 'B')][2]} "
              f"({100 * kept[(name, 'B')][0]:.1f} %)", flush=True)

    def cell(c, fa):
        q = c.at_false_alarm(fa)
        return f"{100 * q['detection_rate']:.1f} ({100 * q['detection_gradual']:.1f})"

    table = {}
    headline = float("nan")
    for sel, rep in (("A", "B"), ("B", "A")):
        print(f"\n| chosen on half {sel}, reported on half {rep} (scenes {halves[rep][1]}): detection at 1 / 2 / 3 % "
              f"false alarms, all (gradual) | kept | noise-free | 1 mV rms |")
        print("|---|---|---|---|")
        rows = [("bundled net", curves(rep, bundled.weights), "-")]
        if rep == "B":
            headline = rows[0][1]["noise-free"].at_false_alarm(0.02)["detection_rate"]
        rows += [(name, curves(rep, kept[(name, sel)][1]), kept[(name, sel)][2]) for name, _ in variants]
        for name, c, label in rows:
            cells = [" / ".join(cell(c[cond], fa) for fa in (0.01, 0.02, 0.03)) for cond in ("noise-free", "1 mV rms")]
            print(f"| {name} | {label} | " + " | ".join(cells) + " |")
            table[f"{name}, reported on {rep}"] = {cond: {f"{fa:g}": c[cond].at_false_alarm(fa)
                                                          for fa in (0.01, 0.02, 0.03)} for cond in c}
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    if args.json:
        write_json(args.json, json.loads(json.dumps(table, default=float)))
    return headline


if __name__ == "__main__":
    main()
