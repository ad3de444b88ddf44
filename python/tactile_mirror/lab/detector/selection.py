"""Choosing among trained candidates: the detector build's selection on validation scenes.

Training a recurrent net by L-BFGS-B from different initial weights ends in different
minima, and along one run the validation false alarms start to rise while the training
loss still falls. :func:`train_selected` trains a few seeds with checkpoints and keeps the
candidate :func:`select_candidate` finds best by a :class:`ValidationScorer`, on validation
scenes that are neither the training nor the held-out set. The scores can be stated in
named sensor conditions (:func:`condition_names`, :func:`condition_results`).

The training runs (one task per seed and hidden size) and the scoring of their candidates
(one task per run) are spread over workers by :func:`tactile_mirror.engine.run_tasks`
(``executor=`` / ``workers=``); the chosen net is bit-identical wherever they ran.
"""
from __future__ import annotations

import functools
import os
import time

import numpy as np

from tactile_mirror.checks import integer
from tactile_mirror.detector.core import SlipDetector
from tactile_mirror.engine import open_executor, run_tasks
from tactile_mirror.lab.detector.evaluation import evaluate
from tactile_mirror.lab.detector.training import train_detector

__all__ = [
    "ValidationScorer",
    "best_candidate",
    "check_false_alarm_rate",
    "condition_names",
    "condition_results",
    "select_candidate",
    "spread_executor",
    "task_threads",
    "train_selected",
    "train_selected_sizes",
]


def spread_executor(executor=None, workers: int | None = None):
    """The executor a job of several sweeps runs all of them on: ``executor`` itself if given,
    else for ``workers`` > 1 one local process pool for the whole job (started once, not per
    sweep; :func:`tactile_mirror.engine.open_executor`), else ``None`` (in this process).
    A context manager; a pool it started is shut down at the end.

    A worker process of that pool that dies fails the job (a pool shared by several sweeps
    is not restarted); a dask scheduler reschedules the tasks of a lost worker."""
    if executor is not None:
        if workers is not None:
            raise ValueError("give executor or workers, not both")
        import contextlib

        return contextlib.nullcontext(executor)
    return open_executor(None, workers)


def task_threads(train_options: dict, spread: bool) -> int:
    """The ``n_threads`` of the C++ training gradient each training task runs with, fixed by
    the driver: ``train_options["n_threads"]`` if given, else 1 where the runs are spread
    over workers (each worker a core) and ``min(2, os.cpu_count())`` in this process. The
    gradient sums its blocks in a fixed order, so the weights do not depend on it (1, 2 and
    3 threads are tested to give the same bits); only the speed does."""
    n = train_options.get("n_threads")
    if n is not None:
        return n
    return 1 if spread else min(2, os.cpu_count() or 1)


def _train_run(ts, maxiter: int, checkpoint_every: int, feedback: bool, metadata, progress: bool,
               train_options: dict, run: tuple) -> tuple[list, float]:
    """One training run, a task: ``run = (n_hidden, seed)``. Returns its candidates (the
    checkpoints every ``checkpoint_every`` iterations, if > 0, then the final weights) and
    the seconds it took."""
    n_hidden, seed = run
    t0 = time.perf_counter()
    got: list = []
    cb = (lambda it, wk: got.append(wk)) if checkpoint_every else None
    got.append(train_detector(ts, n_hidden=int(n_hidden), maxiter=maxiter, seed=seed, feedback=feedback,
                              progress=progress, metadata=metadata, callback=cb,
                              callback_every=checkpoint_every or 1, **train_options))
    return got, time.perf_counter() - t0


def _score_run(scorer, candidates: list) -> tuple[list, float]:
    """The scores of one run's candidates, a task; and the seconds they took."""
    t0 = time.perf_counter()
    return [scorer(w) for w in candidates], time.perf_counter() - t0


def train_selected_sizes(ts, sizes, maxiter: int, seed: int, candidates: int, checkpoint_every: int, scorer,
                         feedback: bool = True, progress: bool = True, metadata=None, *, executor=None,
                         workers: int | None = None, **train_options) -> list[tuple]:
    """:func:`train_selected` for each hidden size of ``sizes``, the runs of all sizes spread
    together: one training task per (size, seed), then one scoring task per run.

    ``executor`` (any :class:`concurrent.futures.Executor`: a process pool, dask's
    ``Client.get_executor()``, ...) or ``workers`` (N local processes) spread the tasks
    (:func:`tactile_mirror.engine.run_tasks`); neither runs them here, one after the other.
    Every task runs with its thread pools pinned and the C++ gradient's threads fixed by
    :func:`task_threads`; the candidates come back in (size, seed) order, so the kept
    weights are bit-identical wherever the tasks ran.

    Returns
    -------
    list of (weights, index of the kept candidate, candidate scores, seconds), one per size
        ``seconds``: the size's training and scoring tasks' own seconds, summed.
    """
    sizes = [int(h) for h in sizes]
    seeds = [seed + k for k in range(max(1, int(candidates)))]
    runs = [(h, s) for h in sizes for s in seeds]
    checkpoints = checkpoint_every if scorer is not None else 0
    with spread_executor(executor, workers) as ex:
        spread = ex is not None
        options = dict(train_options, n_threads=task_threads(train_options, spread))
        train = functools.partial(_train_run, ts, maxiter, checkpoints, feedback, metadata,
                                  progress and not spread, options)
        trained = run_tasks(train, runs, executor=ex, progress=progress, desc="train")
        scored = None
        if scorer is not None:
            scored = run_tasks(functools.partial(_score_run, scorer), [ws for ws, _ in trained], executor=ex,
                               progress=progress, desc="score")
    out = []
    for i in range(len(sizes)):
        k0, k1 = i * len(seeds), (i + 1) * len(seeds)
        ws = [w for run_ws, _ in trained[k0:k1] for w in run_ws]
        seconds = sum(t for _, t in trained[k0:k1])
        if scored is None:
            out.append((ws[-1], len(ws) - 1, [], seconds))
            continue
        scores = [sc for run_scores, _ in scored[k0:k1] for sc in run_scores]
        seconds += sum(t for _, t in scored[k0:k1])
        best = best_candidate(scores)
        out.append((ws[best], best, scores, seconds))
    return out


