"""What the neighbouring ridges tell a ridge's detector: a study on 6-ridge pad scenes.

The build's scenes have one ridge, so every detector so far reads one ridge's strips
alone. On the paper's pad (six ridges under one finger) gross slip does not reach the
ridges at once: the outer, least loaded ridges let go first and the inner ones follow
tens to hundreds of ms later, while a stop stills every ridge in the same ms. This
study asks how much of what is still missing (gradual onsets at low false-alarm rates,
their latency) a ridge's detector gains from the pad:

* ``ridge``: the ridge's own 17 filter-bank inputs (what the bundled net reads);
* ``ridge + pad mean``: plus the mean of those 17 over the pad's six ridges (34: a
  C++ bank could add it for one reduction over the SIMD lanes per tick);
* ``ridge + pad mean, min, max``: plus the smallest and largest of the 13 bank channels
  over the ridges (60).

Each set trains the bound study's classifier (gradient-boosted trees, scikit-learn;
alarm: 3 samples in a row) on pad training scenes and is scored, with the threshold
swept (``detector.evaluate.roc``), on pad *validation* scenes of another seed, noise-free
and with 1 mV rms white noise; the bundled net (per ridge, as it runs in the pipeline)
is scored on the same scenes. Both seeds are new (used by no build or report set); the
scene ranges are the build's held-out ranges (``build_options.TEST_KWARGS``) with six ridges.
The pad is symmetric (ridge ``r`` and ``5 - r`` see the same contact, with their own
noise), so the rates count ridges 0-2 of each scene only.

Run: ``python bench/detector_pad_study.py --cache out/scenes [--n-train 160] [--n-validation 160]``
(3.5 min on 2 cores with the scenes cached; ``--quick``: 2 + 3 pad scenes simulated here, 20 boosting
iterations, a smoke run of a few seconds). ``main`` returns the bundled net's detection rate at 2 %
false alarms, noise-free.
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from tactile_mirror.cli.arguments import add_workers_options, open_workers

#: Seeds of the study's pad scenes (disjoint from every seed of the build and the reports).
PAD_TRAIN_SEED = 60601
PAD_VALIDATION_SEED = 60602
N_RIDGES = 6
#: Ridges scored per scene (the pad is mirror-symmetric).
SCORED = (0, 1, 2)


def pad_feature_sets(x: np.ndarray) -> dict:
    """Per-sample inputs, shape (n_ridges, n, n_inputs), of each studied set from a pad's
    (n_ridges, 17, n) filter-bank features."""
    own = np.moveaxis(x, 1, 2)
    mean = np.broadcast_to(x.mean(axis=0, keepdims=True), x.shape)
    lo = np.broadcast_to(x[:, 4:].min(axis=0, keepdims=True), x[:, 4:].shape)
    hi = np.broadcast_to(x[:, 4:].max(axis=0, keepdims=True), x[:, 4:].shape)
    return {
        "ridge": own,
        "ridge + pad mean": np.concatenate([own, np.moveaxis(mean, 1, 2)], axis=2),
        "ridge + pad mean, min, max": np.concatenate([own, np.moveaxis(mean, 1, 2), np.moveaxis(lo, 1, 2),
                                                      np.moveaxis(hi, 1, 2)], axis=2),
    }


def latency_at(t, scores, gross, threshold: float, consecutive: int, max_latency: float = 0.05):
    """Latency (s) of the first alarm after the onset (NaN when missed or no slip)."""
    from tactile_mirror.lab.detector.thresholds import running_min

    on = np.flatnonzero(np.asarray(gross) >= 0.5)
    if not on.size:
        return np.nan
    x = running_min(np.asarray(scores, dtype=np.float64), consecutive)
    i0 = int(on[0])
    hit = np.flatnonzero((x[i0:] >= threshold) & (t[i0:] <= t[i0] + max_latency + 1e-12))
    return float(t[i0 + hit[0]] - t[i0]) if hit.size else np.nan


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes")
    ap.add_argument("--n-train", type=int, default=None, help="training pads (default 160; --quick: 2)")
    ap.add_argument("--n-validation", type=int, default=None,
                    help="validation pads (default 160; --quick: 3)")
    ap.add_argument("--train-noise", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                    help="train the trees as the build trains its nets: two copies of every training scene "
                         "with sensor noise drawn from LOW-HIGH V rms (default: the condition's own noise)")
    ap.add_argument("--gains", action="store_true",
                    help="and scale every training copy by a random gain (0.6-1.7), as the build")
    ap.add_argument("--quick", action="store_true",
                    help="a few pads simulated here, few boosting iterations (a smoke run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    quick = args.quick
    for name, full, small in (("n_train", 160, 2), ("n_validation", 160, 3)):
        if getattr(args, name) is None:
            setattr(args, name, small if quick else full)
    from common import BOUND_TREES, QUICK_TREES, fit_bound_classifier, simulated
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.detector.data_prep import features_from_result, targets_from_result
    from tactile_mirror.lab.detector import build_options
    from tactile_mirror.lab.detector.augment import augment_noise
    from tactile_mirror.lab.detector.evaluation import noise_free, onset_kinds, with_noise
    from tactile_mirror.lab.detector.thresholds import roc
    from tactile_mirror.lab.measure import cpu_model

    t0 = time.perf_counter()
    kw = {**build_options.TEST_KWARGS, "n_ridges": N_RIDGES}
    with open_workers(args) as executor:
        train = simulated(args.n_train, PAD_TRAIN_SEED, kw, args.cache, quick=quick, executor=executor)
        val = simulated(args.n_validation, PAD_VALIDATION_SEED, kw, args.cache, quick=quick, executor=executor)
    kinds_all = onset_kinds(val)
    kinds = [k for i, k in enumerate(kinds_all) if i % N_RIDGES in SCORED]
    order = []
    for r in val[:40]:
        g, _ = targets_from_result(r)
        on = [np.flatnonzero(g[i] >= 0.5)[:1] for i in SCORED]
        if all(o.size for o in on):
            order.append((on[1][0] - on[0][0]) / r.fs * 1e3)
    print(f"# CPU: {cpu_model()}; pad scenes ({N_RIDGES} ridges, build_options.TEST_KWARGS): {len(train)} training "
          f"(seed {PAD_TRAIN_SEED}), {len(val)} validation (seed {PAD_VALIDATION_SEED}); scored ridges {SCORED}: "
          f"{kinds.count('release')} release, {kinds.count('gradual')} gradual onsets, "
          f"{kinds.count(None)} without slip")
    if order:
        print(f"# ridge 1 slips {np.median(order):.0f} ms (median; {np.min(order):.0f}-{np.max(order):.0f}) after "
              f"the outer ridge 0 in the first 40 validation scenes where both slip")
    net = SlipDetector.default()
    thr_net = float(net.metadata.get("slip_threshold", 0.8))
    if args.train_noise is not None or args.gains:
        print(f"# trees trained on two copies of every training scene in every condition, noise "
              f"{args.train_noise or 'of the condition'} V rms, gains {'0.6-1.7' if args.gains else 'none'}")
    print("\n| condition | detector | inputs | detection at 1 / 2 / 3 % false alarms: all (gradual) "
          "| gradual latency at 2 % (mean, ms) | at y_slip >= 0.8: detection (gradual) / false alarms |")
    print("|---|---|---|---|---|---|")
    headline = float("nan")
    for ci, (cond, white) in enumerate((("noise-free", 0.0), ("1 mV rms white", 1e-3))):
        tr, va = noise_free(train), noise_free(val)
        if white:
            tr = with_noise(tr, cond, seed=7000 + ci)
            va = with_noise(va, cond, seed=8000 + ci)
        if args.train_noise is not None:
            tr = augment_noise(train, 2, tuple(args.train_noise), seed=2)
        gains = (np.exp(np.random.default_rng(1).uniform(np.log(0.6), np.log(1.7), len(tr))) if args.gains
                 else np.ones(len(tr)))
        ftr = [pad_feature_sets(g * features_from_result(r, "stress_rate_bank")) for r, g in zip(tr, gains)]
        fva = [pad_feature_sets(features_from_result(r, "stress_rate_bank")) for r in va]
        Y = np.concatenate([targets_from_result(r)[0][:, ::2].ravel() for r in tr])

        def report(name, n_in, scores, consecutive, at_08=None):
            sc = [s[list(SCORED)] for s in scores]
            curve = roc(sc, va, kinds, consecutive=consecutive)
            cells = []
            for fa in (0.01, 0.02, 0.03):
                p = curve.at_false_alarm(fa)
                cells.append(f"{100 * p['detection_rate']:.1f} ({100 * p['detection_gradual']:.1f})")
            thr = curve.at_false_alarm(0.02)["threshold"]
            lat = []
            for s, r in zip(sc, va):
                g, _ = targets_from_result(r)
                for i in range(len(SCORED)):
                    lat.append(latency_at(r.t, s[i], g[i], thr, consecutive))
            lat = np.array(lat)
            gmask = np.array([k == "gradual" for k in kinds])
            glat = lat[gmask]
            glat = glat[np.isfinite(glat)]
            last = "-"
            if at_08 is not None:
                q = curve.at_threshold(at_08)
                last = (f"{100 * q['detection_rate']:.1f} ({100 * q['detection_gradual']:.1f}) / "
                        f"{100 * q['false_alarm_rate']:.1f} %")
            print(f"| {cond} | {name} | {n_in} | " + " / ".join(cells) + f" | "
                  f"{1e3 * glat.mean() if glat.size else float('nan'):.1f} | {last} |", flush=True)
            return curve

        c = report("bundled filter-bank net", 17,
                   [net.run(features_from_result(r, net.features, estimator=net.metadata.get("estimator")),
                            fs=r.fs)[0] for r in va], 1, thr_net)
        if cond == "noise-free":
            headline = c.at_false_alarm(0.02)["detection_rate"]
        for name in ftr[0]:
            X = np.concatenate([f[name][:, ::2].reshape(-1, f[name].shape[2]) for f in ftr])
            clf = fit_bound_classifier(X, Y, max_iter=QUICK_TREES if quick else BOUND_TREES)
            probs = [clf.predict_proba(f[name].reshape(-1, f[name].shape[2]))[:, 1].reshape(N_RIDGES, -1)
                     for f in fva]
            report(f"trees: {name}", X.shape[1], probs, 3)
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return headline


if __name__ == "__main__":
    main()
