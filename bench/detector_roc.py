"""Detection against false alarms as curves: a threshold sweep per noise condition.

For each detector the statistic it thresholds is swept (``y_slip`` of the nets, the
bound classifier's probability, the force ratio ``|F_y| / F_z``) and every
threshold gives one point (false-alarm rate, detection rate) with
:func:`tactile_mirror.lab.detector.evaluation.roc`, whose definitions of detection, false
alarm and onset kind are those of ``detector.evaluate``. Three noise conditions,
added to the circuit outputs of the same simulated scenes (the contact simulation
runs once; noise is added to ``v_out``/``u_out`` afterwards):

* noise-free;
* 1 mV rms white noise on ``v_out`` and ``u_out`` (independent per strip);
* the circuit's thermal floor (:class:`tactile_mirror.noise.SensorNoise`: feedback
  resistors, op-amp voltage and current noise) plus 2 mV rms of 50 Hz mains hum with
  harmonics, with the stress-rate estimator's 50 Hz notch switched on for every
  detector that reads the estimator.

Detectors: the filter-bank net (``SlipDetector.bank()``, or ``--bank-weights``: the Jordan
kernel on the stress rates plus a bank of IIR filters over them,
:mod:`tactile_mirror.detector.bank`); the early net (``SlipDetector.early()``: the same net trained
to find a slip soon after it starts); the load-memory net (``SlipDetector.memory()``, or ``--memory-weights``:
the Jordan kernel on the stress rates plus the ridge's load integrals and the pad's
shear rate and load, :mod:`tactile_mirror.detector.memory`); the paper's Jordan net
(``SlipDetector.paper()``); the no-feedback MLP,
trained here as the build trains it (same options and augmentation, one initial
seed, no checkpoint selection: the bundled weights ship without it); the bound
study's classifier (``bench/detector_bound.py``: boosted trees on 256 ms of lagged
signals and their integrals, 3 samples in a row), trained per noise condition on the
training scenes with that condition's noise; the force ratio (noise-free: a force
sensor is not this circuit, so its curve is the same in every panel).

Scenes: held-out scenes drawn with the build's held-out ranges (``build_options.TEST_KWARGS``)
from seed :data:`ROC_SEED`, disjoint from the build's training (``TRAIN_SEED``),
validation (``VALIDATION_SEED``), held-out (``TEST_SEED``) and the bound study's
extra training seed (99); training scenes of the MLP and the classifier from the
build's training seed, and for the classifier also ``--bound-extra`` scenes from the
held-out ranges with seed 99, as the bound study trains it. Simulated scenes are cached (``--cache``, under ``out/``,
which git ignores).

Run: ``python bench/detector_roc.py [--scenes 80] [--train-scenes 40]`` (needs
scikit-learn for the bound classifier). Writes ``docs/figures/detector_roc.png``
and a markdown and a JSON table (``--out``). The default 80 held-out scenes resolve
false alarms in steps of 1.25 %; the figure in ``docs/figures`` was made with
``--scenes 200`` (steps of 0.5 %; about 8 min of simulation on 2 cores, then 2 min). ``--quick``: 8
held-out, 6 training and 4 extra scenes simulated here (not cached), a 10-iteration MLP and 20 boosting
iterations, a smoke run of a few seconds. ``main`` returns the filter-bank net's detection rate at 2 %
false alarms, noise-free.
"""
from __future__ import annotations

import argparse
import os
import pickle
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from tactile_mirror import scenes
from tactile_mirror.cli.arguments import add_workers_options, open_workers
from tactile_mirror.lab.detector.evaluation import NOISE_CONDITIONS, condition_estimator, with_noise

#: Seed of the held-out scenes of this study (disjoint from every seed the build uses).
ROC_SEED = 5150
BOUND_EXTRA_SEED = 99


def scene_kwargs() -> tuple[dict, dict]:
    """The ``scenes.random`` options of the held-out and the training scenes: the build's, noise-free."""
    from tactile_mirror.lab.detector import build_options

    clean = {"noise": (0.0, 0.0)}
    return {**build_options.TEST_KWARGS, **clean}, {**build_options.TRAIN_KWARGS, **clean}


