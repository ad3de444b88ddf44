"""Which causal features carry what the bound classifier uses? A study on validation scenes.

The bound study's classifier (``bench/detector_bound.py``) reads the four stress rates
now and at lags of 1-256 ms plus their integrals since contact (45 inputs) and finds
the gradual onsets the paper's net misses. A recurrent net with a small state cannot
hold 256 ms of lags; a bank of first-order filters can hold their gist. This study
trains the same classifier (gradient-boosted trees, scikit-learn) on several input sets
and scores each, by the threshold sweep of ``detector.evaluate.roc`` (alarm: 3 samples
in a row), on the build's *validation* scenes (seed ``build_options.VALIDATION_SEED``), never on
the held-out seed the nets are reported on:

* ``rates``: the four rates now (what the paper's net sees at one instant);
* ``rates+load``: plus the load-memory net's leaky load integrals;
* ``lags (bound)``: the bound study's 45 lag and integral inputs;
* ``bank``: the rates plus the filter bank of ``detector.bank`` (:data:`DEFAULT_BANK`);
* ``bank, no peak`` and ``bank, no |d|``: the bank without one of its parts;
* ``lean bank``: :data:`LEAN_BANK`, three low-passes and no ``|d|`` (13 inputs, a cheaper kernel);
* ``bank + u envelopes``: the bank plus low-passes (8 and 32 ms) of ``|u_L - u_R|`` and ``|u_L + u_R|``,
  the envelopes of the second-order rates (21 inputs): do the flickers of the ridge edges that
  slide before a creeping slip show in the u channels, which the bank passes through raw?
* ``bank + fast-shear envelope``: the bank plus low-passes (8 and 32 ms) of ``|d - lp_4ms(d)|``, the envelope of
  the shear rate's fast part (19 inputs), the same question asked of v.

``--only NAME ...`` runs some of the sets.

Training scenes: the build's training set plus its extra scenes from the held-out ranges
(``--extra``, seed ``build_options.EXTRA_TRAIN_SEED``). Noise-free signals (their circuit outputs
without noise), and with ``--noise`` 1 mV rms white noise too.

Run: ``python bench/detector_bank_study.py --cache out/scenes [--extra 96] [--noise]`` (``--quick``:
6 + 4 training and 8 validation scenes simulated here, 20 boosting iterations, a smoke run of a few
seconds). ``main`` returns the number of rows of the table (condition x input set scored).
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

#: A smaller bank: three low-passes, no |d| channels (13 inputs with the four rates).
LEAN_BANK = {"lp_taus": [0.008, 0.032, 0.128], "abs_taus": [], "load_tau": 0.5, "peak_tau": 2.0}


def feature_sets(x, fs):
    """Per-sample inputs of each studied set from one ridge's (4, n) stress rates."""
    from types import SimpleNamespace

    from detector_bound import window_features
    from scipy.signal import lfilter
    from tactile_mirror.detector.bank import DEFAULT_BANK, bank_features
    from tactile_mirror.detector.memory import memory_features

    def lp(y, tau):
        a = np.exp(-1.0 / (fs * tau))
        return lfilter([1.0 - a], [1.0, -a], y)

    bank = bank_features(x[None], fs)[0]
    du, su = np.abs(x[2] - x[3]), np.abs(x[2] + x[3])
    d = x[0] - x[1]
    hf = np.abs(d - lp(d, 0.004))
    u_env = np.vstack([lp(du, 0.008), lp(du, 0.032), lp(su, 0.008), lp(su, 0.032)])
    hf_env = np.vstack([lp(hf, 0.008), lp(hf, 0.032)])
    n_lp, n_abs = len(DEFAULT_BANK["lp_taus"]), len(DEFAULT_BANK["abs_taus"])
    peak = 4 + 2 * n_lp + n_abs + 2
    keep_no_abs = [i for i in range(bank.shape[0]) if not (4 + 2 * n_lp <= i < 4 + 2 * n_lp + n_abs)]
    return {
        "rates": x.T,
        "rates+load": memory_features(x[None], fs)[0, :6].T,
        "lags (bound)": window_features(SimpleNamespace(features=x[None], fs=fs), True),
        "bank": bank.T,
        "bank, no peak": np.delete(bank, peak, axis=0).T,
        "bank, no |d|": bank[keep_no_abs].T,
        "lean bank": bank_features(x[None], fs, LEAN_BANK)[0].T,
        "bank + u envelopes": np.vstack([bank, u_env]).T,
        "bank + fast-shear envelope": np.vstack([bank, hf_env]).T,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes")
    ap.add_argument("--extra", type=int, default=None, help="extra training scenes (default 96; --quick: 4)")
    ap.add_argument("--n-validation", type=int, default=None,
                    help="validation scenes (default 120; --quick: 8)")
    ap.add_argument("--noise", action="store_true", help="also with 1 mV rms white noise")
    ap.add_argument("--only", nargs="*", help="input sets to run (default: all)")
    ap.add_argument("--quick", action="store_true",
                    help="6 training scenes and few others, simulated here; few boosting iterations (a smoke "
                         "run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    args.extra = (4 if args.quick else 96) if args.extra is None else args.extra
    args.n_validation = (8 if args.quick else 120) if args.n_validation is None else args.n_validation
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import BOUND_TREES, QUICK_TREES, fit_bound_classifier, simulated, study_training_scenes
    from tactile_mirror.detector.data_prep import features_from_result, targets_from_result
    from tactile_mirror.lab.detector import build_options
    from tactile_mirror.lab.detector.evaluation import noise_free as clean
    from tactile_mirror.lab.detector.evaluation import onset_kinds, with_noise
    from tactile_mirror.lab.detector.thresholds import roc
    from tactile_mirror.lab.measure import cpu_model

    t0 = time.perf_counter()
    cache = args.cache or None
    with open_workers(args) as executor:
        train = study_training_scenes(cache, args.extra, executor=executor,
                                      **({"n_train": 6, "quick": True} if args.quick else {}))
        val = simulated(args.n_validation, build_options.VALIDATION_SEED, build_options.TEST_KWARGS, cache,
                        quick=args.quick, executor=executor)
    kinds = onset_kinds(val)
    print(f"# CPU: {cpu_model()}; {len(train)} training scenes, {len(val)} validation scenes "
          f"(seed {build_options.VALIDATION_SEED}): {kinds.count('release')} release, {kinds.count('gradual')} gradual")
    conds = [("noise-free", 0.0)] + ([("1 mV rms white", 1e-3)] if args.noise else [])
    print("\n| condition | inputs | n | detection at 2 % FA (all / release / gradual) | at 3 % | at 5 % |")
    print("|---|---|---|---|---|---|")
    n_rows = 0
    for ci, (cond, white) in enumerate(conds):
        tr, va = clean(train), clean(val)
        if white:
            tr = with_noise(tr, cond, seed=3000 + ci)
            va = with_noise(va, cond, seed=4000 + ci)
        ftr = [feature_sets(features_from_result(r)[0], r.fs) for r in tr]
        fva = [feature_sets(features_from_result(r)[0], r.fs) for r in va]
        Y = np.concatenate([targets_from_result(r)[0][0][::2] for r in tr])
        for name in ftr[0]:
            if args.only and name not in args.only:
                continue
            X = np.vstack([f[name][::2] for f in ftr])
            clf = fit_bound_classifier(X, Y, max_iter=QUICK_TREES if args.quick else BOUND_TREES)
            probs = [clf.predict_proba(f[name])[:, 1][None] for f in fva]
            curve = roc(probs, val, kinds, consecutive=3)
            cells = []
            for fa in (0.02, 0.03, 0.05):
                p = curve.at_false_alarm(fa)
                cells.append(f"{100 * p['detection_rate']:.1f} / {100 * p['detection_release']:.1f} / {100 * p['detection_gradual']:.1f} (FA {100 * p['false_alarm_rate']:.1f})")
            print(f"| {cond} | {name} | {X.shape[1]} | " + " | ".join(cells) + " |", flush=True)
            n_rows += 1
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return n_rows


if __name__ == "__main__":
    main()