def train_selected(ts, n_hidden: int, maxiter: int, seed: int, candidates: int, checkpoint_every: int, scorer,
                   feedback: bool = True, progress: bool = True, metadata=None, *, executor=None,
                   workers: int | None = None, **train_options):
    """Train ``candidates`` seeds (``seed``, ``seed + 1``, ...) and keep the best on ``scorer``.

    With ``checkpoint_every`` > 0 the iterates every that many L-BFGS-B
    iterations are candidates too (early stopping). Without a scorer the last
    seed's final weights are returned.

    ``executor`` / ``workers``: where the training runs (one task per seed) and the
    scoring of their candidates (one task per run) go, as in :func:`train_selected_sizes`;
    the kept weights are the same bits wherever they ran.

    Returns
    -------
    weights, index of the kept candidate, list of candidate scores (empty without a scorer)
    """
    w, k, scores, _ = train_selected_sizes(ts, [n_hidden], maxiter, seed, candidates, checkpoint_every, scorer,
                                           feedback, progress, metadata, executor=executor, workers=workers,
                                           **train_options)[0]
    return w, k, scores


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
    :func:`~tactile_mirror.lab.detector.calibration.calibrate_slip` score in these copies."""
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
    point is calibrated afterwards (:func:`~tactile_mirror.lab.detector.calibration.calibrate_slip`),
    where what the threshold 0.8 of the uncalibrated net gives does not matter, only how far
    its curve reaches.

    ``conditions`` (with ``at_false_alarm``): names of sensor conditions
    (:data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`) in which to score instead of
    the scenes' own noise: their noise-free outputs plus each condition's noise (seeded by
    ``noise_seed`` + the condition's place in ``conditions``, as
    :func:`~tactile_mirror.lab.detector.calibration.calibrate_slip` seeds its own), the score
    the mean detection rate over them. The goals and the calibration are
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
            from tactile_mirror.lab.detector.thresholds import roc

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


def select_candidate(candidates, validation, fa_cost: float = 10.0, *, executor=None, workers: int | None = None):
    """The candidate weights with the best validation score, and every score.

    Training a recurrent net by L-BFGS-B from different initial weights ends in
    different minima (on this problem detection varied by 10 points and false
    alarms by 2-15 points between seeds), and along one run the training loss
    keeps falling after the validation false alarms have started to rise (nets
    run to 800 iterations raised 12-29 % false alarms where their own
    100-iteration checkpoints raised 1-5 %). So the build trains a few seeds,
    keeps checkpoints, and takes the candidate scoring best on a validation set
    that is neither the training nor the held-out set (:func:`best_candidate`).

    Parameters
    ----------
    candidates : sequence of DetectorWeights
    validation : ValidationScorer or sequence of simulation results
    executor, workers
        Score the candidates as tasks (one each) on this executor or on that many local
        processes (:func:`tactile_mirror.engine.run_tasks`); default here, one after the other.
        Each task receives the scorer, validation results included.
    """
    candidates = list(candidates)
    if not candidates:
        raise ValueError("candidates must not be empty")
    scorer = validation if isinstance(validation, ValidationScorer) else ValidationScorer(validation, fa_cost)
    scored = run_tasks(functools.partial(_score_run, scorer), [[w] for w in candidates], executor=executor,
                       workers=workers, progress=False, desc="score")
    scores = [run_scores[0] for run_scores, _ in scored]
    best = best_candidate(scores)
    return candidates[best], best, scores


def best_candidate(scores) -> int:
    """The index of the best of the candidates' validation ``scores`` (dicts of
    :class:`ValidationScorer`): the highest ``score`` (``detection_rate - fa_cost *
    false_alarm_rate``, or the detection at the calibration's false-alarm rate; a false
    alarm moves the stage for nothing, ``fa_cost`` = 10 prices one like ten misses), ties
    broken by fewer false-alarm samples, then by the longer y_pred lead, then by the
    earlier candidate."""
    scores = list(scores)
    if not scores:
        raise ValueError("scores must not be empty")
    return max(range(len(scores)), key=lambda i: (scores[i]["score"], -scores[i]["false_alarm_samples"],
                                                  scores[i]["pred_lead_mean_ms"]))


def check_false_alarm_rate(value, name: str) -> None:
    """Raise ValueError naming ``name`` unless ``value`` is a false-alarm rate: a number
    (not a bool) in [0, 1)."""
    if isinstance(value, bool) or not (isinstance(value, (int, float)) and 0 <= value < 1):
        raise ValueError(f"{name} must be a false-alarm rate in [0, 1), got {value!r}")
