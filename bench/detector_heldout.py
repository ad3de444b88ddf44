"""The filter-bank and load-memory nets against the paper's Jordan net on the build's held-out scenes.

The three nets (and, with ``--bound``, the bound study's causal classifier and the same
boosted trees on the filter bank's inputs, both trained on the build's training scenes
plus the bound study's extra scenes) are scored on the same
held-out scenes (``build_options.TEST_SEED``, ``build_options.TEST_KWARGS`` ranges, disjoint from the
training and validation seeds) with the definitions of ``detector.evaluate``: per
noise condition (noise-free, 1 mV rms white noise on ``v_out``/``u_out``, and with ``--hum``
the circuit's thermal floor plus 2 mV of 50 Hz hum, the estimator notching it) the
detection and false-alarm rates at ``y_slip >= 0.8``, split by onset kind, the mean
latency per onset kind, the share of slips whose ``y_pred`` at the onset lies in
0.8 +- 0.1, and the ``y_pred`` lead; then the detection at 1, 2 and 3 % false alarms with
the threshold swept (``detector.evaluate.roc``). Then the kernels' tick time for 6 ridges
(measured inside C++, float32 and float64, all nets in the same run).

Run: ``python bench/detector_heldout.py [--cache out/scenes] [--bound] [--bound-extra 96] [--hum]
[--consecutive 2 3 5]`` (the last: the filter-bank net's curve when an alarm needs that many samples in a
row over the threshold). ``--quick``: 8 held-out scenes (and with ``--bound`` 6 training scenes) simulated
here, 20 boosting iterations, short kernel timings: a smoke run of a few seconds. ``main`` returns the
filter-bank net's detection rate at 2 % false alarms, noise-free.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from tactile_mirror.cli.arguments import add_workers_options, open_workers

CONDITIONS = ("noise-free", "1 mV rms white")
#: The third condition of ``--hum`` (``detector.evaluate.NOISE_CONDITIONS``: the circuit's thermal floor, 2 mV of
#: 50 Hz hum with harmonics, the estimator's notch at 50, 100, 150 Hz).
HUM = "thermal + 2 mV 50 Hz hum, notch"


def table_rows(name, scores_pred, results, kinds, cond):
    """One row per detector: the held-out metrics from (y_slip, y_pred) per result."""
    from tactile_mirror.detector.data_prep import targets_from_result
    from tactile_mirror.lab.detector.evaluation import analyse_sequence

    seqs, at_onset = [], []
    for (ys, yp), r in zip(scores_pred, results):
        gross, _ = targets_from_result(r)
        for k in range(ys.shape[0]):
            g = gross[min(k, gross.shape[0] - 1)]
            seqs.append(analyse_sequence(r.t, ys[k], yp[k], g))
            on = np.flatnonzero(g >= 0.5)
            at_onset.append(float(yp[k][on[0]]) if on.size else np.nan)
    slips = [i for i, s in enumerate(seqs) if s["slip"]]
    det = np.array([seqs[i]["detected"] for i in slips])
    out = {"detector": name, "noise": cond, "n_seq": len(seqs), "n_slip": len(slips),
           "detection": float(det.mean()), "false_alarm": float(np.mean([s["false_alarm"] for s in seqs]))}
    for kind in ("release", "gradual"):
        sel = [i for i in slips if kinds[i] == kind]
        out[f"n_{kind}"] = len(sel)
        out[f"det_{kind}"] = float(np.mean([seqs[i]["detected"] for i in sel])) if sel else np.nan
        lat = [seqs[i]["latency"] for i in sel if seqs[i]["detected"]]
        out[f"lat_{kind}_ms"] = 1e3 * float(np.mean(lat)) if lat else np.nan
    yp0 = np.array([at_onset[i] for i in slips])
    out["pred_in_band"] = float(np.mean(np.abs(yp0 - 0.8) <= 0.1))
    out["pred_at_onset_median"] = float(np.median(yp0))
    out["lead_ms"] = 1e3 * float(np.mean([seqs[i]["lead"] for i in slips]))
    return out


def bank_tree_scores(train, test, notch=None, trees: int | None = None) -> list:
    """Probabilities of the bound study's boosted trees on the filter bank's inputs (ridge 0);
    ``trees``: boosting iterations (default the bound study's)."""
    from common import BOUND_TREES, fit_bound_classifier
    from tactile_mirror.detector.data_prep import DEFAULT_ESTIMATOR, features_from_result, targets_from_result

    est = dict(DEFAULT_ESTIMATOR, **({} if notch is None else {"notch": notch}))

    def feats(r):
        return features_from_result(r, "stress_rate_bank", estimator=est)[0].T

    X = np.vstack([feats(r)[::2] for r in train])
    Y = np.concatenate([targets_from_result(r)[0][0][::2] for r in train])
    clf = fit_bound_classifier(X, Y, max_iter=trees or BOUND_TREES)
    return [clf.predict_proba(feats(r))[:, 1] for r in test]


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes",
                    help="directory of cached simulated scenes ('' for none)")
    ap.add_argument("--n-test", type=int, default=None, help="held-out scenes (default 200; --quick: 8)")
    ap.add_argument("--memory-weights", default=None, help="load-memory weights (default: bundled)")
    ap.add_argument("--bank-weights", default=None, help="filter-bank weights (default: bundled)")
    ap.add_argument("--also-bank", action="append", default=[], metavar="WEIGHTS",
                    help="a further filter-bank net to score beside it (repeatable; rows named by the file)")
    ap.add_argument("--test-seed", type=int, default=None,
                    help="seed of the held-out scenes (default: the build's, build_options.TEST_SEED); another seed "
                         "gives scenes that chose nothing, for a comparison decided on the build's")
    ap.add_argument("--bound", action="store_true", help="also the bound study's classifier (scikit-learn)")
    ap.add_argument("--bound-extra", type=int, default=0, help="extra bound training scenes (seed 99)")
    ap.add_argument("--val-threshold", type=float, default=None, metavar="FA",
                    help="also the filter-bank net at the lowest threshold of y_slip whose false-alarm rate on the "
                         "build's validation scenes (their own noise) is at most FA (e.g. 0.01)")
    ap.add_argument("--hum", action="store_true",
                    help="also the thermal floor + 2 mV 50 Hz hum condition, notched")
    ap.add_argument("--consecutive", type=int, nargs="+", default=[], metavar="K",
                    help="also the filter-bank net's curve with an alarm only after K samples in a row at or above "
                         "the threshold (detector.evaluate.roc's consecutive), for each K")
    ap.add_argument("--quick", action="store_true",
                    help="a few scenes simulated here, few boosting iterations, short timings (a smoke run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    if any(k < 1 for k in args.consecutive):
        ap.error("--consecutive takes positive sample counts")
    quick = args.quick
    if args.n_test is None:
        args.n_test = 8 if quick else 200
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import QUICK_TREES, header, simulated
    from detector_roc import bound_scores
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector import build_options
    from tactile_mirror.lab.detector.evaluation import NOISE_CONDITIONS, onset_kinds, with_noise
    from tactile_mirror.lab.detector.evaluation import condition_estimator as estimator_of
    from tactile_mirror.lab.detector.evaluation import noise_free as clean
    from tactile_mirror.lab.detector.thresholds import roc
    from tactile_mirror.lab.measure import cpu_model

    header("filter-bank and load-memory nets vs the paper's Jordan net on the build's held-out scenes")
    cache = args.cache or None
    t0 = time.perf_counter()
    test_seed = build_options.TEST_SEED if args.test_seed is None else args.test_seed
    with open_workers(args) as executor:
        test = simulated(args.n_test, test_seed, build_options.TEST_KWARGS, cache, quick=quick, executor=executor)
        kinds = onset_kinds(test)
        print(f"{len(test)} held-out scenes (seed {test_seed}): {kinds.count('release')} release, "
              f"{kinds.count('gradual')} gradual onsets, {kinds.count(None)} sequences without gross slip "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        memory = SlipDetector.load(args.memory_weights) if args.memory_weights else SlipDetector.memory()
        paper = SlipDetector.paper()
        bank = SlipDetector.load(args.bank_weights) if args.bank_weights else SlipDetector.bank()
        nets = (("filter-bank net", bank),) + tuple(
            (f"filter-bank net {os.path.splitext(os.path.basename(p))[0]}", SlipDetector.load(p)) for p in args.also_bank) \
            + (("load-memory net", memory), ("paper Jordan net", paper))
        train = []
        if args.bound:
            train = simulated(6 if quick else 64, build_options.TRAIN_SEED, build_options.TRAIN_KWARGS, cache, quick=quick,
                              executor=executor)
            if args.bound_extra:
                train = train + simulated(args.bound_extra, 99, build_options.TEST_KWARGS, cache, quick=quick,
                                          executor=executor)
        rows, curves = [], []
        thr = None
        if args.val_threshold is not None:
            val = simulated(8 if quick else 120, build_options.VALIDATION_SEED, build_options.TEST_KWARGS, cache,
                            quick=quick, executor=executor)
            vk = onset_kinds(val)
            vs = [bank.run(features_from_result(r, bank.features, estimator=bank.metadata.get("estimator")), fs=r.fs)[0]
                  for r in val]
            pt = roc(vs, val, vk).at_false_alarm(args.val_threshold)
            thr = pt["threshold"]
            print(f"validation (seed {build_options.VALIDATION_SEED}): y_slip >= {thr:.4f} gives {100 * pt['detection_rate']:.1f} % "
                  f"detection at {100 * pt['false_alarm_rate']:.1f} % false alarms", flush=True)
    conditions = CONDITIONS + ((HUM,) if args.hum else ())
    for ci, cond in enumerate(conditions):
        noisy = clean(test)  # the scenes' own noise removed: the circuit outputs of their stresses
        if cond != "noise-free":
            noisy = with_noise(noisy, cond, seed=1000 + ci)
        for name, det in nets:
            outs = []
            for r in noisy:
                ys, _, yp = det.run(features_from_result(r, det.features, estimator=estimator_of(det, cond)),
                                    fs=r.fs)
                outs.append((ys, yp))
            rows.append(table_rows(name, outs, test, kinds, cond))
            curves.append((cond, name, roc([o[0] for o in outs], test, kinds)))
            if det is bank:
                for k in args.consecutive:
                    curves.append((cond, f"{name}, {k} in a row", roc([o[0] for o in outs], test, kinds,
                                                                       consecutive=k)))
            if thr is not None and det is bank:
                # the alarm at the validation-chosen threshold, as a 0/1 statistic for the same analysis
                rows.append(table_rows(f"filter-bank net, y_slip >= {thr:.3f}",
                                       [((ys >= thr).astype(float), yp) for ys, yp in outs], test, kinds, cond))
        if args.bound:
            cond_key = cond
            assert cond_key in NOISE_CONDITIONS
            noisy_train = clean(train)
            if cond != "noise-free":
                noisy_train = with_noise(noisy_train, cond_key, seed=2000 + ci)
            probs = bound_scores(noisy_train, noisy, cond_key, trees=QUICK_TREES if quick else None)
            from detector_bound import debounce

            outs = []
            for p in probs:
                a = debounce(p >= 0.8).astype(float)
                outs.append((a[None], np.zeros_like(a)[None]))
            rows.append(table_rows("bound classifier (p>=0.8, 3 in a row)", outs, test, kinds, cond))
            curves.append((cond, "bound classifier (3 in a row)", roc(probs, test, kinds, consecutive=3)))
            outs = []
            tree_probs = bank_tree_scores(noisy_train, noisy, NOISE_CONDITIONS[cond][2],
                                          trees=QUICK_TREES if quick else None)
            curves.append((cond, "trees on the bank inputs (3 in a row)", roc(tree_probs, test, kinds, consecutive=3)))
            for p in tree_probs:
                a = debounce(p >= 0.8).astype(float)
                outs.append((a[None], np.zeros_like(a)[None]))
            rows.append(table_rows("trees on the bank inputs (same rule)", outs, test, kinds, cond))
        print(f"{cond} done ({time.perf_counter() - t0:.0f} s)", flush=True)
    head = (f"{'noise':<15} {'detector':<38} {'detect %':>8} {'FA %':>6} {'release':>9} {'gradual':>9} "
            f"{'lat rel ms':>10} {'lat grad ms':>11} {'yp in .8+-.1':>12} {'yp med':>7} {'lead ms':>8}")
    print("\n" + head + "\n" + "-" * len(head))
    for r in rows:
        print(f"{r['noise']:<15} {r['detector']:<38} {100 * r['detection']:>8.1f} {100 * r['false_alarm']:>6.1f} "
              f"{100 * r['det_release']:>9.1f} {100 * r['det_gradual']:>9.1f} {r['lat_release_ms']:>10.1f} "
              f"{r['lat_gradual_ms']:>11.1f} {100 * r['pred_in_band']:>12.1f} {r['pred_at_onset_median']:>7.2f} "
              f"{r['lead_ms']:>8.1f}")
    print("\ndetection at a false-alarm rate (threshold swept; all / release / gradual)")
    print(f"{'noise':<15} {'detector':<38} {'at 1 % FA':>20} {'at 2 % FA':>20} {'at 3 % FA':>20}")
    for cond, name, c in curves:
        cells = []
        for fa in (0.01, 0.02, 0.03):
            q = c.at_false_alarm(fa)
            cells.append(f"{100 * q['detection_rate']:.1f}/{100 * q['detection_release']:.1f}/"
                         f"{100 * q['detection_gradual']:.1f}")
        print(f"{cond:<15} {name:<38} {cells[0]:>20} {cells[1]:>20} {cells[2]:>20}")
    print("\nmean latency at a false-alarm rate (ms; release / gradual)")
    print(f"{'noise':<15} {'detector':<38} {'at 1 % FA':>14} {'at 2 % FA':>14} {'at 3 % FA':>14}")
    for cond, name, c in curves:
        cells = [f"{q['latency_release_ms']:.1f} / {q['latency_gradual_ms']:.1f}"
                 for q in (c.at_false_alarm(fa) for fa in (0.01, 0.02, 0.03))]
        print(f"{cond:<15} {name:<38} {cells[0]:>14} {cells[1]:>14} {cells[2]:>14}")
    n0 = rows[0]
    print(f"\n{n0['n_seq']} sequences, {n0['n_slip']} slips ({n0['n_release']} release, {n0['n_gradual']} gradual)")
    n_ticks = 20000 if quick else 200000
    print(f"\nkernel tick, 6 ridges, measured in C++ (ns, best of 5 x {n_ticks} ticks); CPU: {cpu_model()}")
    for dt in (np.float32, np.float64):
        for name, det in nets:
            k = SlipDetector(det.weights, dtype=dt).kernel(6)
            ns = k.time_step_ns(n_ticks, 5)
            print(f"  {np.dtype(dt).name:<8} {name:<18} {ns:8.1f} ns  ({k.simd_path})")
    return next(c for cond, name, c in curves if (cond, name) == ("noise-free", "filter-bank net")
                ).at_false_alarm(0.02)["detection_rate"]


if __name__ == "__main__":
    main()
