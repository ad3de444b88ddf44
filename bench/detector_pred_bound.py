"""How well can any causal estimator place ``y_pred`` at a slip's onset?

``y_pred``'s training target is ``0.8 |F_y| / (mu_k F_z)`` (the tangential load as a share
of what the sliding contact carries, :func:`tactile_mirror.detector.data_prep.targets_from_result`)
and 1 in gross slip; the detector issue asks for ``y_pred`` within 0.8 +- 0.1 at the onset
for 90 % of slips. This study puts the bundled filter-bank net next to boosted regression
trees trained on the same target with more than the net has:

* ``trees``: the ridge's own filter-bank inputs (what the net reads);
* ``trees + mu_k``: those and the scene's kinetic friction coefficient, which no strip
  measures before the contact slides: the estimator an oracle of the friction would allow.

All three are causal (the bank's filters are causal; the trees map one sample's inputs).
Trained on the build's training scenes plus the bound study's extra scenes (seed 99), scored
on the build's held-out scenes (``TEST_SEED``), noise-free. ``y_pred`` is read at two
samples: the last one before the onset of gross slip (the prediction "slip is coming"
proper) and the onset sample itself (where the target is already 1 and a net that sees
the slip start answers it); per onset kind (``detector.evaluate.onset_kinds``).

Run: ``python bench/detector_pred_bound.py [--cache out/scenes] [--extra 96]`` (needs
scikit-learn; about 3 min with the scenes cached; ``--quick``: 6 + 4 training and 8 held-out scenes
simulated here, 20 boosting iterations, a smoke run of a few seconds). ``main`` returns the share of
the bundled net's slips whose ``y_pred`` at the last sample before the onset lies in 0.8 +- 0.1.
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

BAND = 0.1  # y_pred within 0.8 +- BAND


def ridge_rows(results):
    """Per result: (inputs per ridge (n_ridges, n, 18): the 17 bank inputs and mu_k; y_pred target (n_ridges, n);
    gross slip (n_ridges, n))."""
    from tactile_mirror.detector.data_prep import features_from_result, targets_from_result

    out = []
    for r in results:
        f = features_from_result(r, "stress_rate_bank")  # (n_ridges, 17, n), causal
        own = np.transpose(f, (0, 2, 1))
        mu_k = r.scene.friction * r.scene.kinetic_ratio
        cols = [own, np.full(own.shape[:2] + (1,), mu_k)]
        gross, target = targets_from_result(r)
        n_r = own.shape[0]
        out.append((np.concatenate(cols, axis=-1), np.broadcast_to(target, (n_r, own.shape[1])),
                    np.broadcast_to(gross, (n_r, own.shape[1]))))
    return out


def onsets(gross_row):
    on = np.flatnonzero(gross_row >= 0.5)
    return int(on[0]) if on.size else None


def pred_at_onsets(rows) -> dict:
    """``y_pred`` at the onsets of gross slip, per onset kind: ``rows`` yields (``y_pred`` row,
    gross-slip row, onset kind) per sequence; returns {kind: (values at the last sample before
    the onset, values at the onset sample)} for the release and gradual onsets."""
    vals = {"release": ([], []), "gradual": ([], [])}
    for yp, gross, kind in rows:
        o = onsets(gross)
        if o is not None and kind in vals:
            vals[kind][0].append(yp[max(o - 1, 0)])
            vals[kind][1].append(yp[o])
    return {k: (np.asarray(b), np.asarray(a)) for k, (b, a) in vals.items()}


def pred_table_rows(name: str, vals: dict) -> list:
    """Markdown rows of :func:`pred_at_onsets`' values per kind and for all: slips, share in
    0.8 +- BAND before and at the onset, medians, 10-90 % before."""
    both = (np.concatenate([vals[k][0] for k in vals]), np.concatenate([vals[k][1] for k in vals]))
    out = []
    for kind, (b, a) in list(vals.items()) + [("all", both)]:
        if b.size:
            out.append(f"| {name} | {kind} | {b.size} | {100 * np.mean(np.abs(b - 0.8) <= BAND):.0f} % "
                       f"| {100 * np.mean(np.abs(a - 0.8) <= BAND):.0f} % | {np.median(b):.2f} / {np.median(a):.2f} "
                       f"| {np.quantile(b, 0.1):.2f}-{np.quantile(b, 0.9):.2f} |")
    return out


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes",
                    help="directory of cached simulated scenes ('' for none)")
    ap.add_argument("--n-test", type=int, default=None, help="held-out scenes (default 200; --quick: 8)")
    ap.add_argument("--extra", type=int, default=None,
                    help="extra training scenes (seed 99, held-out ranges; default 96, --quick: 4)")
    ap.add_argument("--every", type=int, default=4, help="training samples: every n-th")
    ap.add_argument("--quick", action="store_true",
                    help="a few scenes simulated here, few boosting iterations (a smoke run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    quick = args.quick
    for name, full, small in (("n_test", 200, 8), ("extra", 96, 4)):
        if getattr(args, name) is None:
            setattr(args, name, small if quick else full)
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import QUICK_TREES, header, simulated, study_training_scenes
    from sklearn.ensemble import HistGradientBoostingRegressor
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector import build_options
    from tactile_mirror.lab.detector.evaluation import onset_kinds
    from tactile_mirror.lab.measure import cpu_model

    header("y_pred at the onset: the bundled net against causal regressors with more information")
    cache = args.cache or None
    t0 = time.perf_counter()
    with open_workers(args) as executor:
        train = study_training_scenes(cache, args.extra, executor=executor,
                                      **({"n_train": 6, "quick": True} if quick else {}))
        test = simulated(args.n_test, build_options.TEST_SEED, build_options.TEST_KWARGS, cache, quick=quick,
                         executor=executor)
    kinds = onset_kinds(test)
    print(f"{len(train)} training scenes (seeds {build_options.TRAIN_SEED}, {build_options.EXTRA_TRAIN_SEED}), {len(test)} held-out "
          f"(seed {build_options.TEST_SEED}); simulation {time.perf_counter() - t0:.0f} s; CPU: {cpu_model()}")

    # y_pred of every model on every held-out ridge: {name: [(n_ridges, n) per scene]}
    preds = {}
    det = SlipDetector.default()
    preds["filter-bank net (bundled)"] = [det.run(features_from_result(r, "stress_rate"))[2] for r in test]
    tr, te = ridge_rows(train), ridge_rows(test)
    for name, ncol in (("trees", 17), ("trees + mu_k", 18)):
        X = np.vstack([f[:, ::args.every, :ncol].reshape(-1, ncol) for f, _, _ in tr])
        Y = np.concatenate([y[:, ::args.every].ravel() for _, y, _ in tr])
        t1 = time.perf_counter()
        reg = HistGradientBoostingRegressor(max_iter=QUICK_TREES if quick else 300, random_state=0).fit(X, Y)
        preds[name] = [np.clip(reg.predict(f[..., :ncol].reshape(-1, ncol)), 0, 1).reshape(f.shape[:2])
                       for f, _, _ in te]
        print(f"  {name}: {X.shape[0]} samples, {ncol} inputs, fit {time.perf_counter() - t1:.0f} s")

    print(f"\n| estimator | onset kind | slips | y_pred in 0.8 +- {BAND}: last sample before the onset | at the onset "
          f"sample | median before / at | 10-90 % before |")
    print("|---|---|---:|---:|---:|---:|---:|")
    in_band = {}
    for name, p in preds.items():
        # kinds are per sequence in the order of onset_kinds: scene by scene, ridge by ridge
        rows = ((yp[k], gross[k]) for yp, (_, _, gross) in zip(p, te) for k in range(yp.shape[0]))
        vals = pred_at_onsets((y, g, kind) for (y, g), kind in zip(rows, kinds))
        before = np.concatenate([b for b, _ in vals.values()])
        in_band[name] = float(np.mean(np.abs(before - 0.8) <= BAND)) if before.size else float("nan")
        for line in pred_table_rows(name, vals):
            print(line)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return in_band["filter-bank net (bundled)"]


if __name__ == "__main__":
    main()
