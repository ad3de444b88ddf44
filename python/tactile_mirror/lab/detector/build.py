"""Building the bundled detector: simulate scenes, study the hidden size, train, evaluate.

Command line (writes the weights, a report and Figure 10)::

    python -m tactile_mirror.lab.detector.build --out weights.npz [--study] [--report report.txt]

The bundled ``data/paper_detector.npz`` (the paper's net) was made with the defaults of :class:`BuildOptions`
(64 training scenes, two noise copies of each at 0-5 mV, gain augmentation 0.6-1.7, H = 16,
:data:`TRAIN_OPTIONS`, 4 initial seeds with checkpoints every 25 iterations, the best on 120
validation scenes kept, evaluated on 200 held-out scenes; about 8 min on 2 cores); its
metadata records the scenes, the training settings, the selection and the held-out evaluation.
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass

import numpy as np

from tactile_mirror._checks import integer
from tactile_mirror._io import save_figure, write_text
from tactile_mirror.detector.core import SlipDetector
from tactile_mirror.detector.memory import DEFAULT_LOAD_TAU
from tactile_mirror.detector.weights import KINDS
from tactile_mirror.lab.detector.augment import augment_gains, augment_noise, compress_training_set
from tactile_mirror.lab.detector.evaluation import ForceRatioDetector, evaluate
from tactile_mirror.lab.detector.training import TrainingSet, make_training_set, train_detector

__all__ = [
    "EXTRA_TRAIN_SEED",
    "NOISE_COPIES",
    "NOISE_RANGE",
    "TEST_KWARGS",
    "TEST_SEED",
    "TRAIN_KWARGS",
    "TRAIN_OPTIONS",
    "TRAIN_SEED",
    "VALIDATION_SEED",
    "BuildOptions",
    "ValidationScorer",
    "build_default",
    "calibrate_slip",
    "hidden_size_study",
    "recalibrate",
    "select_candidate",
    "simulate_cached",
    "simulate_scenes",
    "train_selected",
    "uncalibrate",
]

#: Seeds of the training, validation and held-out scene sets (different on purpose).
TRAIN_SEED = 20261121
#: Seed of the extra training scenes drawn from the held-out ranges (``BuildOptions.n_extra_train``;
#: the bound study's extra training seed).
EXTRA_TRAIN_SEED = 99
TEST_SEED = 777
VALIDATION_SEED = 4242

#: Scene options of the training set (``scenes.random`` defaults otherwise).
TRAIN_KWARGS = {"stop_after_slip": 0.3}
#: Training options of the bundled detector.
TRAIN_OPTIONS = {"negative_weight": 10.0, "normalisation": "rms", "pred_weight": 4.0}
#: Sensor-noise copies of every training scene and their noise range, V rms.
NOISE_COPIES = 2
NOISE_RANGE = (0.0, 5e-3)
#: The held-out set: wider friction, indent, slide speed, stop and noise ranges.
TEST_KWARGS = {"friction": (0.35, 1.0), "indent": (15e-6, 50e-6), "slide_speed": (0.05e-3, 0.6e-3),
               "stop_probability": 0.7, "stop_length": (0.02, 0.15), "noise": (0.0, 4e-3),
               "stop_after_slip": 0.3}


def simulate_scenes(scenes, progress: bool = True, executor=None) -> list:
    """Simulate scenes: ``tactile_mirror.simulate_many`` (processes) when available."""
    import tactile_mirror

    scenes = list(scenes)
    many = getattr(tactile_mirror, "simulate_many", None)
    if many is not None and len(scenes) > 1:
        return list(many(scenes, executor=executor, progress=progress))
    from tqdm.auto import tqdm

    return [tactile_mirror.simulate(s) for s in tqdm(scenes, desc="simulate", disable=not progress, leave=False)]


def simulate_cached(n: int, seed: int, kwargs: dict, cache_dir=None, progress: bool = True) -> list:
    """``simulate_scenes(scenes.random(n, seed=seed, **kwargs))``, kept in ``cache_dir`` (pickle) if given.

    The cache file is named by ``n``, ``seed`` and a hash of ``kwargs`` and of the
    library version, so changed scene options never read stale results; delete the
    directory after a change of the contact solver. The hash covers the full content of
    every value (a numpy array's dtype, shape and bytes, not its abbreviated repr); for
    plain values (numbers, strings, tuples, lists, dicts of them) it is the hash of their
    repr, as it always was. Only for files this process or one like it wrote: pickle runs
    code from the file.

    ``cache_dir`` is checked (a folder, or one that can be made, in which the file can be
    written) before anything is simulated. A cache file that cannot be read or does not
    hold ``n`` simulation results (a truncated save, a foreign pickle) is a cache miss: a
    warning names it, the scenes are simulated again and the file is replaced atomically.
    """
    if cache_dir is None:
        return simulate_scenes(_random_scenes(n, seed, **kwargs), progress)
    import os
    import pickle

    from tactile_mirror import __version__
    from tactile_mirror._io import atomic_write, check_writable

    try:
        folder = os.fspath(cache_dir)
    except TypeError:
        raise TypeError(f"cache_dir must be a path (str or os.PathLike), got {cache_dir!r}") from None
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise NotADirectoryError(f"cache_dir {folder!r} is a file, not a folder")
    if not isinstance(kwargs, dict):
        raise TypeError(f"kwargs must be a dict of scenes.random options, got {type(kwargs).__name__}")
    key = _cache_key(n, seed, kwargs, __version__)
    path = os.path.join(folder, f"scenes_{seed}_{n}_{key}.pkl")
    if os.path.exists(path):
        res = _load_cached_scenes(path, n)
        if res is not None:
            return res
    try:  # (before the simulation, not after it)
        os.makedirs(folder, exist_ok=True)
        check_writable(path)
    except OSError as exc:
        raise type(exc)(f"cache_dir {folder!r} cannot hold the scene cache: {exc}") from exc
    res = simulate_scenes(_random_scenes(n, seed, **kwargs), progress)
    with atomic_write(path, "wb") as fh:
        pickle.dump(res, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return res


def _load_cached_scenes(path: str, n: int):
    """The ``n`` results in the cache file ``path``, or None (with a warning naming the file)
    if it cannot be unpickled or holds anything else."""
    import pickle
    import warnings
    from pathlib import Path

    from tactile_mirror.contact.simulate import SimulationResult

    try:
        value = pickle.loads(Path(path).read_bytes())
    except (pickle.UnpicklingError, EOFError, OSError, AttributeError, ImportError, IndexError, KeyError,
            TypeError, ValueError, MemoryError) as exc:  # (truncated: EOFError; garbage: UnpicklingError, ...)
        problem = f"cannot be read ({type(exc).__name__}: {exc})"
    else:
        if not isinstance(value, list):
            problem = f"holds a {type(value).__name__}, not a list of simulation results"
        elif len(value) != n:
            problem = f"holds {len(value)} results, not {n}"
        elif not all(isinstance(r, SimulationResult) for r in value):
            bad = next(r for r in value if not isinstance(r, SimulationResult))
            problem = f"holds a {type(bad).__name__} among its results, not only SimulationResult"
        else:
            return value
    warnings.warn(f"scene cache {path!r} {problem}; simulating the scenes again and replacing it",
                  RuntimeWarning, stacklevel=3)
    return None


def _plain(value) -> bool:
    """True if ``repr(value)`` holds all of ``value`` (numbers, strings, None, numpy scalars,
    and tuples, lists and dicts of them; not arrays, whose repr is abbreviated, nor objects)."""
    if value is None or isinstance(value, (bool, int, float, complex, str, bytes, np.generic)):
        return True
    if isinstance(value, (tuple, list)):
        return all(_plain(v) for v in value)
    if isinstance(value, dict):
        return all(_plain(k) and _plain(v) for k, v in value.items())
    return False


def _hash_content(h, value) -> None:
    """Feed the full content of ``value`` to the hash ``h`` (type-tagged: ``(1,)`` and ``[1]``,
    an array and its list, differ)."""
    if isinstance(value, np.ndarray):
        h.update(f"ndarray {value.dtype.str} {value.shape}\0".encode())
        if value.dtype.hasobject:
            for v in value.ravel(order="C"):
                _hash_content(h, v)
        else:
            h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, (tuple, list)):
        h.update(f"{type(value).__name__} {len(value)}\0".encode())
        for v in value:
            _hash_content(h, v)
    elif isinstance(value, dict):
        h.update(f"dict {len(value)}\0".encode())
        for k, v in sorted(value.items(), key=lambda kv: repr(kv[0])):
            _hash_content(h, k)
            _hash_content(h, v)
    elif _plain(value):
        h.update(f"{type(value).__name__} {value!r}\0".encode())
    else:  # any other object: its pickle holds its state (arrays in full)
        import pickle

        try:
            data = pickle.dumps(value, protocol=4)
        except (pickle.PicklingError, TypeError, AttributeError):
            data = repr(value).encode()
        h.update(f"object {type(value).__module__}.{type(value).__qualname__} {len(data)}\0".encode())
        h.update(data)


def _cache_key(n: int, seed: int, kwargs: dict, version: str) -> str:
    """The 16-hex-digit key of a scene set in :func:`simulate_cached`'s cache."""
    import hashlib

    if _plain(kwargs):
        # the repr holds every value in full: the key the existing cache files were saved under
        return hashlib.sha256(repr((n, seed, sorted(kwargs.items()), version)).encode()).hexdigest()[:16]
    h = hashlib.sha256(b"simulate_cached content key 1\0")
    h.update(repr((n, seed, version)).encode())
    for name in sorted(kwargs):
        h.update(f"{name!r}\0".encode())
        _hash_content(h, kwargs[name])
    return h.hexdigest()[:16]


def subset(ts: TrainingSet, ridges_per_scene: int, n_ridges: int) -> TrainingSet:
    """Keep the first ``ridges_per_scene`` of every ``n_ridges`` sequences (scene-major order)."""
    keep = (np.arange(ts.n_seq) % n_ridges) < ridges_per_scene
    return TrainingSet(ts.x[keep], ts.y_slip[keep], ts.y_pred[keep], ts.mask[keep], ts.fs, ts.features,
                       ts.estimator, ts.targets, ts.load_tau, ts.bank)


def hidden_size_study(train, validation, sizes=(4, 8, 12, 16, 24), maxiter: int = 800, seed: int = 0,
                      candidates: int = 4, checkpoint_every: int = 25, progress: bool = True,
                      **train_options) -> list:
    """Train a detector per hidden size as the build does and score it on validation results.

    Each size gets the build's procedure (:func:`train_selected`: ``candidates``
    seeds, checkpoints, the best on ``validation`` kept), so sizes are compared
    at their best rather than at one arbitrary iteration count. ``validation``
    must not be the held-out set the chosen size is reported on.

    Returns
    -------
    list of dict
        Per size: ``n_hidden``, ``seconds`` (training and selection), ``iterations``
        and ``seed`` of the kept candidate, and its validation detection rate,
        false-alarm rate, y_pred lead and score.
    """
    scorer = validation if isinstance(validation, ValidationScorer) else ValidationScorer(validation)
    rows = []
    for h in sizes:
        t0 = time.perf_counter()
        w, k, scores = train_selected(train, int(h), maxiter, seed, candidates, checkpoint_every, scorer,
                                      progress=progress, **train_options)
        rows.append({"n_hidden": int(h), "seconds": round(time.perf_counter() - t0, 1),
                     "iterations": int(w.metadata["training"]["iterations"]),
                     "seed": int(w.metadata["training"]["seed"]), **scores[k]})
    return rows


def train_selected(ts, n_hidden: int, maxiter: int, seed: int, candidates: int, checkpoint_every: int, scorer,
                   feedback: bool = True, progress: bool = True, metadata=None, **train_options):
    """Train ``candidates`` seeds (``seed``, ``seed + 1``, ...) and keep the best on ``scorer``.

    With ``checkpoint_every`` > 0 the iterates every that many L-BFGS-B
    iterations are candidates too (early stopping). Without a scorer the last
    seed's final weights are returned.

    Returns
    -------
    weights, index of the kept candidate, list of candidate scores (empty without a scorer)
    """
    ws = []
    for k in range(max(1, int(candidates))):
        cb = (lambda it, wk: ws.append(wk)) if scorer is not None and checkpoint_every else None
        ws.append(train_detector(ts, n_hidden=int(n_hidden), maxiter=maxiter, seed=seed + k, feedback=feedback,
                                 progress=progress, metadata=metadata, callback=cb,
                                 callback_every=checkpoint_every or 1, **train_options))
    if scorer is None:
        return ws[-1], len(ws) - 1, []
    return select_candidate(ws, scorer)


def condition_names(conditions, name: str) -> tuple[str, ...]:
    """``conditions`` (one name or a sequence) as a tuple of distinct keys of
    :data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`; ValueError naming ``name``."""
    from tactile_mirror.lab.detector.evaluation import NOISE_CONDITIONS

    names = (conditions,) if isinstance(conditions, str) else tuple(conditions)
    if not names:
        raise ValueError(f"{name} must name at least one sensor condition")
    for c in names:
        if c not in NOISE_CONDITIONS:
            raise ValueError(f"{name}: unknown condition {c!r}; known: {sorted(NOISE_CONDITIONS)}")
    if len(set(names)) != len(names):
        raise ValueError(f"{name}: a condition is named twice in {names!r}")
    return names


def condition_results(validation, names, seed: int) -> dict:
    """``{name: results}``: the ``validation`` results' noise-free outputs plus the noise of
    each sensor condition ``names`` (seeded ``seed`` + its place in ``names``; a noise-free
    condition gets the clean results themselves). :class:`ValidationScorer` and
    :func:`calibrate_slip` score in these copies."""
    from tactile_mirror.lab.detector.evaluation import NOISE_CONDITIONS, noise_free, with_noise

    clean = noise_free(validation)
    return {name: clean if NOISE_CONDITIONS[name] == (0.0, None, None) else with_noise(clean, name, seed + k)
            for k, name in enumerate(names)}


class ValidationScorer:
    """Scores detector weights on validation results (features computed once).

    ``scorer(weights)`` returns the detection and false-alarm rates, the y_pred
    lead and ``score = detection_rate - fa_cost * false_alarm_rate`` of the
    weights on the validation set (:func:`~tactile_mirror.lab.detector.evaluation.evaluate`'s
    definitions). Scoring hundreds of checkpoints costs one C++ block run per
    scene each, not a feature computation.

    With ``at_false_alarm`` (a rate) the score is instead the detection rate at that
    false-alarm rate along the net's threshold sweep (:func:`~tactile_mirror.lab.detector.evaluation.roc`;
    also returned as ``detection_at_false_alarm``): the right score for a net whose decision
    point is calibrated afterwards (:func:`calibrate_slip`), where what the threshold
    0.8 of the uncalibrated net gives does not matter, only how far its curve reaches.

    ``conditions`` (with ``at_false_alarm``): names of sensor conditions
    (:data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`) in which to score instead of
    the scenes' own noise: their noise-free outputs plus each condition's noise (seeded by
    ``noise_seed`` + the condition's place in ``conditions``, as :func:`calibrate_slip` seeds
    its own), the score the mean detection rate over them. The goals and the calibration are
    stated in these conditions; the scenes' own noise (0-4 mV) ranks candidates otherwise (see
    docs/detector.md, "How soon"). Also returned: ``latency_gradual_ms``, the mean latency of
    the gradual onsets found, over the conditions.
    """

    def __init__(self, validation, fa_cost: float = 10.0, at_false_alarm: float | None = None,
                 conditions=None, noise_seed: int = 4000):
        self.validation = list(validation)
        if not self.validation:
            raise ValueError("validation must not be empty")
        if not np.isfinite(fa_cost) or fa_cost < 0:
            raise ValueError(f"fa_cost must be a non-negative number, got {fa_cost!r}")
        if at_false_alarm is not None and not (isinstance(at_false_alarm, (int, float))
                                               and not isinstance(at_false_alarm, bool)
                                               and 0 <= at_false_alarm < 1):
            raise ValueError(f"at_false_alarm must be a false-alarm rate in [0, 1) or None, got {at_false_alarm!r}")
        self.fa_cost = float(fa_cost)
        self.at_false_alarm = None if at_false_alarm is None else float(at_false_alarm)
        self._features = {}
        self.conditions = None
        if conditions is not None:
            from tactile_mirror.lab.detector.evaluation import onset_kinds

            names = condition_names(conditions, "conditions")
            if self.at_false_alarm is None:
                raise ValueError("conditions needs at_false_alarm (they score the threshold sweep)")
            self.conditions = condition_results(self.validation, names, integer(noise_seed, "noise_seed", 0))
            self._condition_features = {name: {} for name in names}
            self._kinds = onset_kinds(self.validation)  # (the latency per onset kind)

    def __call__(self, weights) -> dict:
        det = SlipDetector(weights)
        m = evaluate(det, self.validation, features_cache=self._features)["detector"]
        out = {"detection_rate": m.detection_rate, "false_alarm_rate": m.false_alarm_rate,
               "false_alarm_samples": m.false_alarm_samples, "pred_lead_mean_ms": m.pred_lead_mean_ms,
               "score": m.detection_rate - self.fa_cost * m.false_alarm_rate}
        if self.at_false_alarm is not None:
            from tactile_mirror.lab.detector.evaluation import cached_features
            from tactile_mirror.lab.detector.roc import roc

            # the features evaluate() has just computed, from the same cache
            scores = [det.run(cached_features(det, k, r, self._features), fs=r.fs)[0]
                      for k, r in enumerate(self.validation)]
            if self.conditions is None:
                point = roc(scores, self.validation).at_false_alarm(self.at_false_alarm)
                out["detection_at_false_alarm"] = point["detection_rate"]
                out["score"] = point["detection_rate"]
                return out
            from tactile_mirror.detector.data_prep import features_from_result
            from tactile_mirror.lab.detector.evaluation import condition_estimator

            points = {}
            for name, res in self.conditions.items():
                cache, est = self._condition_features[name], condition_estimator(det, name)
                key = (det.features, repr(est))  # (the features do not depend on the weights: once per kind)
                if key not in cache:
                    cache[key] = [features_from_result(r, det.features, estimator=est) for r in res]
                scores = [det.run(x, fs=r.fs)[0] for x, r in zip(cache[key], res)]
                points[name] = roc(scores, self.validation, self._kinds).at_false_alarm(self.at_false_alarm)
            out["conditions"] = {name: {"detection_rate": p["detection_rate"],
                                        "false_alarm_rate": p["false_alarm_rate"],
                                        "latency_gradual_ms": p.get("latency_gradual_ms", float("nan"))}
                                 for name, p in points.items()}
            out["detection_at_false_alarm"] = float(np.mean([p["detection_rate"] for p in points.values()]))
            lat = np.array([c["latency_gradual_ms"] for c in out["conditions"].values()], dtype=float)
            out["latency_gradual_ms"] = float(lat[np.isfinite(lat)].mean()) if np.isfinite(lat).any() else float("nan")
            out["score"] = out["detection_at_false_alarm"]
        return out


def select_candidate(candidates, validation, fa_cost: float = 10.0):
    """The candidate weights with the best validation score, and every score.

    Training a recurrent net by L-BFGS-B from different initial weights ends in
    different minima (on this problem detection varied by 10 points and false
    alarms by 2-15 points between seeds), and along one run the training loss
    keeps falling after the validation false alarms have started to rise (nets
    run to 800 iterations raised 12-29 % false alarms where their own
    100-iteration checkpoints raised 1-5 %). So the build trains a few seeds,
    keeps checkpoints, and takes the candidate scoring best on a validation set
    that is neither the training nor the held-out set:
    ``detection_rate - fa_cost * false_alarm_rate`` (a false alarm moves the stage
    for nothing; ``fa_cost`` = 10 prices one like ten misses), ties broken by
    fewer false-alarm samples, then by the y_pred lead.

    Parameters
    ----------
    candidates : sequence of DetectorWeights
    validation : ValidationScorer or sequence of simulation results
    """
    candidates = list(candidates)
    if not candidates:
        raise ValueError("candidates must not be empty")
    scorer = validation if isinstance(validation, ValidationScorer) else ValidationScorer(validation, fa_cost)
    scores = [scorer(w) for w in candidates]
    best = max(range(len(candidates)), key=lambda i: (scores[i]["score"], -scores[i]["false_alarm_samples"],
                                                      scores[i]["pred_lead_mean_ms"]))
    return candidates[best], best, scores


def bias_shift(threshold: float, slip_threshold: float = 0.8) -> float:
    """What to add to ``y_slip``'s output bias ``b2[0]`` so that the net's ``y_slip >=
    threshold`` becomes ``y_slip >= slip_threshold``, exactly (``y_slip`` is not fed back):
    ``logit(slip_threshold) - logit(threshold)``."""
    import math

    return math.log(slip_threshold / (1 - slip_threshold)) - math.log(threshold / (1 - threshold))


def _check_rate(value, name: str) -> None:
    if isinstance(value, bool) or not (isinstance(value, (int, float)) and 0 <= value < 1):
        raise ValueError(f"{name} must be a false-alarm rate in [0, 1), got {value!r}")


def calibrate_slip(weights, validation, false_alarm: float | None, slip_threshold: float = 0.8, scenes: str = "",
                   conditions=None, seed: int = 5000):
    """Weights whose ``y_slip >= slip_threshold`` alarms at most ``false_alarm`` of the
    validation sequences without slip in time.

    ``y_slip`` is not fed back (only ``y_pred`` is), so adding ``c`` to its output bias
    ``b2[0]`` thresholds the same net at another level, exactly: the lowest threshold
    ``t`` whose false-alarm rate on ``validation`` is at most ``false_alarm``
    (:func:`~tactile_mirror.lab.detector.evaluation.roc`, the evaluation's own definitions)
    becomes ``slip_threshold`` with ``c = logit(slip_threshold) - logit(t)``. Every
    consumer (the pipeline's status, the slip guard, :func:`evaluate`) keeps the one
    rule ``y_slip >= 0.8``. Choose ``validation`` disjoint from what is reported.

    ``conditions``: a mapping of sensor conditions (keys of
    :data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`) to false-alarm bounds. The
    validation scenes are then scored in each condition (their noise-free outputs plus the
    condition's noise, seeded by ``seed`` + the condition's index) instead of in their own
    noise, and ``t`` is the lowest threshold that keeps every condition within its bound
    (``false_alarm`` is not used; pass None). A bound somewhat below the rate a goal allows
    leaves room for the difference between two scene sets: the standard error of a rate
    near 2 % is 0.6 points on 480 sequences, 1 point on 200.

    Returns ``(weights, info)``; ``info`` (threshold found, bias shift, the validation's
    detection and false-alarm rates, per condition if given) is also stored in
    ``metadata["slip_calibration"]``.
    """
    import copy

    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector.evaluation import condition_estimator, onset_kinds
    from tactile_mirror.lab.detector.roc import roc

    if isinstance(slip_threshold, bool) or not (isinstance(slip_threshold, (int, float)) and 0 < slip_threshold < 1):
        raise ValueError(f"slip_threshold must be in (0, 1), got {slip_threshold!r}")
    if conditions is None:
        if false_alarm is None:
            raise ValueError("give false_alarm or conditions")
        _check_rate(false_alarm, "false_alarm")  # (NaN or -1 gave a detector that never alarms; 5, always)
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
            _check_rate(conditions[name], f"conditions[{name!r}]")
        copies = condition_results(validation, names, seed)
        runs = {name: (copies[name], condition_estimator(det, name), float(conditions[name])) for name in names}
    curves = {}
    t = 0.0
    for name, (res, est, fa) in runs.items():
        scores = [det.run(features_from_result(r, det.features, estimator=est), fs=r.fs)[0] for r in res]
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
                cache_dir=None, progress: bool = True):
    """Calibrate a trained net's decision point anew (:func:`uncalibrate`, then
    :func:`calibrate_slip` with ``conditions`` on ``n_validation`` validation scenes, seed
    :data:`VALIDATION_SEED`), refresh its held-out evaluation record (``n_test`` scenes, seed
    :data:`TEST_SEED`, as :func:`build_default` writes it) and save it to ``out_path``.
    Returns ``(weights, info)``."""
    from tactile_mirror.detector.weights import DetectorWeights

    w = uncalibrate(DetectorWeights.load(weights_path))
    val = simulate_cached(n_validation, VALIDATION_SEED, TEST_KWARGS, cache_dir, progress)
    w, info = calibrate_slip(w, val, None, conditions=conditions,
                             scenes=f"scenes.random({n_validation}, seed={VALIDATION_SEED}, **{TEST_KWARGS})")
    test = simulate_cached(n_test, TEST_SEED, TEST_KWARGS, cache_dir, progress)
    rep = evaluate(SlipDetector(w), test, {})
    w.metadata["evaluation"] = dict(w.metadata.get("evaluation") or {},
                                    scenes=f"scenes.random({n_test}, seed={TEST_SEED}, **{TEST_KWARGS})",
                                    detector=rep["detector"].as_dict())
    w.save(out_path)
    return w, info


