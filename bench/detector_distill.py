"""Does a teacher's soft target lift the filter-bank net's curve? A study on validation scenes.

The boosted trees on the filter bank's 17 inputs reach further along the threshold sweep
than the net trained on the same inputs (``bench/detector_bank_study.py``): the net's
target ``y_slip`` is a step at the onset of gross slip, which the signals of a creeping
slip cannot show at once. This study trains the net, by the build's recipe
(``detector.build``, kind ``"jordan_bank"``), on the teacher's probability instead:

1. the build's training set (its 64 scenes plus the extra scenes from the held-out ranges,
   noise and gain augmentation);
2. trees (scikit-learn ``HistGradientBoostingClassifier``) *cross-fitted* on it: each
   scene's samples are scored by trees fitted on the other folds' scenes, so the teacher's
   probability is never its own training label;
3. the net's ``y_slip`` target becomes ``blend * hard + (1 - blend) * p_teacher``; the
   loss weights still come from the hard classes (slip / no slip).

Candidates (seeds and checkpoints) are kept by the build's rule (detection at the
calibration's false-alarm rate on the validation scenes in their own noise), and the
kept nets and the bundled one are scored along the threshold sweep on the build's
validation scenes (seed ``build_options.VALIDATION_SEED``) noise-free and with 1 mV rms: never
the held-out seed.

Run: ``python bench/detector_distill.py --cache out/scenes [--blend 0 0.5] [--seeds 2]`` (``--quick``:
6 + 4 training and 8 validation scenes simulated here, 20 boosting iterations, one seed of 10
iterations with checkpoints every 5, a smoke run of a few seconds). ``main`` returns the bundled
net's detection rate at 2 % false alarms on the validation scenes, noise-free.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from tactile_mirror.cli.arguments import add_workers_options, open_workers


def teacher_targets(ts, groups, folds: int = 4, stride: int = 2, seed: int = 0, trees: int | None = None):
    """Cross-fitted tree probabilities of slip for every sample of ``ts`` (0 on padding);
    ``trees``: boosting iterations (default the bound study's)."""
    from common import BOUND_TREES, fit_bound_classifier

    n_seq, n_ch, n = ts.x.shape
    fold = np.random.default_rng(seed).permutation(np.max(groups) + 1) % folds
    fold = fold[groups]
    p = np.zeros((n_seq, n))
    for k in range(folds):
        tr, te = np.flatnonzero(fold != k), np.flatnonzero(fold == k)
        m = ts.mask[tr][:, ::stride]
        X = np.moveaxis(ts.x[tr][:, :, ::stride], 1, 2)[m]
        Y = (ts.y_slip[tr][:, ::stride] >= 0.5)[m].astype(np.float64)
        clf = fit_bound_classifier(X, Y, seed, trees or BOUND_TREES)
        for i in te:
            p[i] = clf.predict_proba(ts.x[i].T)[:, 1] * ts.mask[i]
        print(f"  teacher fold {k + 1}/{folds}: {X.shape[0]} samples", flush=True)
    return p


@contextlib.contextmanager
def loss_weights_from(hard):
    """Within the block, the training's y_slip loss weights come from the classes of ``hard``
    (the hard targets), whatever target the training set carries: ``loss_weights`` of the
    module that defines ``train_detector`` is replaced, and put back afterwards."""
    from tactile_mirror.lab.detector import training
    from tactile_mirror.lab.detector.training import TrainingSet

    module = sys.modules[training.train_detector.__module__]
    hard_weights = module.loss_weights

    def weights_from_hard(data, *a, **k):
        return hard_weights(TrainingSet(data.x, hard, data.y_pred, data.mask,
                                        data.fs, data.features, data.estimator, data.targets, data.load_tau,
                                        data.bank), *a, **k)

    module.loss_weights = weights_from_hard
    try:
        yield
    finally:
        module.loss_weights = hard_weights


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes")
    ap.add_argument("--extra", type=int, default=None, help="extra training scenes (default 240; --quick: 4)")
    ap.add_argument("--n-validation", type=int, default=None,
                    help="validation scenes (default 480; --quick: 8)")
    ap.add_argument("--blend", type=float, nargs="+", default=[0.0, 0.5],
                    help="weights of the hard target in the net's y_slip target")
    ap.add_argument("--seeds", type=int, default=None,
                    help="initial seeds per variant (default 2; --quick: 1)")
    ap.add_argument("--maxiter", type=int, default=None,
                    help="L-BFGS-B iterations (default 300; --quick: 10)")
    ap.add_argument("--negative-weight", type=float, default=30.0)
    ap.add_argument("--select-fa", type=float, default=0.015)
    ap.add_argument("--save", default=None, help="directory to keep each variant's selected weights in")
    ap.add_argument("--quick", action="store_true",
                    help="6 training scenes and few others, simulated here; short trainings (a smoke run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    quick = args.quick
    for name, full, small in (("extra", 240, 4), ("n_validation", 480, 8), ("seeds", 2, 1),
                              ("maxiter", 300, 10)):
        if getattr(args, name) is None:
            setattr(args, name, small if quick else full)
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

    from common import QUICK_TREES, simulated, study_training_scenes
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector import build_options, selection
    from tactile_mirror.lab.detector.augment import augment_gains, augment_noise
    from tactile_mirror.lab.detector.evaluation import noise_free, onset_kinds, with_noise
    from tactile_mirror.lab.detector.thresholds import roc
    from tactile_mirror.lab.detector.training import TrainingSet, make_training_set
    from tactile_mirror.lab.measure import cpu_model

    t0 = time.perf_counter()
    # (the scenes only: the trainings replace train_detector's loss weights in this process)
    with open_workers(args) as executor:
        train = study_training_scenes(args.cache, args.extra, executor=executor,
                                      **({"n_train": 6, "quick": True} if quick else {}))
        val = simulated(args.n_validation, build_options.VALIDATION_SEED, build_options.TEST_KWARGS, args.cache,
                        quick=quick, executor=executor)
    kinds = onset_kinds(val)
    print(f"# CPU: {cpu_model()}; {len(train)} training scenes, {len(val)} validation scenes "
          f"(seed {build_options.VALIDATION_SEED}): {kinds.count('release')} release, {kinds.count('gradual')} gradual")

    # The build's training set for kind "jordan_bank" (one ridge per scene, noise copies, gains).
    seqs = augment_noise(train, build_options.NOISE_COPIES, build_options.NOISE_RANGE, seed=2)
    groups = np.repeat(np.arange(len(train)), build_options.NOISE_COPIES)
    ts = augment_gains(make_training_set(seqs, "stress_rate_bank"), (0.6, 1.7), seed=1)
    assert ts.n_seq == groups.size
    print(f"# {ts.n_seq} training sequences, {int(ts.mask.sum())} samples", flush=True)
    p = teacher_targets(ts, groups, trees=QUICK_TREES if quick else None)
    hard = ts.y_slip

    clean_val = noise_free(val)
    noisy_val = with_noise(clean_val, "1 mV rms white", seed=4001)

    def curves(det):
        out = {}
        for name, res in (("noise-free", clean_val), ("1 mV rms", noisy_val)):
            scores = [det.run(features_from_result(r, det.features, estimator=det.metadata.get("estimator")),
                              fs=r.fs)[0] for r in res]
            out[name] = roc(scores, val, kinds)
        return out

    def cell(c, fa):
        q = c.at_false_alarm(fa)
        return f"{100 * q['detection_rate']:.1f} ({100 * q['detection_gradual']:.1f})"

    rows = [("bundled net", curves(SlipDetector.default()))]
    scorer = selection.ValidationScorer(val, at_false_alarm=args.select_fa)
    opts = {"negative_weight": args.negative_weight, "normalisation": "rms", "pred_weight": 4.0}
    for blend in args.blend:
        target = blend * hard + (1.0 - blend) * p
        ts_b = TrainingSet(ts.x, target, ts.y_pred, ts.mask, ts.fs, ts.features, ts.estimator,
                           {**ts.targets, "y_slip_teacher": "cross-fitted boosted trees on the bank inputs",
                            "y_slip_blend": blend}, ts.load_tau, ts.bank)
        t1 = time.perf_counter()
        # the loss weights come from the hard classes whatever the target (the soft target
        # near an onset is below 0.5 where the hard one is 1)
        with loss_weights_from(hard):
            w, k, scores = selection.train_selected(ts_b, 16, args.maxiter, 0, args.seeds, 5 if quick else 25,
                                                scorer, True, True,
                                                {"kind": "jordan_bank", "distill_blend": blend}, **opts)
        tr = w.metadata["training"]
        print(f"# blend {blend}: kept seed {tr['seed']} at {tr['iterations']} iterations, "
              f"score {scores[k]['score']:.3f} ({time.perf_counter() - t1:.0f} s)", flush=True)
        if args.save:
            os.makedirs(args.save, exist_ok=True)
            w.save(os.path.join(args.save, f"distill_{blend:g}.npz"))
        rows.append((f"soft target, blend {blend:g}", curves(SlipDetector(w))))

    print("\n| validation, detection at 1 / 2 / 3 % false alarms, all (gradual) | noise-free | 1 mV rms |")
    print("|---|---|---|")
    for name, c in rows:
        cells = [" / ".join(cell(c[cond], fa) for fa in (0.01, 0.02, 0.03)) for cond in ("noise-free", "1 mV rms")]
        print(f"| {name} | " + " | ".join(cells) + " |")
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return rows[0][1]["noise-free"].at_false_alarm(0.02)["detection_rate"]


if __name__ == "__main__":
    main()
