"""The hidden-size study of the detector build, and the training set's ridge subset.

:func:`hidden_size_study` trains a net per hidden size by the build's own procedure
(seeds, checkpoints, the best on validation scenes kept:
:func:`~tactile_mirror.lab.detector.selection.train_selected`), so sizes are compared at
their best; :func:`subset` keeps the first ridges of every scene of a training set.
"""
from __future__ import annotations

import numpy as np

from tactile_mirror.lab.detector.selection import ValidationScorer, train_selected_sizes
from tactile_mirror.lab.detector.training import TrainingSet

__all__ = ["hidden_size_study", "subset"]


def subset(ts: TrainingSet, ridges_per_scene: int, n_ridges: int) -> TrainingSet:
    """The training set ``ts`` with only the first ``ridges_per_scene`` of every ``n_ridges``
    sequences (the sequences in scene-major order: each scene's ridges one after the other).

    Returns a new :class:`~tactile_mirror.lab.detector.training.TrainingSet` (same rate,
    features and settings, fewer sequences).
    """
    keep = (np.arange(ts.n_seq) % n_ridges) < ridges_per_scene
    return TrainingSet(ts.x[keep], ts.y_slip[keep], ts.y_pred[keep], ts.mask[keep], ts.fs, ts.features,
                       ts.estimator, ts.targets, ts.load_tau, ts.bank)


def hidden_size_study(train, validation, sizes=(4, 8, 12, 16, 24), maxiter: int = 800, seed: int = 0,
                      candidates: int = 4, checkpoint_every: int = 25, progress: bool = True, *, executor=None,
                      workers: int | None = None, **train_options) -> list:
    """Train a detector per hidden size as the build does and score it on validation results.

    Each size gets the build's procedure (:func:`~tactile_mirror.lab.detector.selection.train_selected`:
    ``candidates`` seeds, checkpoints, the best on ``validation`` kept), so sizes are compared
    at their best rather than at one arbitrary iteration count. ``validation``
    must not be the held-out set the chosen size is reported on.

    ``executor`` (any :class:`concurrent.futures.Executor`, e.g. dask's
    ``Client.get_executor()``) or ``workers`` (N local processes) spread the training runs
    of all sizes together (one task per size and seed) and then the scoring of their
    candidates (one task per run): :func:`~tactile_mirror.lab.detector.selection.train_selected_sizes`.
    The rows are the same wherever the tasks ran, but for ``seconds``.

    Returns
    -------
    list of dict
        Per size: ``n_hidden``, ``seconds`` (its training and scoring tasks' own seconds,
        summed), ``iterations`` and ``seed`` of the kept candidate, and its validation
        detection rate, false-alarm rate, y_pred lead and score.
    """
    scorer = validation if isinstance(validation, ValidationScorer) else ValidationScorer(validation)
    kept = train_selected_sizes(train, sizes, maxiter, seed, candidates, checkpoint_every, scorer,
                                progress=progress, executor=executor, workers=workers, **train_options)
    return [{"n_hidden": int(h), "seconds": round(seconds, 1), "iterations": int(w.metadata["training"]["iterations"]),
             "seed": int(w.metadata["training"]["seed"]), **scores[k]}
            for h, (w, k, scores, seconds) in zip(sizes, kept)]