def scene_sets(n_test: int, n_train: int):
    from tactile_mirror.lab.detector import build_options

    test_kwargs, train_kwargs = scene_kwargs()
    test = scenes.random(n_test, seed=ROC_SEED, **test_kwargs)
    train = scenes.random(n_train, seed=build_options.TRAIN_SEED, **train_kwargs)
    return test, train


def simulated(n_test: int, n_train: int, cache: str | None, quick: bool = False, executor=None):
    """(held-out results, training results), from ``cache`` when it holds these scenes, else
    simulated (on ``executor`` if given; ``quick``: in this process, not cached)."""
    from common import quick_results, write_pickle
    from tactile_mirror.lab.detector import build_options, scene_cache

    if quick:
        test_kwargs, train_kwargs = scene_kwargs()
        return (quick_results(n_test, ROC_SEED, test_kwargs),
                quick_results(n_train, build_options.TRAIN_SEED, train_kwargs))

    key = {"n_test": n_test, "n_train": n_train, "roc_seed": ROC_SEED, "train_seed": build_options.TRAIN_SEED,
           "test_kwargs": repr(sorted(build_options.TEST_KWARGS.items())),
           "train_kwargs": repr(sorted(build_options.TRAIN_KWARGS.items()))}
    if cache and os.path.exists(cache):
        with open(cache, "rb") as fh:
            data = pickle.load(fh)
        if data.get("key") == key:
            return data["test"], data["train"]
    test_sc, train_sc = scene_sets(n_test, n_train)
    t0 = time.perf_counter()
    res = scene_cache.simulate_scenes(test_sc + train_sc, progress=True, **({} if executor is None else
                                                                             {"executor": executor}))
    print(f"simulated {len(res)} scenes in {time.perf_counter() - t0:.0f} s", flush=True)
    test, train = res[:n_test], res[n_test:]
    if cache:
        os.makedirs(os.path.dirname(os.path.abspath(cache)), exist_ok=True)
        write_pickle(cache, {"key": key, "test": test, "train": train})
    return test, train


FA_POINTS = (0.02, 0.03)


def net_scores(detector, results, condition: str) -> list:
    from tactile_mirror.detector.data_prep import features_from_result

    est = condition_estimator(detector, condition)
    return [detector.run(features_from_result(r, detector.features, estimator=est), fs=r.fs)[0] for r in results]


def train_mlp(train, progress: bool, maxiter: int | None = None):
    """The no-feedback MLP, trained as the build trains it (one seed, no checkpoint selection;
    ``maxiter`` default :data:`MLP_MAXITER`)."""
    from tactile_mirror.lab.detector import build_options
    from tactile_mirror.lab.detector.augment import augment_gains, augment_noise
    from tactile_mirror.lab.detector.training import make_training_set, train_detector

    seqs = augment_noise(train, build_options.NOISE_COPIES, build_options.NOISE_RANGE, seed=2)
    ts = augment_gains(make_training_set(seqs), (0.6, 1.7), seed=1)
    from tactile_mirror.detector import SlipDetector

    w = train_detector(ts, n_hidden=16, maxiter=maxiter or MLP_MAXITER, seed=0, feedback=False,
                       progress=progress, **build_options.TRAIN_OPTIONS)
    return SlipDetector(w)


#: L-BFGS-B iterations of the no-feedback MLP (the build's checkpoints kept near 100-200).
MLP_MAXITER = 200


def bound_features(results, condition: str):
    """The bound study's 45 window features per sample (ridge 0), from the condition's signals."""
    from types import SimpleNamespace

    from detector_bound import window_features
    from tactile_mirror.detector.data_prep import features_from_result

    est = condition_estimator(None, condition)
    out = []
    for r in results:
        x = features_from_result(r, "stress_rate", estimator=est)
        out.append(window_features(SimpleNamespace(features=x, fs=r.fs), True))
    return out


