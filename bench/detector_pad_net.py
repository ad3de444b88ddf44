"""Can the Jordan net itself use the pad? A filter-bank net with the pad's mean bank, on 6-ridge scenes.

``bench/detector_pad_study.py`` shows that boosted trees reading a ridge's 17 filter-bank
inputs *and their mean over the pad's six ridges* find nearly every slip at 1-2 % false
alarms on pad scenes, the gradual onsets too, within a few ms. This study asks the same
of the net: the Jordan kernel (H = 16, trained by the C++ BPTT path, L-BFGS-B, the
build's loss options: negative weight 30, ``y_pred`` weight 4) on

* ``pad-trained net, ridge``: the ridge's own 17 inputs (the bundled net's inputs);
* ``pad-trained net, ridge + pad mean``: plus the pad's mean of the 17 (34 inputs).

Scenes: the build's held-out ranges (``build_options.TEST_KWARGS``) with six ridges. Training
seed ``PAD_TRAIN_SEED`` (two noise copies of each scene, 0-5 mV rms, and a random gain
per copy, as the build); the candidates (2 initial seeds, checkpoints every 25
iterations) are chosen, and ``y_slip``'s decision point calibrated (at most 1.5 % false
alarms noise-free), on the validation seed ``PAD_VALIDATION_SEED``; the rows are
measured on a third seed, ``PAD_TEST_SEED``, which chose nothing. Rates over ridges 0-2
(the pad is mirror-symmetric). The nets run here through the numpy recurrence
(``detector.network.forward``, the C++ kernel's specification).

``--save PATH`` (with ``--inputs mean --compress log``): the kept net as a weights file of
kind ``"jordan_bank"`` whose bank has the pad's mean and the knees
(``bank["pad_mean"]``, ``bank["knee"]``), its output bias shifted so that ``y_slip >= 0.8``
is the decision point (the build's rule, ``calibration.calibrate_slip``); it is then loaded
and run by ``SlipDetector`` (the C++ kernel, from the stress rates) on the test scenes,
one more row per condition.

``--weights PATH [--test-seed SEED]``: no training; the bundled net and the given weights
file (run by ``SlipDetector``) on the test scenes of ``SEED`` (default ``PAD_TEST_SEED``;
a seed no choice has seen, e.g. to measure a net whose design was chosen on this one), and
both nets' ``y_pred`` at the slips' onsets (noise-free; read as ``bench/detector_pred_bound.py``
reads it: the last sample before the onset and the onset sample).

Run: ``python bench/detector_pad_net.py --cache out/scenes`` (14 min on 2 cores with the scenes cached;
``--quick``: 2 training, 3 validation and 2 test pads simulated here, one seed of 10 iterations with
checkpoints every 5, a smoke run of a few seconds). ``main`` returns the bundled net's detection rate at
2 % false alarms on the test pads, noise-free.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from types import SimpleNamespace

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from tactile_mirror.cli.arguments import add_workers_options, open_workers

PAD_TEST_SEED = 60603
#: Sensor noise of the training copies, V rms (the build's ``NOISE_RANGE``).
NOISE_RANGE = (0.0, 5e-3)


def pad_inputs(result, with_mean: bool) -> np.ndarray:
    """(n_ridges, 17 or 34, n): a pad result's filter-bank inputs, with the pad mean appended."""
    from tactile_mirror.detector.data_prep import features_from_result

    x = features_from_result(result, "stress_rate_bank")
    if not with_mean:
        return x
    return np.concatenate([x, np.broadcast_to(x.mean(axis=0, keepdims=True), x.shape)], axis=1)


