"""Is a net's latency on creeping slips a property the build can select for? A study on validation scenes.

The build trains a few seeds, keeps checkpoints, and keeps the candidate whose threshold
sweep on the validation scenes reaches furthest at the calibration's false-alarm rate
(``selection.ValidationScorer(at_false_alarm=)``). Nets of one recipe that detect about as
much can differ by a factor of two in how soon they find a slip that creeps in. This
study trains the filter-bank recipe (``--onset-weight`` as the build's option), scores
*every* candidate (seed x checkpoint) on both halves of the build's validation scenes
(seed ``build_options.VALIDATION_SEED``; 1-240 and 241-480) and asks:

- does a candidate's gradual-onset latency on one half predict it on the other (rank
  correlation)? and its detection?
- what do selection rules applied on the first half give on the second, which chose
  nothing: the build's (the most detections at the false-alarm rate), and the quickest on
  gradual onsets among the candidates within ``--tolerance`` of the best detection.

Scores are taken as the build takes them, the scenes in their own sensor noise, at
``--false-alarm`` (the calibration's noise-free bound, 1.5 %), and reported on the second half
noise-free and with 1 mV rms white noise at 2 % false alarms. The held-out seed is not used.

Run: ``python bench/detector_selection_study.py --cache out/scenes [--onset-weight 1] [--seeds 4]``
(``--quick``: 6 + 4 training and 8 validation scenes simulated here, one seed of 10 iterations with
checkpoints every 5, a smoke run of a few seconds). ``main`` returns the number of distinct candidates.
"""
from __future__ import annotations

