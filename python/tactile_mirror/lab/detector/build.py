"""Building the bundled detector: simulate scenes, study the hidden size, train, evaluate.

Command line (writes the weights, a report and Figure 10)::

    tactile-mirror train --out weights.npz [--study 8 16] [--report report.txt] [--figure fig10.png]

The bundled ``data/paper_detector.npz`` (the paper's net) was made with the defaults of
:class:`~tactile_mirror.lab.detector.build_options.BuildOptions` (64 training scenes, two
noise copies of each at 0-5 mV, gain augmentation 0.6-1.7, H = 16,
:data:`~tactile_mirror.lab.detector.build_options.TRAIN_OPTIONS`, 4 initial seeds with
checkpoints every 25 iterations, the best on 120 validation scenes kept, evaluated on 200
held-out scenes; about 8 min on 2 cores); its metadata records the scenes, the training
settings, the selection and the held-out evaluation.

The build's parts: the scene sets (:mod:`~tactile_mirror.lab.detector.scene_cache`), the
options and seeds (:mod:`~tactile_mirror.lab.detector.build_options`), the choice among
candidates (:mod:`~tactile_mirror.lab.detector.selection`), the hidden-size study
(:mod:`~tactile_mirror.lab.detector.size_study`) and the decision point's calibration
(:mod:`~tactile_mirror.lab.detector.calibration`).

On workers: ``build_default(..., executor=client.get_executor())`` (dask) or ``workers=N``
(``tactile-mirror train --scheduler ADDRESS`` / ``--workers N``) spreads the scene
simulation, the training runs (one task per seed and hidden size), the scoring of their
checkpoints and the calibration's runs of the net through
:func:`tactile_mirror.engine.run_tasks`; the chosen net is bit-identical to the serial
build's (docs/cluster.md).
"""
from __future__ import annotations

import json
import time

import numpy as np

from tactile_mirror.detector.core import SlipDetector
from tactile_mirror.engine import pinned_threads
from tactile_mirror.files import write_text
from tactile_mirror.lab.detector.augment import augment_gains, augment_noise, compress_training_set
from tactile_mirror.lab.detector.build_options import (
    EXTRA_TRAIN_SEED,
    TEST_SEED,
    TRAIN_SEED,
    VALIDATION_SEED,
    BuildOptions,
)
from tactile_mirror.lab.detector.calibration import calibrate_slip
from tactile_mirror.lab.detector.evaluation import ForceRatioDetector, evaluate
from tactile_mirror.lab.detector.scene_cache import simulate_cached, simulate_scenes
from tactile_mirror.lab.detector.selection import ValidationScorer, spread_executor, train_selected
from tactile_mirror.lab.detector.size_study import hidden_size_study, subset
from tactile_mirror.lab.detector.training import make_training_set
from tactile_mirror.lab.figure_files import save_figure

__all__ = ["build_default"]


def build_default(out_path, options: BuildOptions | None = None, *, report_path=None, figure_path=None,
                  results=None, cache_dir=None, executor=None, workers: int | None = None):
    """Simulate, train and evaluate the default detector; save its weights.

    Parameters
    ----------
    out_path : path
        Where the weights go.
    options : BuildOptions, optional
        How to build (default ``BuildOptions()``, the bundled detector's settings).
    report_path, figure_path : path, optional
        Text report (evaluation table, study) and Figure 10 image.
    results : (list, list) or (list, list, list), optional
        Already simulated (training, held-out[, validation]) results of exactly these scenes.
    cache_dir : path, optional
        Keep the simulated scene sets there between builds
        (:func:`~tactile_mirror.lab.detector.scene_cache.simulate_cached`).
    executor : concurrent.futures.Executor, optional
        Where the build's tasks run (a process pool, dask's ``Client.get_executor()``, ...):
        the scene simulation, the training runs (one task per seed and hidden size), the
        scoring of their checkpoints, the calibration's runs of the net
        (:func:`tactile_mirror.engine.run_tasks`). The weights are bit-identical to the serial
        build's; the report's ``*_seconds`` are not.
    workers : int, optional
        Instead of ``executor``: one pool of that many local processes for the whole build.
        Neither: the scenes on a pool of this machine's cores (as
        :func:`~tactile_mirror.lab.detector.scene_cache.simulate_cached` does by default), the
        rest in this process.

    Returns
    -------
    weights : DetectorWeights
    report : dict
    """
    if options is None:
        options = BuildOptions()
    elif not isinstance(options, BuildOptions):
        raise TypeError(f"options must be a BuildOptions, got {type(options).__name__}")
    extra = {} if cache_dir is None else {"cache_dir": cache_dir}
    # the driver's own numerics (training sets, scorers, evaluation) on one thread too, as the tasks'
    with pinned_threads(1), spread_executor(executor, workers) as ex:
        if ex is not None:
            extra["executor"] = ex
        return _build(out_path, options, report_path, figure_path, results, **extra)