def bound_scores(train, test, condition: str, trees: int | None = None) -> list:
    """Probabilities of the bound study's classifier, trained on ``train`` with the condition's noise
    (``trees``: boosting iterations, default the bound study's)."""
    from common import BOUND_TREES, fit_bound_classifier
    from tactile_mirror.detector.data_prep import targets_from_result

    X = np.vstack([f[::2] for f in bound_features(train, condition)])
    Y = np.concatenate([targets_from_result(r)[0][0][::2] for r in train])
    clf = fit_bound_classifier(X, Y, max_iter=trees or BOUND_TREES)
    return [clf.predict_proba(f)[:, 1] for f in bound_features(test, condition)]


def pct(x) -> str:
    return "-" if not np.isfinite(x) else f"{100 * x:.1f}"


def bound_extra(n: int, cache: str | None, quick: bool = False, executor=None):
    """Extra training scenes of the bound classifier, as the bound study draws them: the held-out
    ranges, seed :data:`BOUND_EXTRA_SEED` (cached in ``cache`` with ``.extra`` before its extension;
    simulated on ``executor`` if given; ``quick``: in this process, not cached)."""
    from common import quick_results, write_pickle
    from tactile_mirror.lab.detector import build_options, scene_cache

    if n <= 0:
        return []
    kwargs = {**build_options.TEST_KWARGS, "noise": (0.0, 0.0)}
    if quick:
        return quick_results(n, BOUND_EXTRA_SEED, kwargs)
    key = {"n": n, "seed": BOUND_EXTRA_SEED, "test_kwargs": repr(sorted(build_options.TEST_KWARGS.items()))}
    path = None
    if cache:
        root, ext = os.path.splitext(cache)
        path = root + ".extra" + ext
        if os.path.exists(path):
            with open(path, "rb") as fh:
                data = pickle.load(fh)
            if data.get("key") == key:
                return data["results"]
    t0 = time.perf_counter()
    res = scene_cache.simulate_scenes(scenes.random(n, seed=BOUND_EXTRA_SEED, **kwargs), progress=True,
                                      **({} if executor is None else {"executor": executor}))
    print(f"simulated {len(res)} extra training scenes in {time.perf_counter() - t0:.0f} s", flush=True)
    if path:
        write_pickle(path, {"key": key, "results": res})
    return res


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=None, help="held-out scenes (default 80; --quick: 8)")
    ap.add_argument("--train-scenes", type=int, default=None,
                    help="training scenes of the MLP and classifier (default 40; --quick: 6)")
    ap.add_argument("--bound-extra", type=int, default=None,
                    help="extra training scenes of the bound classifier from the held-out ranges (seed 99; "
                         "default 80, --quick: 4)")
    ap.add_argument("--cache", default="out/detector_roc_scenes.pkl",
                    help="simulated-scene cache ('' for none)")
    ap.add_argument("--simulate-only", action="store_true", help="simulate (and cache) the scenes, then stop")
    ap.add_argument("--figure", default="docs/figures/detector_roc.png", help="figure to write")
    ap.add_argument("--out", default="out/detector_roc", help="table path without extension (.md and .json)")
    ap.add_argument("--memory-weights", default=None,
                    help="load-memory net weights (default: the bundled ones)")
    ap.add_argument("--bank-weights", default=None,
                    help="filter-bank net weights (default: the bundled ones)")
    ap.add_argument("--quick", action="store_true",
                    help="a few scenes simulated here (not cached), short trainings (a smoke run, not the "
                         "figures)")
    add_workers_options(ap)
    args = ap.parse_args(argv)
    quick = args.quick
    for name, full, small in (("scenes", 80, 8), ("train_scenes", 40, 6), ("bound_extra", 80, 4)):
        if getattr(args, name) is None:
            setattr(args, name, small if quick else full)
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    with open_workers(args) as executor:
        test, train = simulated(args.scenes, args.train_scenes, args.cache or None, quick, executor)
        extra = bound_extra(args.bound_extra, args.cache or None, quick, executor)
    if args.simulate_only:
        return float("nan")
    from common import QUICK_TREES, header, save_figure, write_json, write_text
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.lab.detector.evaluation import ForceRatioDetector, onset_kinds
    from tactile_mirror.lab.detector.thresholds import roc
    from tactile_mirror.lab.measure import environment, markdown_table

    header("slip detection against false alarms, threshold sweeps per noise condition")
    t0 = time.perf_counter()
    kinds = onset_kinds(test)
    print(f"held-out: {len(test)} scenes (seed {ROC_SEED}), {kinds.count('release')} release and "
          f"{kinds.count('gradual')} gradual onsets, {kinds.count(None)} sequences without gross slip; "
          f"training: {len(train)} scenes (+ {len(extra)} for the bound classifier)", flush=True)
    jordan = SlipDetector.paper()
    memory = SlipDetector.load(args.memory_weights) if args.memory_weights else SlipDetector.memory()
    bank = SlipDetector.load(args.bank_weights) if args.bank_weights else SlipDetector.bank()
    early = SlipDetector.early()
    mlp = train_mlp(train, progress=False, maxiter=10 if quick else None)
    print(f"no-feedback MLP trained in {time.perf_counter() - t0:.0f} s", flush=True)
    force = ForceRatioDetector(1.0)
    force_scores = [force.ratio(r) for r in test]
    curves = {}
    for ci, cond in enumerate(NOISE_CONDITIONS):
        noisy_test = with_noise(test, cond, seed=1000 + ci)
        noisy_train = with_noise(train + extra, cond, seed=2000 + ci)
        curves[cond] = {
            "filter-bank net, y_slip": roc(net_scores(bank, noisy_test, cond), test, kinds, name="filter-bank net"),
            "early net, y_slip": roc(net_scores(early, noisy_test, cond), test, kinds, name="early net"),
            "load-memory net, y_slip": roc(net_scores(memory, noisy_test, cond), test, kinds,
                                           name="load-memory net"),
            "paper Jordan net, y_slip": roc(net_scores(jordan, noisy_test, cond), test, kinds,
                                            name="paper Jordan net"),
            "MLP without feedback, y_slip": roc(net_scores(mlp, noisy_test, cond), test, kinds,
                                                name="MLP without feedback"),
            "bound classifier, p (3 in a row)": roc(bound_scores(noisy_train, noisy_test, cond,
                                                                 trees=QUICK_TREES if quick else None),
                                                    test, kinds, consecutive=3, name="bound classifier"),
            "force ratio |Fy|/Fz (noise-free)": roc(force_scores, test, kinds, name="force ratio"),
        }
        print(f"{cond}: done at {time.perf_counter() - t0:.0f} s", flush=True)

    rows = []
    for cond, cs in curves.items():
        for name, c in cs.items():
            row = [cond, name]
            for fa in FA_POINTS:
                p = c.at_false_alarm(fa)
                row += [pct(p["detection_rate"]), pct(p["detection_release"]), pct(p["detection_gradual"]),
                        pct(p["false_alarm_rate"]), f"{p['threshold']:.6g}"]
            if "y_slip" in name:
                p = c.at_threshold(0.8)
                row += [f"{pct(p['detection_rate'])} / {pct(p['false_alarm_rate'])}"]
            else:
                row += ["-"]
            rows.append(row)
    head = ["noise", "detector"]
    for fa in FA_POINTS:
        f = f"{100 * fa:.0f} %"
        head += [f"det @{f} FA", "release", "gradual", "FA", "threshold"]
    head += ["det / FA at y_slip 0.8"]
    env = environment()
    c0 = next(iter(next(iter(curves.values())).values()))
    md = (f"# Slip detection against false alarms\n\n{len(test)} held-out scenes (seed {ROC_SEED}, build_options.TEST_KWARGS "
          f"ranges), {c0.n_sequences} sequences, {c0.n_slip} slips: {c0.n_by_kind.get('release', 0)} release, "
          f"{c0.n_by_kind.get('gradual', 0)} gradual onsets. Detection in %, at the lowest threshold whose "
          f"false-alarm rate is at most 2 % and 3 %.\n\nCPU: {env.get('cpu_model', '?')}\n"
          + markdown_table(None, head, rows) + "\n")
    print(md)
    out = args.out
    write_text(out + ".md", md)
    write_json(out + ".json", {"settings": {"n_scenes": len(test), "n_train_scenes": len(train), "roc_seed": ROC_SEED,
                                            "conditions": {k: list(map(str, v)) for k, v in NOISE_CONDITIONS.items()},
                                            "mlp_maxiter": MLP_MAXITER, "environment": env},
                               "curves": {cond: {n: c.as_dict() for n, c in cs.items()}
                                          for cond, cs in curves.items()}})
    save_figure(figure(curves, len(test)), args.figure, dpi=110)
    print(f"wrote {args.figure}, {out}.md, {out}.json in {time.perf_counter() - t0:.0f} s")
    return curves["noise-free"]["filter-bank net, y_slip"].at_false_alarm(0.02)["detection_rate"]