import argparse
import os
import pickle
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import scipy.stats
from tactile_mirror.cli.arguments import add_workers_options, open_workers


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes", help="directory of cached simulated scenes")
    ap.add_argument("--extra", type=int, default=None,
                    help="extra training scenes (the bundled recipe: 240, the default; --quick: 4)")
    ap.add_argument("--n-validation", type=int, default=None,
                    help="validation scenes, split in halves (default 480; --quick: 8)")
    ap.add_argument("--seeds", type=int, default=None,
                    help="initial seeds (the build's --candidates; default 4, --quick: 1)")
    ap.add_argument("--maxiter", type=int, default=None,
                    help="L-BFGS-B iterations (default 300; --quick: 10)")
    ap.add_argument("--checkpoint-every", type=int, default=None, help="default 25; --quick: 5")
    ap.add_argument("--negative-weight", type=float, default=30.0)
    ap.add_argument("--onset-weight", type=float, default=1.0)
    ap.add_argument("--false-alarm", type=float, default=0.015, help="selection's false-alarm rate")
    ap.add_argument("--candidates-file", default=None,
                    help="pickle of the trained candidates: read if it exists, else written after training")
    ap.add_argument("--tolerance", type=float, nargs="+", default=[0.01, 0.02],
                    help="detection (a rate) a quicker candidate may give up against the best one")
    ap.add_argument("--quick", action="store_true",
                    help="6 training scenes and few others, simulated here; short trainings (a smoke run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    quick = args.quick
    for name, full, small in (("extra", 240, 4), ("n_validation", 480, 8), ("seeds", 4, 1),
                              ("maxiter", 300, 10), ("checkpoint_every", 25, 5)):
        if getattr(args, name) is None:
            setattr(args, name, small if quick else full)
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

    from common import bank_training_set, bank_validation_conditions, header, study_scenes
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector import calibration
    from tactile_mirror.lab.detector.evaluation import NOISE_CONDITIONS, onset_kinds
    from tactile_mirror.lab.detector.thresholds import roc
    from tactile_mirror.lab.detector.training import train_detector

    t0 = time.perf_counter()
    header("latency as a selection criterion, on the build's validation halves")
    # (the scenes; the candidates' trainings, with their checkpoints, run here)
    with open_workers(args) as executor:
        train, val = study_scenes(args.cache, args.extra, args.n_validation, executor=executor,
                                  **({"n_train": 6, "quick": True} if quick else {}))
    half = len(val) // 2
    halves = {"A": val[:half], "B": val[half:]}
    ts = bank_training_set(train)
    est = SlipDetector.default().metadata.get("estimator")
    own = {h: ([features_from_result(r, "stress_rate_bank", estimator=est) for r in rr], rr, onset_kinds(rr))
           for h, rr in halves.items()}
    report = bank_validation_conditions(halves["B"], est)
    goal_a = bank_validation_conditions(halves["A"], est)  # noise-free and 1 mV rms, as the goals

    cands = []
    if args.candidates_file and os.path.exists(args.candidates_file):
        with open(args.candidates_file, "rb") as fh:
            cands = pickle.load(fh)
        print(f"# {len(cands)} candidates read from {args.candidates_file}")
    for seed in range(args.seeds if not cands else 0):
        found = []
        w_end = train_detector(ts, 16, seed=seed, maxiter=args.maxiter, negative_weight=args.negative_weight,
                               pred_weight=4.0, normalisation="rms", features="stress_rate_bank",
                               onset_weight=args.onset_weight, progress=False,
                               callback=lambda it, w: found.append((it, w)), callback_every=args.checkpoint_every)
        found.append((w_end.metadata["training"]["iterations"], w_end))
        cands += [(seed, it, w) for it, w in found]
        print(f"# seed {seed}: {len(found)} candidates ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.candidates_file and not os.path.exists(args.candidates_file):
        with open(args.candidates_file, "wb") as fh:
            pickle.dump(cands, fh)
    # a run that ends on a checkpoint gives that net twice (the checkpoint and the end): once here
    distinct = {}
    for seed, it, w in cands:
        distinct.setdefault((seed, it), w)
    cands = [(seed, it, w) for (seed, it), w in distinct.items()]

    def curve(w, feats, rr, kinds):
        det = SlipDetector(w)
        return roc([det.run(x[:, :4], fs=1000.0)[0] for x in feats], rr, kinds)

    def point(w, feats, rr, kinds, fa):
        return curve(w, feats, rr, kinds).at_false_alarm(fa)

    rows = []
    for seed, it, w in cands:
        a = point(w, *own["A"], args.false_alarm)
        b = point(w, *own["B"], args.false_alarm)
        g = [point(w, *goal_a[cond], 0.02) for cond in ("noise-free", "1 mV rms")]
        rows.append({"seed": seed, "it": it, "w": w, "det_A": a["detection_rate"], "lat_A": a["latency_gradual_ms"],
                     "goal_A": float(np.mean([q["detection_rate"] for q in g])),
                     "goal_lat_A": float(np.mean([q["latency_gradual_ms"] for q in g])),
                     "det_B": b["detection_rate"], "lat_B": b["latency_gradual_ms"]})

    def spearman(x, y):  # over the candidates with a latency on both halves
        x, y = np.asarray(x, float), np.asarray(y, float)
        ok = np.isfinite(x) & np.isfinite(y)
        return float(scipy.stats.spearmanr(x[ok], y[ok]).statistic)

    print(f"\n# {len(rows)} candidates, own noise, at {100 * args.false_alarm:g} % false alarms: rank correlation "
          f"between the halves: detection {spearman([r['det_A'] for r in rows], [r['det_B'] for r in rows]):.2f}, "
          f"gradual latency {spearman([r['lat_A'] for r in rows], [r['lat_B'] for r in rows]):.2f}")
    print("\n| seed | iterations | A: detection, gradual latency ms | B: detection, gradual latency ms |")
    print("|---|---|---|---|")
    for r in rows:
        print(f"| {r['seed']} | {r['it']} | {100 * r['det_A']:.1f} %, {r['lat_A']:.1f} | "
              f"{100 * r['det_B']:.1f} %, {r['lat_B']:.1f} |")

    def quickest(det, lat, tol):
        """The row with the lowest ``lat`` among those within ``tol`` of the most ``det`` (the one
        with the most ``det`` where none of them has a latency: no gradual onset found)."""
        top = max(rows, key=lambda r: r[det])
        near = [r for r in rows if r[det] >= top[det] - tol - 1e-12 and np.isfinite(r[lat])]
        return min(near, key=lambda r: r[lat]) if near else top

    rules = [("the build's: most detections on A", max(rows, key=lambda r: r["det_A"])),
             ("most detections on A noise-free and with 1 mV rms (2 % false alarms)", max(rows, key=lambda r: r["goal_A"]))]
    rules += [(f"quickest on A (noise-free, 1 mV) within {100 * tol:g} points of that", quickest("goal_A", "goal_lat_A", tol))
              for tol in args.tolerance]
    rules += [(f"quickest on A within {100 * tol:g} points of the best", quickest("det_A", "lat_A", tol))
              for tol in args.tolerance]
    # the bundled calibration's goals: 1.5 % false alarms noise-free, 2.5 % in the noisy conditions
    goals = {name: (0.015 if name == "noise-free" else 0.025) for name in NOISE_CONDITIONS}
    print("\n| rule (chosen on A) | kept | B noise-free at 2 % false alarms: all (gradual), gradual latency ms "
          "| B 1 mV rms | B at y_slip >= 0.8 after calibration on A (noise-free) |")
    print("|---|---|---|---|---|")
    for name, r in rules:
        cells = []
        for cond in ("noise-free", "1 mV rms"):
            q = point(r["w"], *report[cond], 0.02)
            cells.append(f"{100 * q['detection_rate']:.1f} ({100 * q['detection_gradual']:.1f}) %, "
                         f"{q['latency_gradual_ms']:.1f}")
        wc, _ = calibration.calibrate_slip(r["w"], halves["A"], None, conditions=goals)
        p = curve(wc, *report["noise-free"]).at_threshold(0.8)
        cells.append(f"{100 * p['detection_rate']:.1f} % at {100 * p['false_alarm_rate']:.1f} %, gradual "
                     f"{100 * p['detection_gradual']:.1f} % ({p['latency_gradual_ms']:.1f} ms)")
        print(f"| {name} | seed {r['seed']}, {r['it']} it | " + " | ".join(cells) + " |")
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return len(rows)


if __name__ == "__main__":
    main()
