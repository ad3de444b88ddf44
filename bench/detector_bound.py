"""How well can any causal detector do on these strip signals? A reference for the slip detector.

The recurrent net reads four strip signals and remembers one number (its own
y_pred). To tell whether its misses and false alarms come from that small
network or from the signals themselves, this study trains a far more flexible
causal classifier on the same signals and scores it with the same metrics
(``detector.evaluate``) on the same held-out scenes as the bundled detector:

* gradient-boosted trees (scikit-learn ``HistGradientBoostingClassifier``) on,
  per sample, the four signals now and at lags of 1-256 ms, and their running
  integrals since contact (the strip stress changes): 45 inputs, 256 ms of
  explicit history where the net has one feedback value;
* trained on many more scenes than the net (the training set plus scenes drawn
  from the held-out ranges, other seeds), which favours the classifier;
* an alarm needs ``p >= threshold`` for 3 samples in a row (3 ms);
* once on the noisy signals the detector sees and once on noise-free ones.

Needs scikit-learn (``pip install scikit-learn``; not a dependency of the
package). Run: ``python bench/detector_bound.py [--quick]`` (about 6 min; the
scene simulation is most of it; ``--quick``: 6 + 4 training and 8 held-out scenes simulated here,
20 boosting iterations, a smoke run of a few seconds). ``main`` returns the bundled net's
detection rate on the held-out scenes.
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from types import SimpleNamespace

import numpy as np
from tactile_mirror import scenes
from tactile_mirror.cli.arguments import add_workers_options, open_workers
from tactile_mirror.detector import SlipDetector
from tactile_mirror.detector.data_prep import features_from_result, targets_from_result
from tactile_mirror.lab.detector import build_options, scene_cache
from tactile_mirror.lab.detector.evaluation import analyse_sequence, onset_kinds
from tactile_mirror.lab.measure import cpu_model

LAGS = (1, 2, 4, 8, 16, 32, 64, 128, 256)


def window_features(result, noisy: bool) -> np.ndarray:
    """(n, 45): the signals, their lags and their integrals since contact (ridge 0)."""
    if noisy:
        x = features_from_result(result)[0]
    else:
        v, u = result.scene.circuit.simulate(result.stress, result.fs)
        x = features_from_result(SimpleNamespace(v_out=v, u_out=u, fs=result.fs, circuit=result.scene.circuit))[0]
    cols = [x]
    for lag in LAGS:
        xl = np.zeros_like(x)
        xl[:, lag:] = x[:, :-lag]
        cols.append(xl)
    integ = np.cumsum(x[:2], axis=1) / result.fs
    cols += [integ, np.vstack([integ[0] - integ[1], integ[0] + integ[1]]),
             np.maximum.accumulate(np.abs(integ[0] - integ[1]))[None]]
    return np.vstack(cols).T


def debounce(alarm: np.ndarray, k: int = 3) -> np.ndarray:
    out = alarm.copy()
    for j in range(1, k):
        out[j:] &= alarm[:-j]
        out[:j] = False
    return out


def score(seqs, kinds):
    slips = [s for s in seqs if s["slip"]]
    by = {}
    for kind in ("release", "gradual"):
        sel = [s["detected"] for s, k in zip(seqs, kinds) if k == kind]
        by[kind] = (len(sel), float(np.mean(sel)) if sel else float("nan"))
    return (float(np.mean([s["detected"] for s in slips])), float(np.mean([s["false_alarm"] for s in seqs])), by)


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="a few scenes simulated here, few boosting iterations (a smoke run, not the "
                         "figures)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    from common import BOUND_TREES, QUICK_TREES, fit_bound_classifier, quick_results

    n_train, n_extra, n_test = (6, 4, 8) if args.quick else (64, 240, 200)
    print(f"# CPU: {cpu_model()}")
    t0 = time.perf_counter()
    if args.quick:
        train = quick_results(n_train, build_options.TRAIN_SEED, build_options.TRAIN_KWARGS)
        train += quick_results(n_extra, 99, build_options.TEST_KWARGS)
        test = quick_results(n_test, build_options.TEST_SEED, build_options.TEST_KWARGS)
    else:
        with open_workers(args) as executor:
            spread = {} if executor is None else {"executor": executor}
            train = scene_cache.simulate_scenes(scenes.random(n_train, seed=build_options.TRAIN_SEED,
                                                              **build_options.TRAIN_KWARGS), True, **spread)
            train += scene_cache.simulate_scenes(scenes.random(n_extra, seed=99, **build_options.TEST_KWARGS), True,
                                                 **spread)
            test = scene_cache.simulate_scenes(scenes.random(n_test, seed=build_options.TEST_SEED,
                                                             **build_options.TEST_KWARGS), True, **spread)
    print(f"simulated {len(train)} training and {len(test)} held-out scenes in {time.perf_counter() - t0:.0f} s")
    kinds = onset_kinds(test)
    print(f"held-out onsets: {kinds.count('release')} release, {kinds.count('gradual')} gradual, "
          f"{kinds.count(None)} without gross slip")

    det = SlipDetector.default()
    seqs = []
    for r in test:
        ys, _, yp = det.run(features_from_result(r, det.features, estimator=det.metadata.get("estimator")), fs=r.fs)
        seqs.append(analyse_sequence(r.t, ys[0], yp[0], targets_from_result(r)[0][0]))
    d, fa, by = score(seqs, kinds)
    bundled = d
    print(f"\n{'detector':<44} {'thr':>5} {'detect %':>9} {'false %':>8} {'release':>9} {'gradual':>9}")
    print(f"{'Jordan net (bundled), y_slip >= 0.8':<44} {0.8:>5.2f} {100 * d:>9.1f} {100 * fa:>8.1f} "
          f"{100 * by['release'][1]:>9.1f} {100 * by['gradual'][1]:>9.1f}")
    for noisy in (True, False):
        X, Y = [], []
        for r in train:
            f = window_features(r, noisy)[::2]
            X.append(f)
            Y.append(targets_from_result(r)[0][0][::2])
        X, Y = np.vstack(X), np.concatenate(Y)
        clf = fit_bound_classifier(X, Y, max_iter=QUICK_TREES if args.quick else BOUND_TREES)
        probs = [clf.predict_proba(window_features(r, noisy))[:, 1] for r in test]
        for thr in (0.8, 0.9, 0.97, 0.99):
            seqs = [analyse_sequence(r.t, debounce(p >= thr).astype(float), np.zeros_like(p),
                                     targets_from_result(r)[0][0]) for r, p in zip(test, probs)]
            d, fa, by = score(seqs, kinds)
            name = f"boosted trees, 256 ms window, {'noisy' if noisy else 'noise-free'}"
            print(f"{name:<44} {thr:>5.2f} {100 * d:>9.1f} {100 * fa:>8.1f} {100 * by['release'][1]:>9.1f} "
                  f"{100 * by['gradual'][1]:>9.1f}")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return bundled


if __name__ == "__main__":
    main()
