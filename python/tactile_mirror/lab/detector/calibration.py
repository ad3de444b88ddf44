"""The decision point of a trained detector: calibrated to a false-alarm rate on validation scenes.

``y_slip`` is not fed back, so a shift of its output bias thresholds the same net at
another level, exactly (:func:`bias_shift`). :func:`calibrate_slip` finds the shift that
keeps the validation scenes within a false-alarm rate (in their own noise or in named
sensor conditions), :func:`uncalibrate` undoes a recorded one, and :func:`recalibrate`
calibrates a saved net anew and refreshes its held-out evaluation.

The detector's runs over the validation scenes (one task per sensor condition and block of
scenes) and the scene sets spread over workers with ``executor=`` / ``workers=``
(:func:`tactile_mirror.engine.run_tasks`), with the same result wherever they ran.
"""
from __future__ import annotations

import functools

from tactile_mirror.detector.core import SlipDetector
from tactile_mirror.engine import pinned_threads, run_tasks
from tactile_mirror.lab.detector.build_options import TEST_KWARGS, TEST_SEED, VALIDATION_SEED
from tactile_mirror.lab.detector.evaluation import evaluate
from tactile_mirror.lab.detector.scene_cache import simulate_cached
from tactile_mirror.lab.detector.selection import (
    check_false_alarm_rate,
    condition_names,
    condition_results,
    spread_executor,
)

__all__ = ["bias_shift", "calibrate_slip", "recalibrate", "uncalibrate"]

#: Validation scenes per task of :func:`calibrate_slip`'s detector runs.
_BLOCK = 40


def bias_shift(threshold: float, slip_threshold: float = 0.8) -> float:
    """What to add to ``y_slip``'s output bias ``b2[0]`` so that the net's ``y_slip >=
    threshold`` becomes ``y_slip >= slip_threshold``, exactly (``y_slip`` is not fed back):
    ``logit(slip_threshold) - logit(threshold)``."""
    import math

    return math.log(slip_threshold / (1 - slip_threshold)) - math.log(threshold / (1 - threshold))


def _detector_scores(weights, block: tuple) -> list:
    """A task of :func:`calibrate_slip`: ``y_slip`` of the net ``weights`` over each result
    of ``block = (results, estimator)``, the features made with that estimator."""
    from tactile_mirror.detector.data_prep import features_from_result

    results, estimator = block
    det = SlipDetector(weights)
    return [det.run(features_from_result(r, det.features, estimator=estimator), fs=r.fs)[0] for r in results]


def calibrate_slip(weights, validation, false_alarm: float | None, slip_threshold: float = 0.8, scenes: str = "",
                   conditions=None, seed: int = 5000, *, executor=None, workers: int | None = None):
    """Weights whose ``y_slip >= slip_threshold`` alarms at most ``false_alarm`` of the
    validation sequences without slip in time.

    ``y_slip`` is not fed back (only ``y_pred`` is), so adding ``c`` to its output bias
    ``b2[0]`` thresholds the same net at another level, exactly: the lowest threshold
    ``t`` whose false-alarm rate on ``validation`` is at most ``false_alarm``
    (:func:`~tactile_mirror.lab.detector.evaluation.roc`, the evaluation's own definitions)
    becomes ``slip_threshold`` with ``c = logit(slip_threshold) - logit(t)``. Every
    consumer (the pipeline's status, the slip guard,
    :func:`~tactile_mirror.lab.detector.evaluation.evaluate`) keeps the one
    rule ``y_slip >= 0.8``. Choose ``validation`` disjoint from what is reported.

    ``conditions``: a mapping of sensor conditions (keys of
    :data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`) to false-alarm bounds. The
    validation scenes are then scored in each condition (their noise-free outputs plus the
    condition's noise, seeded by ``seed`` + the condition's index) instead of in their own
    noise, and ``t`` is the lowest threshold that keeps every condition within its bound
    (``false_alarm`` is not used; pass None). A bound somewhat below the rate a goal allows
    leaves room for the difference between two scene sets: the standard error of a rate
    near 2 % is 0.6 points on 480 sequences, 1 point on 200.

    ``executor`` (any :class:`concurrent.futures.Executor`) or ``workers`` (N local
    processes) run the net over the validation scenes as tasks (one per condition and block
    of 40 scenes; :func:`tactile_mirror.engine.run_tasks`); default here. The result is the
    same wherever they ran.

    Returns ``(weights, info)``; ``info`` (threshold found, bias shift, the validation's
    detection and false-alarm rates, per condition if given) is also stored in
    ``metadata["slip_calibration"]``.
    """
    import copy

    from tactile_mirror.lab.detector.evaluation import condition_estimator, onset_kinds
    from tactile_mirror.lab.detector.thresholds import roc

    if isinstance(slip_threshold, bool) or not (isinstance(slip_threshold, (int, float)) and 0 < slip_threshold < 1):
        raise ValueError(f"slip_threshold must be in (0, 1), got {slip_threshold!r}")
    if conditions is None:
        if false_alarm is None:
            raise ValueError("give false_alarm or conditions")
        # (NaN or -1 gave a detector that never alarms; 5, always)
        check_false_alarm_rate(false_alarm, "false_alarm")
    validation = list(validation)
    if not validation:
        raise ValueError("validation must hold at least one simulation result")
    det = SlipDetector(weights)
    kinds = onset_kinds(validation)
    if conditions is None:
        runs = {"own noise": (validation, det.metadata.get("estimator"), float(false_alarm))}
    else:
        conditions = dict(conditions)
        names = condition_names(conditions, "conditions")
        for name in names:
            check_false_alarm_rate(conditions[name], f"conditions[{name!r}]")
        copies = condition_results(validation, names, seed)
        runs = {name: (copies[name], condition_estimator(det, name), float(conditions[name])) for name in names}
    blocks = [(name, k) for name, (res, _, _) in runs.items() for k in range(0, len(res), _BLOCK)]
    outs = run_tasks(functools.partial(_detector_scores, weights),
                     [(runs[name][0][k:k + _BLOCK], runs[name][1]) for name, k in blocks],
                     executor=executor, workers=workers, progress=False, desc="calibrate")
    curves = {}
    t = 0.0
    for name, (res, est, fa) in runs.items():
        scores = [y for (block_name, _), out in zip(blocks, outs) if block_name == name for y in out]
        curves[name] = roc(scores, validation, kinds)
        if curves[name].n_slip == 0:
            raise ValueError("validation has no slipping sequence: its detection rate, which the calibration "
                             "reports, is undefined")
        t = max(t, float(curves[name].at_false_alarm(fa)["threshold"]))
    t = min(max(t, 1e-6), 1 - 1e-6)
    shift = bias_shift(t, slip_threshold)
    w = copy.deepcopy(weights)
    w.params.b2[0] += shift
    at = {name: c.at_threshold(t) for name, c in curves.items()}
    info = {"validation": scenes, "threshold": t, "b2_shift": shift}
    if conditions is None:
        info.update({"false_alarm": float(false_alarm),
                     "validation_detection": float(at["own noise"]["detection_rate"]),
                     "validation_false_alarm": float(at["own noise"]["false_alarm_rate"])})
    else:
        info["conditions"] = {name: {"false_alarm_bound": runs[name][2],
                                     "validation_detection": float(at[name]["detection_rate"]),
                                     "validation_false_alarm": float(at[name]["false_alarm_rate"])}
                              for name in runs}
        info["noise_seed"] = int(seed)
    w.metadata["slip_calibration"] = info
    return w, info


