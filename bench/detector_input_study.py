"""Does compressing the filter bank's inputs let the net reach further? A study on validation scenes.

The boosted trees on the bank's 17 inputs reach further along the threshold sweep than
the Jordan net trained on the same inputs. Trees do not care how an input is scaled;
a net with sigmoid hidden units does. The bank's channels are heavy-tailed: a release of
stored shear gives rates and low-passes tens of times their quiet level, while a slip
that creeps in changes them by a fraction of it. Normalised by their rms (the build's
``normalisation="rms"``), the quiet range a creeping onset lives in is squeezed near
zero. This study trains the net, by the build's recipe (kind ``"jordan_bank"``: the
build's training scenes plus the extra scenes from the held-out ranges, two noise copies
each, random gains), on the bank's inputs passed through

- ``linear``: as they are (the build);
- ``asinh/median``: ``asinh(x / k)``, ``k`` the channel's median ``|x|`` over the
  training samples (linear below the typical level, logarithmic above);
- ``asinh/rms``: the same with ``k`` the rms;
- ``softsign/median``: ``x / (k + |x|)`` (one division; bounded);
- ``log/median``: the library's ``sign(x) log(1 + |x| / k)`` (``detector.bank.log_compress``,
  what a bank with knees computes; ``k`` the median, as ``build --compress``);
- ``linear, median scale``: as they are, but normalised by the median ``|x|`` instead of
  the rms (``normalisation="median"``): the hidden units' sigmoids do the compressing;

and keeps, per variant, the seed and checkpoint with the best detection at 2 % false
alarms on the first half (``--swap``: the second) of the build's validation scenes (seed
``build_options.VALIDATION_SEED``; noise-free and 1 mV rms, averaged). It reports the curves on
the *other* half, which chose nothing, next to the bundled net's. The held-out seed is
not used.

Run: ``python bench/detector_input_study.py --cache out/scenes [--variants linear asinh/median] [--seeds 2]``
(``--quick``: 6 + 4 training and 8 validation scenes simulated here, one seed of 10 iterations with
checkpoints every 5, a smoke run of a few seconds). ``main`` returns the bundled net's detection rate at
2 % false alarms on the reporting half, noise-free.
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

VARIANTS = ("linear", "asinh/median", "asinh/rms", "softsign/median", "linear, median scale", "log/median")


def compression(name: str, x, mask):
    """The transform ``f(x)`` of variant ``name``, its knees fitted on ``x`` (n_seq, n_ch, n) and
    kept as ``f.knee`` (None for the linear variants)."""
    from tactile_mirror.lab.detector.training import fit_normalisation

    if name.startswith("linear"):
        def f(v):
            return v
        f.knee = None
        return f
    kind, knee = name.split("/")
    _, k = fit_normalisation(x, mask, knee)
    kk = k[:, None]

    if kind == "log":
        from tactile_mirror.detector.bank import log_compress

        def f(v):
            return log_compress(v, k, axis=-2)
    else:
        def f(v):
            v = np.asarray(v, dtype=np.float64)
            z = v / (kk if v.ndim == 2 else kk[None])
            return np.arcsinh(z) if kind == "asinh" else z / (1.0 + np.abs(z))

    f.knee = k
    return f


def run_net(w, feats):
    """y_slip of weights ``w`` on a list of (n_ridges, 17, n) feature arrays (the numpy recurrence)."""
    from tactile_mirror.detector.network import forward

    out = []
    for x in feats:
        xn = (x - w.input_mean[None, :, None]) / w.input_scale[None, :, None]
        out.append(forward(w.params, xn)[0])
    return out


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", default="out/scenes")
    ap.add_argument("--extra", type=int, default=None, help="extra training scenes (default 240; --quick: 4)")
    ap.add_argument("--n-validation", type=int, default=None,
                    help="validation scenes (default 480; --quick: 8)")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--seeds", type=int, default=None,
                    help="initial seeds per variant (default 2; --quick: 1)")
    ap.add_argument("--maxiter", type=int, default=None,
                    help="L-BFGS-B iterations (default 300; --quick: 10)")
    ap.add_argument("--hidden", type=int, default=16)
    ap.add_argument("--negative-weight", type=float, default=30.0)
    ap.add_argument("--swap", action="store_true", help="choose on the second half, report on the first")
    ap.add_argument("--ensemble", action="store_true",
                    help="also report each seed's kept net and the mean y_slip of all seeds' kept nets")
    ap.add_argument("--json", default=None, help="write the table's figures here")
    ap.add_argument("--quick", action="store_true",
                    help="6 training scenes and few others, simulated here; short trainings (a smoke run)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    quick = args.quick
    for name, full, small in (("extra", 240, 4), ("n_validation", 480, 8), ("seeds", 2, 1),
                              ("maxiter", 300, 10)):
        if getattr(args, name) is None:
            setattr(args, name, small if quick else full)
    every = 5 if quick else 25
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

    from common import bank_training_set, bank_validation_conditions, study_scenes, write_json
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.lab.detector import build_options
    from tactile_mirror.lab.detector.thresholds import roc
    from tactile_mirror.lab.detector.training import TrainingSet, train_detector
    from tactile_mirror.lab.measure import cpu_model

    t0 = time.perf_counter()
    with open_workers(args) as executor:
        train, val = study_scenes(args.cache, args.extra, args.n_validation, executor=executor,
                                  **({"n_train": 6, "quick": True} if quick else {}))
    half = len(val) // 2
    sel_val, rep_val = val[:half], val[half:]
    chosen, reported = f"1-{half}", f"{half + 1}-{len(val)}"
    if args.swap:
        sel_val, rep_val, chosen, reported = rep_val, sel_val, reported, chosen
    print(f"# CPU: {cpu_model()}; {len(train)} training scenes; validation seed {build_options.VALIDATION_SEED}: "
          f"scenes {chosen} choose, {reported} report")

    ts = bank_training_set(train)
    print(f"# {ts.n_seq} training sequences, {int(ts.mask.sum())} samples", flush=True)

    bundled = SlipDetector.default()
    est = bundled.metadata.get("estimator")
    conds = {part: bank_validation_conditions(res, est) for part, res in (("select", sel_val), ("report", rep_val))}
    kinds = conds["report"]["noise-free"][2]
    print(f"# report half: {kinds.count('release')} release, {kinds.count('gradual')} gradual onsets", flush=True)

    def curves(part, scores_of):
        return {name: roc(scores_of(feats), rr, kinds) for name, (feats, rr, kinds) in conds[part].items()}

    def cell(c, fa):
        q = c.at_false_alarm(fa)
        return f"{100 * q['detection_rate']:.1f} ({100 * q['detection_gradual']:.1f})"

    def bundled_scores(feats):
        return [bundled.run(x[:, :4], fs=1000.0)[0] for x in feats]

    rows = [("bundled net", curves("report", bundled_scores), "-")]
    for variant in args.variants:
        f = compression(variant, ts.x, ts.mask)
        tsv = TrainingSet(f(ts.x) * ts.mask[:, None, :], ts.y_slip, ts.y_pred, ts.mask, ts.fs, ts.features,
                          ts.estimator, ts.targets, ts.load_tau, ts.bank)
        best = (-1.0, None, "")
        per_seed = []
        t1 = time.perf_counter()
        for seed in range(args.seeds):
            seed_best = (-1.0, None, "")
            cands = []
            w_end = train_detector(tsv, args.hidden, seed=seed, maxiter=args.maxiter, negative_weight=args.negative_weight,
                                   pred_weight=4.0,
                                   normalisation="median" if variant.endswith("median scale") else "rms", features="stress_rate_bank", progress=False,
                                   callback=lambda it, w: cands.append((it, w)), callback_every=every)
            cands.append((w_end.metadata["training"]["iterations"], w_end))
            for it, w in cands:
                c = curves("select", lambda feats: run_net(w, [f(x) for x in feats]))
                score = np.mean([c[n].at_false_alarm(0.02)["detection_rate"] for n in c])
                if score > best[0]:
                    best = (score, w, f"seed {seed}, {it} it")
                if score > seed_best[0]:
                    seed_best = (score, w, f"seed {seed}, {it} it")
            per_seed.append(seed_best)
        print(f"# {variant}: kept {best[2]} (selection score {100 * best[0]:.1f} %), "
              f"{time.perf_counter() - t1:.0f} s", flush=True)
        w = best[1]
        rows.append((f"net, {variant} inputs", curves("report", lambda feats: run_net(w, [f(x) for x in feats])),
                     best[2]))
        if args.ensemble:
            # Each seed's own kept net, then their mean y_slip: the spread between seeds'
            # minima against what averaging them buys.
            for score, ws, kept in per_seed:
                rows.append((f"net, {variant} inputs, one seed", curves("report", lambda feats, ws=ws: run_net(
                    ws, [f(x) for x in feats])), kept))
            members = [ws for _, ws, _ in per_seed]

            def mean_scores(feats, members=members):
                outs = [run_net(ws, [f(x) for x in feats]) for ws in members]
                return [np.mean([o[i] for o in outs], axis=0) for i in range(len(feats))]

            rows.append((f"mean of {len(members)} seeds' nets, {variant} inputs", curves("report", mean_scores),
                         ", ".join(k for _, _, k in per_seed)))

    print(f"\n| validation scenes {reported}, detection at 1 / 2 / 3 % false alarms, all (gradual) "
          f"| kept | noise-free | 1 mV rms |")
    print("|---|---|---|---|")
    table = {}
    for name, c, kept in rows:
        cells = [" / ".join(cell(c[cond], fa) for fa in (0.01, 0.02, 0.03)) for cond in ("noise-free", "1 mV rms")]
        print(f"| {name} | {kept} | " + " | ".join(cells) + " |")
        table[name] = {cond: {f"{fa:g}": c[cond].at_false_alarm(fa) for fa in (0.01, 0.02, 0.03)} for cond in c}
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    if args.json:
        write_json(args.json, json.loads(json.dumps(table, default=float)))
    return rows[0][1]["noise-free"].at_false_alarm(0.02)["detection_rate"]


if __name__ == "__main__":
    main()