def _build(out_path, options: BuildOptions, report_path, figure_path, results, cache_dir=None, executor=None):
    o = options
    n_train, n_test, n_hidden, maxiter = o.n_train, o.n_test, o.n_hidden, o.maxiter
    ridges_per_scene, seed, study_sizes, progress = o.ridges_per_scene, o.seed, o.study_sizes, o.progress
    gain_range, noise_copies, noise_range = o.gain_range, o.noise_copies, o.noise_range
    n_validation, candidates, checkpoint_every = o.n_validation, o.candidates, o.checkpoint_every
    selecting = o.selecting
    t_all = time.perf_counter()
    # never None after BuildOptions.__post_init__
    train_kwargs, test_kwargs = dict(o.train_kwargs or {}), dict(o.test_kwargs or {})
    opts = dict(o.train_options or {})
    spread = {} if executor is None else {"executor": executor}
    t0 = time.perf_counter()
    results = list(results) if results is not None else []
    train_res = list(results[0]) if len(results) > 0 else simulate_cached(
        n_train, TRAIN_SEED, train_kwargs, cache_dir, progress, **spread)
    test_res = list(results[1]) if len(results) > 1 else simulate_cached(
        n_test, TEST_SEED, test_kwargs, cache_dir, progress, **spread)
    val_res = []
    if selecting:
        val_res = list(results[2]) if len(results) > 2 else simulate_cached(
            n_validation, VALIDATION_SEED, test_kwargs, cache_dir, progress, **spread)
    if o.n_extra_train:
        train_res = train_res + simulate_cached(o.n_extra_train, EXTRA_TRAIN_SEED, test_kwargs, cache_dir, progress,
                                                **spread)
    t_sim = time.perf_counter() - t0
    n_ridges = np.asarray(train_res[0].v_out).shape[0]
    seqs = augment_noise(train_res, noise_copies, noise_range, seed=2) if noise_copies else train_res
    memory = o.kind == "jordan_memory"
    features = {"jordan": "stress_rate", "jordan_memory": "stress_rate_memory",
                "jordan_bank": "stress_rate_bank"}[o.kind]
    ts = subset(make_training_set(seqs, features, load_tau=o.load_tau if memory else None,
                                  bank=o.bank if o.kind == "jordan_bank" else None),
                ridges_per_scene, n_ridges)
    if gain_range is not None:
        ts = augment_gains(ts, gain_range, seed=1)
    if o.compress:
        ts = compress_training_set(ts)
    report = {"n_train_scenes": n_train, "n_test_scenes": n_test, "train_seed": TRAIN_SEED,
              "test_seed": TEST_SEED, "simulation_seconds": round(t_sim, 1), "n_sequences": ts.n_seq,
              "train_kwargs": train_kwargs, "test_kwargs": test_kwargs, "train_options": opts,
              "gain_range": None if gain_range is None else list(gain_range),
              "noise_copies": int(noise_copies), "noise_range": list(noise_range)}
    # A net calibrated afterwards is chosen by how far its curve reaches at the false-alarm
    # rate it will be calibrated to, not by what its uncalibrated threshold gives.
    select_fa = o.calibrate_fa if o.calibrate_conditions is None else min(o.calibrate_conditions.values())
    if o.select_fa is not None:
        select_fa = o.select_fa
    scorer = ValidationScorer(val_res, at_false_alarm=select_fa, conditions=o.select_conditions) if selecting \
        else None
    if study_sizes:
        if scorer is None:
            raise ValueError("study_sizes needs validation scenes: candidates > 1 or checkpoint_every > 0")
        report["hidden_size_study"] = hidden_size_study(ts, scorer, study_sizes, maxiter, seed, candidates,
                                                        checkpoint_every, progress, executor=executor, **opts)
    meta = {"scenes": f"scenes.random({n_train}, seed={TRAIN_SEED}, **{train_kwargs})",
            "ridges_per_scene": ridges_per_scene, "kind": o.kind}
    if o.n_extra_train:
        meta["extra_scenes"] = f"scenes.random({o.n_extra_train}, seed={EXTRA_TRAIN_SEED}, **{test_kwargs})"

    def train(feedback):
        return train_selected(ts, n_hidden, maxiter, seed, candidates, checkpoint_every, scorer, feedback,
                              progress, meta, executor=executor, **opts)

    t0 = time.perf_counter()
    w, k_best, scores = train(True)
    report["train_seconds"] = round(time.perf_counter() - t0, 1)
    if scores:
        tr_meta = w.metadata["training"]
        report["candidates"] = {
            "validation": f"scenes.random({n_validation}, seed={VALIDATION_SEED}, **{test_kwargs})",
            "n_candidates": len(scores), "checkpoint_every": int(checkpoint_every),
            "chosen_seed": int(tr_meta["seed"]), "chosen_iteration": int(tr_meta["iterations"]),
            "chosen_score": scores[k_best]}
        if o.select_conditions is not None:
            report["candidates"].update(conditions=list(o.select_conditions), at_false_alarm=select_fa)
        tr_meta["selection"] = dict(report["candidates"], seeds=int(candidates), fa_cost=10.0)
    if o.calibrate_fa is not None or o.calibrate_conditions is not None:
        w, report["slip_calibration"] = calibrate_slip(
            w, val_res, o.calibrate_fa, conditions=o.calibrate_conditions, executor=executor,
            scenes=f"scenes.random({n_validation}, seed={VALIDATION_SEED}, **{test_kwargs})")
    force = ForceRatioDetector.fit(train_res)
    det = SlipDetector(w)
    if o.kind != "jordan":
        # The baseline of the load-memory and filter-bank nets is the paper's net, on the same scenes.
        second = ("paper Jordan net", "paper", SlipDetector.paper())
    else:
        w_nf, _, _ = train(False)
        second = ("MLP without feedback", "no_feedback", SlipDetector(w_nf))
    rep = evaluate(det, test_res, {second[0]: second[2], "force ratio |Fy|/Fz": force})
    report["evaluation"] = [r.as_dict() for r in rep.rows]
    report["evaluation_table"] = rep.table()
    report["force_ratio_threshold"] = force.threshold
    w.metadata["evaluation"] = {"scenes": f"scenes.random({n_test}, seed={TEST_SEED}, **{test_kwargs})",
                                "detector": rep["detector"].as_dict(),
                                second[1]: rep[second[0]].as_dict(),
                                "force_ratio": rep["force ratio |Fy|/Fz"].as_dict()}
    w.save(out_path)
    report["total_seconds"] = round(time.perf_counter() - t_all, 1)
    if report_path is not None:
        write_text(report_path, rep.table() + "\n\n" + json.dumps(report, indent=1, default=float) + "\n")
    if figure_path is not None:
        from tactile_mirror import scenes
        from tactile_mirror.lab.detector.figures import figure10

        ra = simulate_scenes([scenes.paper("fig6")], False)[0]
        rb = simulate_scenes([scenes.paper("fig8")], False)[0]
        fig = figure10(det, ra, rb, stops_b=[(1.40, 1.45)])
        save_figure(fig, figure_path, dpi=120)
    return w, report
