"""Training choices of the filter-bank net, compared on the build's validation scenes only.

Each variant is trained as the build trains (``selection.train_selected``: initial seeds,
checkpoints every 25 iterations, the best by ``detection - 10 x false alarms`` on the
validation scenes, seed ``build_options.VALIDATION_SEED``) on the build's training scenes plus
its extra scenes from the held-out ranges (seed ``build_options.EXTRA_TRAIN_SEED``), two noise
copies each. The kept candidate of each variant is then scored on the same validation
scenes under the noise conditions of the held-out table (the scenes' own noise,
noise-free, 1 mV rms white). The held-out seed (``build_options.TEST_SEED``) is not touched:
the variant chosen here is the one the README reports on it.

Run: ``python bench/detector_bank_sweep.py --cache out/scenes [--out DIR] [--extra 96]`` (about 4 min with
96 extra scenes; the scenes are simulated first if the cache lacks them). ``--quick``: 6 + 4 training and 8
validation scenes simulated here, 10 iterations with checkpoints every 5, a smoke run of a few seconds.
``main`` returns the number of rows printed (variant x condition).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from tactile_mirror.cli.arguments import add_workers_options, open_workers  # (after the thread settings)

#: A smaller bank (bench/detector_bank_study.py's): three low-passes, no |d| channels, 13 inputs.
LEAN_BANK = {"lp_taus": [0.008, 0.032, 0.128], "abs_taus": [], "load_tau": 0.5, "peak_tau": 2.0}

#: name -> (n_hidden, negative_weight, noise range V rms, candidates[, bank])
VARIANTS = {
    "H16 nw10 noise0-5mV": (16, 10.0, (0.0, 5e-3), 1),
    "H16 nw30 noise0-5mV": (16, 30.0, (0.0, 5e-3), 1),
    "H16 nw100 noise0-5mV": (16, 100.0, (0.0, 5e-3), 1),
    "H16 nw30 noise0-2mV": (16, 30.0, (0.0, 2e-3), 1),
    "H8 nw30 noise0-5mV": (8, 30.0, (0.0, 5e-3), 1),
    "lean H16 nw30 noise0-5mV": (16, 30.0, (0.0, 5e-3), 1, LEAN_BANK),
    "H16 nw20 noise0-5mV": (16, 20.0, (0.0, 5e-3), 1),
    "H16 nw30 noise0-5mV 4 seeds": (16, 30.0, (0.0, 5e-3), 4),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes")
    ap.add_argument("--maxiter", type=int, default=None,
                    help="L-BFGS-B iterations (default 300; --quick: 10)")
    ap.add_argument("--out", default=None, help="directory for the kept weights of each variant")
    ap.add_argument("--only", nargs="*", help="variant names to run")
    ap.add_argument("--extra", type=int, default=None,
                    help="extra training scenes (seed build_options.EXTRA_TRAIN_SEED; default 96, --quick: 4)")
    ap.add_argument("--quick", action="store_true",
                    help="6 training scenes and few others, simulated here; 10 iterations (a smoke run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    args.maxiter = (10 if args.quick else 300) if args.maxiter is None else args.maxiter
    args.extra = (4 if args.quick else 96) if args.extra is None else args.extra
    every = 5 if args.quick else 25
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import simulated, study_training_scenes
    from detector_heldout import table_rows
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector import build_options, selection
    from tactile_mirror.lab.detector.augment import augment_gains, augment_noise
    from tactile_mirror.lab.detector.evaluation import noise_free as clean
    from tactile_mirror.lab.detector.evaluation import onset_kinds, with_noise
    from tactile_mirror.lab.detector.training import make_training_set
    from tactile_mirror.lab.measure import cpu_model

    t0 = time.perf_counter()
    cache = args.cache or None
    small = {"n_train": 6, "quick": True} if args.quick else {}
    with open_workers(args) as executor:
        train = study_training_scenes(cache, args.extra, False, executor=executor, **small)
        val = simulated(8 if args.quick else 120, build_options.VALIDATION_SEED, build_options.TEST_KWARGS, cache, False,
                        args.quick, executor)
        kinds = onset_kinds(val)
        scorer = selection.ValidationScorer(val)
        conds = {"own noise": val, "noise-free": clean(val), "1 mV rms white": with_noise(clean(val), "1 mV rms white", 7)}
        print(f"# CPU: {cpu_model()}; {len(train)} training scenes; validation seed {build_options.VALIDATION_SEED}: "
              f"{kinds.count('release')} release, {kinds.count('gradual')} gradual", flush=True)
        rows = []
        for name, (h, nw, noise, cand, *bank) in VARIANTS.items():
            if args.only and name not in args.only:
                continue
            t1 = time.perf_counter()
            seqs = augment_noise(train, build_options.NOISE_COPIES, noise, seed=2)
            ts = augment_gains(make_training_set(seqs, "stress_rate_bank", bank=bank[0] if bank else None),
                               (0.6, 1.7), seed=1)
            opts = {**build_options.TRAIN_OPTIONS, "negative_weight": nw}
            w, _k, _scores = selection.train_selected(ts, h, args.maxiter, 0, cand, every, scorer, True, False,
                                                      {"kind": "jordan_bank"}, executor=executor, **opts)
            det = SlipDetector(w)
            if args.out:
                os.makedirs(args.out, exist_ok=True)
                w.save(os.path.join(args.out, name.replace(" ", "_") + f"_extra{args.extra}.npz"))
            for cond, res in conds.items():
                outs = []
                for r in res:
                    ys, _, yp = det.run(features_from_result(r, det.features, estimator=det.metadata.get("estimator")),
                                        fs=r.fs)
                    outs.append((ys, yp))
                row = table_rows(name, outs, val, kinds, cond)
                row["iteration"] = w.metadata["training"]["iterations"]
                rows.append(row)
                print(f"{name:<24} extra {args.extra:>3} {cond:<15} it {row['iteration']:>4} det {100 * row['detection']:5.1f} "
                      f"FA {100 * row['false_alarm']:4.1f} rel {100 * row['det_release']:5.1f} "
                      f"grad {100 * row['det_gradual']:5.1f} lat {row['lat_release_ms']:.1f}/{row['lat_gradual_ms']:.1f} ms"
                      f"  ({time.perf_counter() - t1:.0f} s)", flush=True)
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return len(rows)


if __name__ == "__main__":
    main()