def _random_scenes(n, seed, **kwargs):
    from tactile_mirror import scenes

    return scenes.random(n, seed=seed, **kwargs)


def _positive_int(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or int(value) != value or value < minimum:
        kind = "positive" if minimum == 1 else "non-negative"
        raise ValueError(f"{name} must be a {kind} integer, got {value!r}")
    return int(value)


def _pair(name: str, value) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a pair of numbers (low, high), got {value!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
        raise ValueError(f"{name} must satisfy 0 <= low <= high (finite), got {value!r}")
    return lo, hi


@dataclass(frozen=True)
class BuildOptions:
    """How :func:`build_default` builds the detector. Frozen; fields are checked on
    construction (``ValueError``/``TypeError`` naming the field). The defaults made the
    bundled weights.

    Attributes
    ----------
    n_train, n_test : int
        Randomised training scenes (seed :data:`TRAIN_SEED`) and held-out scenes
        (seed :data:`TEST_SEED`, wider parameters via ``test_kwargs``). Defaults 64, 200.
    n_hidden : int
        Hidden size of the shipped net. Default 16.
    maxiter : int
        L-BFGS-B iterations per training run. Default 800.
    ridges_per_scene : int
        Ridges of each training scene used as sequences. Default 1.
    seed : int
        First initial seed of the training runs. Default 0.
    study_sizes : tuple of int, optional
        Also run :func:`hidden_size_study` with these hidden sizes (scored on the
        validation scenes, not the held-out set).
    train_kwargs, test_kwargs : dict, optional
        Scene options of :func:`tactile_mirror.scenes.random`; default
        :data:`TRAIN_KWARGS`, :data:`TEST_KWARGS` (stored as copies).
    train_options : dict, optional
        Extra :func:`train_detector` options; default :data:`TRAIN_OPTIONS`.
    gain_range : (float, float) or None
        Gain augmentation of the training sequences (:func:`augment_gains`), as
        factors. Default (0.6, 1.7); None: none.
    noise_copies : int
        Each training scene enters ``noise_copies`` times with fresh sensor noise
        (:func:`augment_noise`; 0: the scenes' own noise). Default :data:`NOISE_COPIES`.
    noise_range : (float, float)
        Range of that noise, V rms. Default :data:`NOISE_RANGE`.
    n_validation, candidates, checkpoint_every : int
        Each net (and the no-feedback baseline) is trained from ``candidates``
        initial seeds (``seed``, ``seed + 1``, ...); of these runs, and of their
        checkpoints every ``checkpoint_every`` iterations (0: final weights only),
        the best on ``n_validation`` scenes (seed :data:`VALIDATION_SEED`, held-out
        ranges) is kept (:func:`select_candidate`). Defaults 120, 4, 25.
    progress : bool
        Progress bars. Default True.
    kind : {"jordan", "jordan_memory", "jordan_bank"}
        ``"jordan"``: the paper's net on the four stress rates (``paper_detector.npz``);
        ``"jordan_memory"``: the same net on the load-memory channels
        (:mod:`~tactile_mirror.detector.memory`; ``memory_detector.npz``);
        ``"jordan_bank"``: on the filter-bank channels with the default bank
        (:mod:`~tactile_mirror.detector.bank`; ``bank_detector.npz``).
    load_tau : float
        Leak time constant of the load integrals of ``"jordan_memory"``, s.
    n_extra_train : int
        Extra training scenes drawn from the held-out ranges (``test_kwargs``) with seed
        :data:`EXTRA_TRAIN_SEED`: lower friction and stops, where slips creep in. Default 0.
    bank : dict, optional
        Time constants of the ``"jordan_bank"`` filter bank (:func:`~tactile_mirror.detector.bank.bank_config`);
        default :data:`~tactile_mirror.detector.bank.DEFAULT_BANK`.
    calibrate_fa : float, optional
        After the selection, move ``y_slip``'s decision point so that ``y_slip >= 0.8``
        gives at most this false-alarm rate on the validation scenes
        (:func:`calibrate_slip`); None (default): no calibration.
    compress : bool
        ``"jordan_bank"`` only: train on the bank's inputs compressed to
        ``sign(x) log(1 + |x| / knee)`` (:func:`~tactile_mirror.detector.bank.log_compress`),
        the knees the median ``|x|`` of the training inputs (after the gains), kept in the
        weights' bank. Default False.
    calibrate_conditions : dict, optional
        Instead of ``calibrate_fa``: false-alarm bounds per sensor condition (keys of
        :data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`); the decision point is
        the lowest that keeps the validation scenes within every bound in its condition
        (:func:`calibrate_slip` with ``conditions``).

        With either, the candidates are chosen by their validation detection at that
        false-alarm rate (the smallest bound) along their threshold sweep
        (``ValidationScorer(at_false_alarm=...)``), since the calibration, not the
        threshold the net was trained to, sets where they operate.
    select_conditions : tuple of str, optional
        Choose the candidates in these sensor conditions (keys of
        :data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`: the validation scenes'
        noise-free outputs plus each condition's noise, ``ValidationScorer(conditions=...)``)
        instead of in the scenes' own noise, by their mean detection at ``select_fa``.
    select_fa : float, optional
        The false-alarm rate of that choice (default: the calibration's, as above).
    """

    n_train: int = 64
    n_test: int = 200
    n_hidden: int = 16
    maxiter: int = 800
    ridges_per_scene: int = 1
    seed: int = 0
    study_sizes: tuple[int, ...] | None = None
    train_kwargs: dict | None = None
    test_kwargs: dict | None = None
    train_options: dict | None = None
    gain_range: tuple[float, float] | None = (0.6, 1.7)
    noise_copies: int = NOISE_COPIES
    noise_range: tuple[float, float] = NOISE_RANGE
    n_validation: int = 120
    candidates: int = 4
    checkpoint_every: int = 25
    progress: bool = True
    kind: str = "jordan"
    load_tau: float = DEFAULT_LOAD_TAU
    n_extra_train: int = 0
    bank: dict | None = None
    calibrate_fa: float | None = None
    calibrate_conditions: dict | None = None
    compress: bool = False
    select_conditions: tuple[str, ...] | None = None
    select_fa: float | None = None

    def __post_init__(self) -> None:
        def put(name, value):
            object.__setattr__(self, name, value)

        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {sorted(KINDS)}, got {self.kind!r}")
        if isinstance(self.load_tau, bool) or not isinstance(self.load_tau, (int, float)) \
                or not (np.isfinite(self.load_tau) and self.load_tau > 0):
            raise ValueError(f"load_tau must be a positive number of seconds, got {self.load_tau!r}")
        put("load_tau", float(self.load_tau))
        if not isinstance(self.compress, bool):
            raise TypeError(f"compress must be True or False, got {self.compress!r}")
        if self.compress and self.kind != "jordan_bank":
            raise ValueError(f"compress is for kind 'jordan_bank' (its bank's inputs), not {self.kind!r}")
        if self.bank is not None:
            from tactile_mirror.detector.bank import bank_config

            put("bank", bank_config(self.bank))
        for name in ("n_train", "n_test", "n_hidden", "maxiter", "ridges_per_scene", "candidates"):
            put(name, _positive_int(name, getattr(self, name)))
        for name in ("noise_copies", "checkpoint_every", "n_extra_train"):
            put(name, _positive_int(name, getattr(self, name), minimum=0))
        if isinstance(self.seed, bool) or int(self.seed) != self.seed:
            raise ValueError(f"seed must be an integer, got {self.seed!r}")
        put("seed", int(self.seed))
        if self.selecting:
            put("n_validation", _positive_int("n_validation", self.n_validation))
        if self.study_sizes is not None:
            put("study_sizes", tuple(_positive_int("study_sizes", h) for h in self.study_sizes))
        for name, default in (("train_kwargs", TRAIN_KWARGS), ("test_kwargs", TEST_KWARGS),
                              ("train_options", TRAIN_OPTIONS)):
            value = getattr(self, name)
            if value is not None and not isinstance(value, dict):
                raise TypeError(f"{name} must be a dict or None, got {type(value).__name__}")
            put(name, dict(default if value is None else value))
        if self.gain_range is not None:
            put("gain_range", _pair("gain_range", self.gain_range))
        put("noise_range", _pair("noise_range", self.noise_range))
        put("progress", bool(self.progress))
        if self.calibrate_fa is not None:
            fa = self.calibrate_fa
            if isinstance(fa, bool) or not isinstance(fa, (int, float)) or not 0 < fa < 1:
                raise ValueError(f"calibrate_fa must be a false-alarm rate in (0, 1), got {fa!r}")
            if not self.selecting:
                raise ValueError("calibrate_fa needs the validation scenes: candidates > 1 or checkpoint_every > 0")
            put("calibrate_fa", float(fa))
        if self.select_conditions is not None:
            put("select_conditions", condition_names(self.select_conditions, "select_conditions"))
            if not self.selecting:
                raise ValueError("select_conditions needs the validation scenes: candidates > 1 or "
                                 "checkpoint_every > 0")
            if self.select_fa is None and self.calibrate_fa is None and self.calibrate_conditions is None:
                raise ValueError("select_conditions needs a false-alarm rate: select_fa, calibrate_fa or "
                                 "calibrate_conditions")
        if self.select_fa is not None:
            _check_rate(self.select_fa, "select_fa")
            put("select_fa", float(self.select_fa))
        if self.calibrate_conditions is not None:
            cc = self.calibrate_conditions
            if not isinstance(cc, dict) or not cc:
                raise ValueError(f"calibrate_conditions must be a non-empty dict, got {cc!r}")
            if self.calibrate_fa is not None:
                raise ValueError("give calibrate_fa or calibrate_conditions, not both")
            condition_names(cc, "calibrate_conditions")
            for name, fa in cc.items():
                if isinstance(fa, bool) or not isinstance(fa, (int, float)) or not 0 < fa < 1:
                    raise ValueError(f"calibrate_conditions[{name!r}] must be a false-alarm rate in (0, 1), "
                                     f"got {fa!r}")
            if not self.selecting:
                raise ValueError("calibrate_conditions needs the validation scenes: candidates > 1 or "
                                 "checkpoint_every > 0")
            put("calibrate_conditions", {k: float(v) for k, v in cc.items()})

    @property
    def selecting(self) -> bool:
        """Whether the build chooses among candidates on validation scenes."""
        return self.candidates > 1 or self.checkpoint_every > 0


def build_default(out_path, options: BuildOptions | None = None, *, report_path=None, figure_path=None,
                  results=None, cache_dir=None):
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
        Keep the simulated scene sets there between builds (:func:`simulate_cached`).

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
    return _build(out_path, options, report_path, figure_path, results, **extra)


def _build(out_path, options: BuildOptions, report_path, figure_path, results, cache_dir=None):
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
    t0 = time.perf_counter()
    results = list(results) if results is not None else []
    train_res = list(results[0]) if len(results) > 0 else simulate_cached(
        n_train, TRAIN_SEED, train_kwargs, cache_dir, progress)
    test_res = list(results[1]) if len(results) > 1 else simulate_cached(
        n_test, TEST_SEED, test_kwargs, cache_dir, progress)
    val_res = []
    if selecting:
        val_res = list(results[2]) if len(results) > 2 else simulate_cached(
            n_validation, VALIDATION_SEED, test_kwargs, cache_dir, progress)
    if o.n_extra_train:
        train_res = train_res + simulate_cached(o.n_extra_train, EXTRA_TRAIN_SEED, test_kwargs, cache_dir, progress)
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
                                                        checkpoint_every, progress, **opts)
    meta = {"scenes": f"scenes.random({n_train}, seed={TRAIN_SEED}, **{train_kwargs})",
            "ridges_per_scene": ridges_per_scene, "kind": o.kind}
    if o.n_extra_train:
        meta["extra_scenes"] = f"scenes.random({o.n_extra_train}, seed={EXTRA_TRAIN_SEED}, **{test_kwargs})"

    def train(feedback):
        return train_selected(ts, n_hidden, maxiter, seed, candidates, checkpoint_every, scorer, feedback,
                              progress, meta, **opts)

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
            w, val_res, o.calibrate_fa, conditions=o.calibrate_conditions,
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


#: The command line's option for each BuildOptions field (named in its errors' messages).
_OPTIONS = {"n_train": "--n-train", "n_test": "--n-test", "n_hidden": "--hidden", "maxiter": "--maxiter",
            "study_sizes": "--study", "candidates": "--candidates", "n_extra_train": "--extra-train",
            "checkpoint_every": "--checkpoint-every", "noise_range": "--noise-range", "calibrate_fa": "--calibrate-fa",
            "calibrate_conditions": "--calibrate-goals / --calibrate-condition", "n_validation": "--n-validation",
            "bank": "--lp-taus / --abs-taus", "compress": "--compress", "kind": "--kind",
            "select_conditions": "--select-conditions", "select_fa": "--select-fa"}


def _usage_error(ap: argparse.ArgumentParser, exc: Exception):
    """``ap.error`` (usage line, exit status 2) for an argument the options refused, naming its option."""
    msg = str(exc)
    for field, option in _OPTIONS.items():
        if msg.startswith(field):
            ap.error(f"argument {option}: {msg}")
    ap.error(msg)


def main(argv=None):
    """The command line. Bad arguments (a count below 1, a negative weight, a bank time
    constant <= 0, ...) end in a usage line and exit status 2, before anything is simulated."""
    from tactile_mirror._checks import real_number

    ap = argparse.ArgumentParser(description="Train and evaluate the default slip detector.")
    ap.add_argument("--out", required=True, help="weights file to write (.npz)")
    ap.add_argument("--recalibrate", metavar="WEIGHTS", default=None,
                    help="do not train: calibrate the net in WEIGHTS anew (--calibrate-goals, --n-validation) and "
                         "write it to --out")
    ap.add_argument("--report", help="text report to write")
    ap.add_argument("--figure", help="Figure 10 image to write (.png)")
    ap.add_argument("--n-train", type=int, default=64)
    ap.add_argument("--n-test", type=int, default=200)
    ap.add_argument("--hidden", type=int, default=16)
    ap.add_argument("--maxiter", type=int, default=800)
    ap.add_argument("--study", type=int, nargs="*", help="hidden sizes to compare")
    ap.add_argument("--negative-weight", type=float, default=TRAIN_OPTIONS["negative_weight"])
    ap.add_argument("--pred-weight", type=float, default=TRAIN_OPTIONS["pred_weight"])
    ap.add_argument("--onset-weight", type=float, default=0.0,
                    help="extra weight of the first 50 ms of every slip in the y_slip loss (0: none)")
    ap.add_argument("--normalisation", default="rms", choices=["rms", "median"])
    ap.add_argument("--kind", default="jordan", choices=sorted(KINDS),
                    help="jordan: the paper's net; jordan_memory: the load-memory net; jordan_bank: the filter-bank net")
    ap.add_argument("--candidates", type=int, default=4, help="initial seeds trained (the best kept)")
    ap.add_argument("--cache", help="directory keeping the simulated scenes between builds")
    ap.add_argument("--extra-train", type=int, default=0,
                    help=f"extra training scenes from the held-out ranges (seed {EXTRA_TRAIN_SEED})")
    ap.add_argument("--checkpoint-every", type=int, default=25)
    ap.add_argument("--lp-taus", type=float, nargs="+", default=None,
                    help="low-pass time constants of the jordan_bank filter bank, s (default: the default bank's)")
    ap.add_argument("--abs-taus", type=float, nargs="*", default=None,
                    help="time constants of its shear-rate energy low-passes, s (none: no such channels)")
    ap.add_argument("--calibrate-fa", type=float, default=None, metavar="FA",
                    help="move y_slip's decision point to FA false alarms on the validation scenes (e.g. 0.02)")
    ap.add_argument("--calibrate-goals", type=float, nargs=2, default=None, metavar=("FA_CLEAN", "FA_NOISY"),
                    help="instead: the decision point that keeps the validation scenes within FA_CLEAN false alarms "
                         "noise-free and FA_NOISY with 1 mV rms white noise and with the thermal floor + 2 mV hum "
                         "(notched), e.g. 0.015 0.025")
    ap.add_argument("--calibrate-condition", nargs=2, action="append", default=None, metavar=("CONDITION", "FA"),
                    help="instead: the decision point for the named sensor condition(s) only (repeatable; one of "
                         "detector.evaluate.NOISE_CONDITIONS, e.g. '1 mV rms white' 0.025): a net for a sensor whose "
                         "noise is known, not bound by the other conditions' false alarms")
    ap.add_argument("--n-validation", type=int, default=120,
                    help=f"validation scenes (seed {VALIDATION_SEED}) for the choice among candidates and the calibration")
    ap.add_argument("--noise-range", type=float, nargs=2, default=list(NOISE_RANGE), metavar=("LOW", "HIGH"),
                    help="range of the training noise copies' sensor noise, V rms")
    ap.add_argument("--select-conditions", nargs="+", default=None, metavar="CONDITION",
                    help="choose among the candidates in these sensor conditions (detector.evaluate.NOISE_CONDITIONS, "
                         "e.g. 'noise-free' '1 mV rms white') instead of in the validation scenes' own noise")
    ap.add_argument("--select-fa", type=float, default=None, metavar="FA",
                    help="the false-alarm rate at which the candidates' detection is compared (default: the "
                         "calibration's)")
    ap.add_argument("--compress", action="store_true",
                    help="jordan_bank: compress the bank's inputs to sign(x) log(1 + |x| / knee), the knees fitted "
                         "on the training inputs")
    args = ap.parse_args(argv)
    for option, value in (("--negative-weight", args.negative_weight), ("--pred-weight", args.pred_weight),
                          ("--onset-weight", args.onset_weight)):
        try:  # (checked by the training itself only after the scenes were simulated)
            real_number(value, option, nonnegative=True)
        except ValueError as exc:
            ap.error(f"argument {exc}")
    bank = None
    if args.lp_taus is not None or args.abs_taus is not None:
        from tactile_mirror.detector.bank import DEFAULT_BANK

        bank = dict(DEFAULT_BANK)
        if args.lp_taus is not None:
            bank["lp_taus"] = list(args.lp_taus)
        if args.abs_taus is not None:
            bank["abs_taus"] = list(args.abs_taus)
    goals = None
    if args.calibrate_goals is not None and args.calibrate_condition:
        ap.error("--calibrate-goals and --calibrate-condition exclude each other")
    if args.calibrate_fa is not None and args.calibrate_condition:
        ap.error("--calibrate-fa and --calibrate-condition exclude each other")
    if args.calibrate_goals is not None:
        from tactile_mirror.lab.detector.evaluation import NOISE_CONDITIONS

        clean_fa, noisy_fa = args.calibrate_goals
        goals = {name: (clean_fa if name == "noise-free" else noisy_fa) for name in NOISE_CONDITIONS}
    if args.calibrate_condition:
        from tactile_mirror.lab.detector.evaluation import NOISE_CONDITIONS

        goals = {}
        for name, fa in args.calibrate_condition:
            if name not in NOISE_CONDITIONS:
                ap.error(f"--calibrate-condition: unknown condition {name!r}; known: {sorted(NOISE_CONDITIONS)}")
            if name in goals:
                ap.error(f"--calibrate-condition: {name!r} given twice")
            try:
                rate = float(fa)
            except ValueError:
                rate = float("nan")
            if not 0.0 <= rate < 1.0:
                ap.error(f"--calibrate-condition {name!r}: the false-alarm rate must be a number in [0, 1), got {fa!r}")
            goals[name] = rate
    if args.recalibrate is not None:
        if goals is None:
            ap.error("--recalibrate needs --calibrate-goals or --calibrate-condition")
        try:
            n_validation = _positive_int("n_validation", args.n_validation)
            n_test = _positive_int("n_test", args.n_test)
        except (TypeError, ValueError) as exc:
            _usage_error(ap, exc)
        _w, info = recalibrate(args.recalibrate, args.out, goals, n_validation, n_test, args.cache)
        print(json.dumps(info, indent=1))
        return
    try:
        options = BuildOptions(n_train=args.n_train, n_test=args.n_test, n_hidden=args.hidden, maxiter=args.maxiter,
                               bank=bank, study_sizes=args.study or None, kind=args.kind, candidates=args.candidates,
                               n_extra_train=args.extra_train, checkpoint_every=args.checkpoint_every,
                               noise_range=tuple(args.noise_range), calibrate_fa=args.calibrate_fa,
                               calibrate_conditions=goals, n_validation=args.n_validation, compress=args.compress,
                               select_conditions=args.select_conditions, select_fa=args.select_fa,
                               train_options={"negative_weight": args.negative_weight,
                                              "pred_weight": args.pred_weight, "normalisation": args.normalisation,
                                              **({"onset_weight": args.onset_weight} if args.onset_weight else {})})
    except (TypeError, ValueError) as exc:
        _usage_error(ap, exc)
    extra = {} if args.cache is None else {"cache_dir": args.cache}
    _w, report = build_default(args.out, options, report_path=args.report, figure_path=args.figure, **extra)
    print(report["evaluation_table"])
    if "hidden_size_study" in report:
        for row in report["hidden_size_study"]:
            print(row)


if __name__ == "__main__":
    main()