def stack(results, with_mean: bool, gains=None):
    """Padded (n_seq, n_in, n) inputs, targets and mask of the results' ridges."""
    from tactile_mirror.detector.data_prep import targets_from_result
    from tactile_mirror.lab.detector.training import pad_sequences

    xs, ys, ps = [], [], []
    for k, r in enumerate(results):
        x = pad_inputs(r, with_mean)
        s, p = targets_from_result(r)
        xs.append(x if gains is None else x * gains[k])
        ys.append(s)
        ps.append(p)
    return pad_sequences(xs, ys, ps)


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes")
    ap.add_argument("--n-train", type=int, default=None, help="training pads (default 160; --quick: 2)")
    ap.add_argument("--n-validation", type=int, default=None,
                    help="validation pads (default 160; --quick: 3)")
    ap.add_argument("--n-test", type=int, default=None, help="test pads (default 160; --quick: 2)")
    ap.add_argument("--maxiter", type=int, default=None,
                    help="L-BFGS-B iterations (default 300; --quick: 10)")
    ap.add_argument("--seeds", type=int, default=None, help="initial seeds (default 2; --quick: 1)")
    ap.add_argument("--calibrate-fa", type=float, default=0.015)
    ap.add_argument("--hidden", type=int, default=16)
    ap.add_argument("--noise-range", type=float, nargs=2, default=list(NOISE_RANGE), metavar=("LOW", "HIGH"),
                    help="sensor noise of the training copies, V rms (the build's: 0-5 mV)")
    ap.add_argument("--negative-weight", type=float, default=30.0)
    ap.add_argument("--select-clean", action="store_true",
                    help="keep the candidate by the noise-free validation scenes (default: their own noise)")
    ap.add_argument("--compress", choices=["none", "asinh", "log"], default="none",
                    help="pass every input through asinh(x / k) or the library's sign(x) log(1 + |x| / k) "
                         "(detector.bank.log_compress), k its median |x| over the training samples "
                         "(bench/detector_input_study.py), before the rms normalisation")
    ap.add_argument("--inputs", nargs="+", default=["ridge", "mean"], choices=["ridge", "mean"],
                    help="input sets: the ridge's bank alone, or with the pad's mean bank")
    ap.add_argument("--save", default=None, metavar="PATH",
                    help="save the pad-mean net as weights (needs --compress log) and run it through SlipDetector")
    ap.add_argument("--weights", default=None, metavar="PATH",
                    help="train nothing: measure this weights file (and the bundled net) on the test scenes")
    ap.add_argument("--test-seed", type=int, default=PAD_TEST_SEED, help="seed of the test scenes")
    ap.add_argument("--figure", default=None, metavar="PATH",
                    help="also plot every row's threshold sweep per condition (detector_roc.py's figure)")
    ap.add_argument("--hum", action="store_true",
                    help="(with --weights) also the thermal floor + 2 mV 50 Hz hum condition, the estimator notching it")
    ap.add_argument("--recalibrate-goals", type=float, nargs=2, default=None, metavar=("NOISE_FREE", "NOISY"),
                    help="(with --weights and --save) set the net's decision point anew on --n-validation validation "
                         "pads, as the build's --calibrate-goals: the lowest threshold with at most NOISE_FREE false "
                         "alarms noise-free and NOISY with 1 mV rms white noise and with the hum condition; save it "
                         "to --save and measure it")
    ap.add_argument("--quick", action="store_true",
                    help="a few pads simulated here, short trainings (a smoke run, not the figures)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    quick = args.quick
    for name, full, small in (("n_train", 160, 2), ("n_validation", 160, 3), ("n_test", 160, 2),
                              ("maxiter", 300, 10), ("seeds", 2, 1)):
        if getattr(args, name) is None:
            setattr(args, name, small if quick else full)
    every = 5 if quick else 25
    if args.recalibrate_goals and not (args.weights and args.save):
        ap.error("--recalibrate-goals needs --weights (the net) and --save (where the recalibrated net goes)")
    if args.hum and not args.weights:
        ap.error("--hum needs --weights (the study's own nets read the bank without the estimator's notch)")
    if args.save and not args.recalibrate_goals and (args.compress != "log" or "mean" not in args.inputs):
        ap.error("--save needs --compress log and --inputs mean (the library's compressed pad-mean bank)")
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import scipy.optimize
    from common import save_figure, simulated
    from detector_input_study import compression
    from detector_pad_study import N_RIDGES, PAD_TRAIN_SEED, PAD_VALIDATION_SEED, SCORED, latency_at
    from tactile_mirror.detector import DetectorWeights, SlipDetector
    from tactile_mirror.detector.bank import DEFAULT_BANK
    from tactile_mirror.detector.data_prep import features_from_result, targets_from_result
    from tactile_mirror.detector.network import Params, forward, init_params
    from tactile_mirror.lab.detector import build_options, calibration
    from tactile_mirror.lab.detector.augment import augment_noise
    from tactile_mirror.lab.detector.evaluation import (
        condition_estimator,
        noise_free,
        onset_kinds,
        with_noise,
    )
    from tactile_mirror.lab.detector.thresholds import roc
    from tactile_mirror.lab.detector.training import cpp_loss, fit_normalisation, loss_weights
    from tactile_mirror.lab.measure import cpu_model

    t0 = time.perf_counter()
    kw = {**build_options.TEST_KWARGS, "n_ridges": N_RIDGES}
    with open_workers(args) as executor:
        if args.weights:  # nothing is trained or chosen: only the test scenes are needed
            args.inputs, train, val = [], None, []
        else:
            train = simulated(args.n_train, PAD_TRAIN_SEED, kw, args.cache, quick=quick, executor=executor)
            val = simulated(args.n_validation, PAD_VALIDATION_SEED, kw, args.cache, quick=quick, executor=executor)
        if args.recalibrate_goals:
            # the decision point anew, on validation pads only (the test pads choose nothing)
            val = simulated(args.n_validation, PAD_VALIDATION_SEED, kw, args.cache, quick=quick, executor=executor)
            nf, noisy = args.recalibrate_goals
            goals = {"noise-free": nf, "1 mV rms white": noisy, "thermal + 2 mV 50 Hz hum, notch": noisy}
            w, info = calibration.calibrate_slip(calibration.uncalibrate(SlipDetector.load(args.weights).weights), val, None,
                                                 scenes=f"seed {PAD_VALIDATION_SEED}, {len(val)} pads", conditions=goals,
                                                 executor=executor)
            w.save(args.save)
            print(f"# recalibrated {args.weights} on {len(val)} validation pads: threshold {info['threshold']:.3f} of "
                  "the net as trained; validation " + ", ".join(
                      f"{c} {100 * v['validation_detection']:.1f} % at {100 * v['validation_false_alarm']:.1f} %"
                      for c, v in info["conditions"].items()) + f"; saved {args.save}", flush=True)
            args.weights = args.save
        test = simulated(args.n_test, args.test_seed, kw, args.cache, quick=quick, executor=executor)
    kinds = {name: [k for i, k in enumerate(onset_kinds(res)) if i % N_RIDGES in SCORED]
             for name, res in (("val", val), ("test", test))}
    print(f"# CPU: {cpu_model()}; pad scenes ({N_RIDGES} ridges): {len(train or [])} training (seed "
          f"{PAD_TRAIN_SEED}), {len(val)} validation (seed {PAD_VALIDATION_SEED}), {len(test)} test (seed "
          f"{args.test_seed}: "
          f"{kinds['test'].count('release')} release, {kinds['test'].count('gradual')} gradual onsets on ridges "
          f"{SCORED})", flush=True)
    if train is not None:
        seqs = augment_noise(train, build_options.NOISE_COPIES, tuple(args.noise_range), seed=2)
        gains = np.exp(np.random.default_rng(1).uniform(np.log(0.6), np.log(1.7), len(seqs)))
    conditions = {"noise-free": noise_free(test)}
    conditions["1 mV rms white"] = with_noise(conditions["noise-free"], "1 mV rms white", seed=9001)
    hum = "thermal + 2 mV 50 Hz hum, notch"
    if args.hum:
        conditions[hum] = with_noise(conditions["noise-free"], hum, seed=9002)
    val_clean = noise_free(val)

    def ridge_scores(y, results):
        """Per-result (n_ridges, n) rows of a (n_seq, n) output."""
        out, i = [], 0
        for r in results:
            n = np.asarray(r.t).size
            out.append(y[i:i + N_RIDGES, :n])
            i += N_RIDGES
        return out

    def curve(scores, results, kind_list, consecutive=1):
        return roc([s[list(SCORED)] for s in scores], results, kind_list, consecutive=consecutive)

    curves = {}

    def row(cond, name, scores, thr):
        results = conditions[cond]
        c = curve(scores, results, kinds["test"])
        curves.setdefault(cond, {})[name] = c
        q = c.at_threshold(thr)
        p2 = c.at_false_alarm(0.02)
        p3 = curve(scores, results, kinds["test"], 3).at_false_alarm(0.02)
        lat = []
        for s, r in zip(scores, results):
            g, _ = targets_from_result(r)
            lat += [latency_at(r.t, s[i], g[i], thr, 1) for i in SCORED]
        lat = np.array(lat)
        glat = lat[np.array([k == "gradual" for k in kinds["test"]]) & np.isfinite(lat)]
        rlat = lat[np.array([k == "release" for k in kinds["test"]]) & np.isfinite(lat)]
        return (f"| {name} | {100 * q['detection_rate']:.1f} % | {100 * q['false_alarm_rate']:.1f} % | "
                f"{100 * q['detection_release']:.1f} % | {100 * q['detection_gradual']:.1f} % | "
                f"{1e3 * rlat.mean():.1f} / {1e3 * glat.mean():.1f} ms | "
                f"{100 * p2['detection_rate']:.1f} ({100 * p2['detection_gradual']:.1f}) % | "
                f"{100 * p3['detection_rate']:.1f} ({100 * p3['detection_gradual']:.1f}) % |")

    rows = {c: [] for c in conditions}
    net = SlipDetector.default()
    for cond, res in conditions.items():
        sc = [net.run(features_from_result(r, net.features, estimator=condition_estimator(net, cond)), fs=r.fs)[0]
              for r in res]
        rows[cond].append(row(cond, "bundled filter-bank net (single-ridge training)", sc, 0.8))
    if args.weights:
        det = SlipDetector.load(args.weights)
        for cond, res in conditions.items():
            sc = [det.run(features_from_result(r, "stress_rate", estimator=condition_estimator(det, cond)), fs=r.fs)[0]
                  for r in res]
            rows[cond].append(row(cond, f"{os.path.basename(args.weights)} (SlipDetector, C++)", sc, 0.8))

    H = args.hidden
    for with_mean in [name == "mean" for name in args.inputs]:
        name = "pad-trained net, ridge + pad mean" if with_mean else "pad-trained net, ridge"
        X, S, P, M = stack(seqs, with_mean, gains)
        # the input study's transforms, knees from these training inputs
        compressed = compression({"none": "linear", "asinh": "asinh/median", "log": "log/median"}[args.compress],
                                 X, M)
        X = compressed(X)
        _mean, scale = fit_normalisation(X, M, "rms")
        xn = X / scale[None, :, None] * M[:, None, :]
        data = SimpleNamespace(x=X, y_slip=S, y_pred=P, mask=M, fs=float(train[0].fs))
        w_slip, w_pred = loss_weights(data, 4.0, args.negative_weight)
        n_in = X.shape[1]
        fun = cpp_loss(xn, data, w_slip, w_pred, H, 1e-4, True, 2)
        sel = val_clean if args.select_clean else val
        xv_clean = compressed(stack(val_clean, with_mean)[0]) / scale[None, :, None]
        xv = xv_clean if args.select_clean else compressed(stack(val, with_mean)[0]) / scale[None, :, None]

        def val_curve(theta):
            ys, _ = forward(Params.unpack(theta, n_in, H), xv)
            return curve(ridge_scores(ys, sel), sel, kinds["val"])

        best = (-1.0, None)
        t1 = time.perf_counter()
        for seed in range(args.seeds):
            count = [0]
            cands = []

            def cb(xk):
                count[0] += 1
                if count[0] % every == 0:
                    cands.append((count[0], np.array(xk)))

            res = scipy.optimize.minimize(fun, init_params(n_in, H, seed).pack(), jac=True, method="L-BFGS-B",
                                          callback=cb, options={"maxiter": args.maxiter, "maxfun": 2 * args.maxiter,
                                                                "gtol": 1e-9, "ftol": 1e-12})
            cands.append((int(res.nit), res.x))
            for it, theta in cands:
                score = val_curve(theta).at_false_alarm(args.calibrate_fa)["detection_rate"]
                if score > best[0]:
                    best = (score, theta, seed, it)
        _, theta, seed, it = best
        # The decision point: the lowest threshold with at most calibrate_fa false alarms on the
        # noise-free validation scenes (the build's calibration, applied as a threshold here).
        ys, _ = forward(Params.unpack(theta, n_in, H), xv_clean)
        thr = float(curve(ridge_scores(ys, val_clean), val_clean, kinds["val"]).at_false_alarm(args.calibrate_fa)[
            "threshold"])
        how = "" if args.compress == "none" else f", compressed ({args.compress})"
        print(f"# {name}: {n_in} inputs{how}, H = {H}, negative weight {args.negative_weight:g}, training noise "
              f"{1e3 * args.noise_range[0]:g}-{1e3 * args.noise_range[1]:g} mV, kept seed {seed} at {it} "
              f"iterations (validation detection at "
              f"{100 * args.calibrate_fa:g} % false alarms {100 * best[0]:.1f} %), threshold {thr:.3f} "
              f"({time.perf_counter() - t1:.0f} s)", flush=True)
        for cond, res in conditions.items():
            Xt, _, _, _ = stack(res, with_mean)
            yt, _ = forward(Params.unpack(theta, n_in, H), compressed(Xt) / scale[None, :, None])
            rows[cond].append(row(cond, name, ridge_scores(yt, res), thr))
        if args.save and with_mean:
            # The library's pad-mean bank with these knees: the same inputs (the mean summed in
            # ridge order instead of numpy's mean: round-off), y_slip >= 0.8 at the decision point.
            params = Params.unpack(theta, n_in, H)
            params.b2[0] += calibration.bias_shift(thr)
            bank = {**DEFAULT_BANK, "pad_mean": True, "knee": [float(k) for k in compressed.knee]}
            w = DetectorWeights(params, np.zeros(n_in), scale, float(train[0].fs),
                                {"features": "stress_rate_bank", "bank": bank,
                                 "trained_on": f"pad scenes seed {PAD_TRAIN_SEED} (bench/detector_pad_net.py)",
                                 "slip_calibration": {"threshold": thr, "validation": f"seed {PAD_VALIDATION_SEED}"}})
            w.save(args.save)
            det = SlipDetector.load(args.save)
            print(f"# saved {args.save}; run by SlipDetector ({det.simd_path}, float64) from the stress rates",
                  flush=True)
            for cond, res in conditions.items():
                sc = [det.run(features_from_result(r, "stress_rate"), fs=r.fs)[0] for r in res]
                rows[cond].append(row(cond, f"{name}, saved, run by SlipDetector (C++)", sc, 0.8))

    print("\n| pad test scenes, ridges 0-2 | detection | false alarms | release | gradual | latency release / "
          "gradual | at 2 % false alarms: all (gradual) | the same, 3 in a row |")
    print("|---|---|---|---|---|---|---|---|")
    for cond, rs in rows.items():
        print(f"| **{cond}** | | | | | | | |")
        for r in rs:
            print(r)
    if args.weights:
        # y_pred read as bench/detector_pred_bound.py reads it: at the last sample before the
        # onset of gross slip (the prediction proper) and at the onset sample, noise-free
        print("\n| pad test scenes, ridges 0-2, noise-free | onset kind | slips | y_pred in 0.8 +- 0.1: last "
              "sample before the onset | at the onset sample | median before / at | 10-90 % before |")
        print("|---|---|---:|---:|---:|---:|---:|")
        from detector_pred_bound import pred_at_onsets, pred_table_rows

        for name, d, feats in (("`SlipDetector.default()`", net, net.features),
                               (os.path.basename(args.weights), det, "stress_rate")):
            rows = []
            for r in conditions["noise-free"]:
                yp = d.run(features_from_result(r, feats), fs=r.fs)[2]
                g, _ = targets_from_result(r)
                rows += [(yp[k], g[k]) for k in SCORED]
            for line in pred_table_rows(name, pred_at_onsets((y, g, kind) for (y, g), kind in zip(rows, kinds["test"]))):
                print(line)
    if args.figure:
        from detector_roc import figure

        save_figure(figure(curves, len(test)), args.figure, dpi=110)
        print(f"wrote {args.figure}")
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return curves["noise-free"]["bundled filter-bank net (single-ridge training)"].at_false_alarm(0.02)[
        "detection_rate"]


if __name__ == "__main__":
    main()