def uncalibrate(weights, slip_threshold: float = 0.8):
    """A copy of ``weights`` without the decision-point shift :func:`calibrate_slip` recorded
    in ``metadata["slip_calibration"]`` (the net as trained), to calibrate it anew. A record
    with only the ``threshold`` that was moved to ``slip_threshold`` (as
    ``bench/detector_pad_net.py --save`` writes it) is undone by the same shift."""
    import copy

    w = copy.deepcopy(weights)
    info = w.metadata.pop("slip_calibration", None)
    if info is not None:
        if "b2_shift" in info:
            shift = float(info["b2_shift"])
        elif "threshold" in info:
            t = float(info["threshold"])
            if not 0 < t < 1:
                raise ValueError(f"weights: slip_calibration threshold must lie in (0, 1), got {t!r}")
            shift = bias_shift(t, slip_threshold)
        else:
            raise ValueError("weights: slip_calibration records neither b2_shift nor threshold")
        w.params.b2[0] -= shift
    return w


def recalibrate(weights_path, out_path, conditions: dict, n_validation: int = 480, n_test: int = 200,
                cache_dir=None, progress: bool = True, *, executor=None, workers: int | None = None):
    """Calibrate a trained net's decision point anew and save it.

    The net in ``weights_path`` loses its recorded shift (:func:`uncalibrate`), is
    calibrated with :func:`calibrate_slip` for the sensor ``conditions`` (a mapping of
    condition names to false-alarm bounds) on ``n_validation`` validation scenes (seed
    :data:`~tactile_mirror.lab.detector.build_options.VALIDATION_SEED`), gets a fresh
    held-out evaluation record (``n_test`` scenes, seed
    :data:`~tactile_mirror.lab.detector.build_options.TEST_SEED`, as
    :func:`~tactile_mirror.lab.detector.build.build_default` writes it) and is saved to
    ``out_path``. The scene sets are kept in ``cache_dir`` if given
    (:func:`~tactile_mirror.lab.detector.scene_cache.simulate_cached`). ``executor`` or
    ``workers`` (one local process pool for the whole job) spread the scene simulation and
    the calibration's runs of the net (:func:`calibrate_slip`); neither: the scenes on a pool
    of this machine's cores, the rest here.

    Returns ``(weights, info)``: the calibrated weights and :func:`calibrate_slip`'s record.
    """
    from tactile_mirror.detector.weights import DetectorWeights

    w = uncalibrate(DetectorWeights.load(weights_path))
    with pinned_threads(1), spread_executor(executor, workers) as ex:
        spread = {} if ex is None else {"executor": ex}
        val = simulate_cached(n_validation, VALIDATION_SEED, TEST_KWARGS, cache_dir, progress, **spread)
        w, info = calibrate_slip(w, val, None, conditions=conditions, executor=ex,
                                 scenes=f"scenes.random({n_validation}, seed={VALIDATION_SEED}, **{TEST_KWARGS})")
        test = simulate_cached(n_test, TEST_SEED, TEST_KWARGS, cache_dir, progress, **spread)
        rep = evaluate(SlipDetector(w), test, {})
    w.metadata["evaluation"] = dict(w.metadata.get("evaluation") or {},
                                    scenes=f"scenes.random({n_test}, seed={TEST_SEED}, **{TEST_KWARGS})",
                                    detector=rep["detector"].as_dict())
    w.save(out_path)
    return w, info