def gradual_latency(c) -> np.ndarray:
    """Mean latency (ms) of the gradual onsets a curve finds, at each of its points (NaN where none)."""
    gradual = np.array([k == "gradual" for k in c.slip_kinds], dtype=bool)
    out = np.full(c.thresholds.size, np.nan)
    if not gradual.any():
        return out
    for j, t in enumerate(c.thresholds):
        lat = c.latencies(t)[gradual]
        if np.isfinite(lat).any():
            out[j] = 1e3 * np.nanmean(lat)
    return out


def figure(curves, n_scenes):
    import matplotlib.pyplot as plt

    colors = ["C5", "C6", "C4", "C0", "C1", "C2", "C3"]
    fig, axes = plt.subplots(2, len(curves), figsize=(5.2 * len(curves), 8.6), sharex=True,
                             gridspec_kw={"height_ratios": [3, 2]})
    axes = np.asarray(axes).reshape(2, len(curves))
    for k, (cond, cs) in enumerate(curves.items()):
        ax, lax = axes[0, k], axes[1, k]
        for col, (name, c) in zip(colors, cs.items()):
            fa = 100 * np.concatenate([[0.0], c.false_alarm_rate, [1.0]])
            ax.plot(fa, 100 * np.concatenate([[0.0], c.detection_rate, [1.0]]), color=col,
                    drawstyle="steps-post", label=f"{name}: all slips")
            if "gradual" in c.detection_by_kind:
                ax.plot(fa, 100 * np.concatenate([[0.0], c.detection_by_kind["gradual"], [1.0]]), color=col,
                        ls="--", lw=1, drawstyle="steps-post", label="  gradual onsets")
                # (a mean over a few of the gradual onsets says little: drawn where a quarter are found)
                lat = np.where(c.detection_by_kind["gradual"] >= 0.25, gradual_latency(c), np.nan)
                if np.isfinite(lat).sum() > 1 and "force ratio" not in name:
                    lax.plot(100 * c.false_alarm_rate, lat, color=col, drawstyle="steps-post", lw=1.2)
        for a in (ax, lax):
            for x in FA_POINTS:
                a.axvline(100 * x, color="0.6", lw=0.7, ls=":")
            a.set_xlim(0, 20)
            a.grid(alpha=0.3)
        lax.axhline(15.0, color="0.3", lw=0.8, ls="--")
        handles, labels = ax.get_legend_handles_labels()
        ax.set_ylim(0, 101)
        lax.set_ylim(0, 50)
        lax.set_xlabel("false alarms, % of sequences")
        ax.set_title(cond)
    axes[0, 0].set_ylabel("slips detected within 50 ms, %")
    axes[1, 0].set_ylabel("gradual onsets: mean latency, ms\n(where >= 25 % are found; dashed: 15 ms goal)")
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f"Threshold sweeps on {n_scenes} held-out scenes (top, solid: all slips, dashed: gradual onsets; "
                 f"bottom: how soon the gradual onsets are found; dotted: 2 % and 3 % false alarms)")
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    return fig


if __name__ == "__main__":
    main()
