"""Helpers of the benchmark scripts (run as ``python bench/<script>.py``; imported by them as
``from common import ...``, the scripts' folder being on ``sys.path``).

The measuring functions themselves live in :mod:`tactile_mirror.lab.measure`, shared with
``tactile-mirror bench``; this module names them for the scripts, prints, writes the scripts'
files, and gives the detector studies their scene sets, training set and classifier.

``--quick`` runs of the detector studies simulate a few scenes in this process
(:func:`quick_results`, kept for the life of the process: several studies run in one
process share them) instead of the build's cached sets, which a process pool simulates.

The studies take ``--scheduler ADDRESS`` (a dask scheduler) or ``--workers N``
(``tactile_mirror.cli.arguments.add_workers_options``, as the command line): their scene sets
and training runs then go to those workers (the same results; docs/cluster.md).
"""
from __future__ import annotations

import json
import os
import tempfile

from tactile_mirror.lab.measure import best_time, best_times, environment_line, markdown_table, timed

__all__ = ["BOUND_TREES", "QUICK_TREES", "bank_training_set", "bank_validation_conditions", "best_time",
           "best_times", "environment_line", "fit_bound_classifier", "header", "on", "quick_results", "save_figure",
           "simulated", "study_scenes", "study_training_scenes", "table", "timed", "write_json", "write_pickle",
           "write_text"]

#: Boosting iterations of the bound study's classifier, and of a ``--quick`` run's.
BOUND_TREES = 300
QUICK_TREES = 20


def table(title: str, header, rows) -> None:
    """Print a markdown table under a heading."""
    print(markdown_table(title, header, rows))


def header(what: str) -> None:
    """Print what is measured and where (versions, SIMD path, CPU model, threads)."""
    print(f"# {what}\n# {environment_line()}")


# ---------------------------------------------------------------- files
def _replace_atomically(path, write, mode: str) -> None:
    """``write(file)`` into a temporary file beside ``path``, then moved over it: an
    interrupted run leaves the previous file as it was."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=os.path.basename(path) + ".", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, mode, **({"encoding": "utf-8"} if "b" not in mode else {})) as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text(path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path``, atomically."""
    _replace_atomically(path, lambda fh: fh.write(text), "w")


def write_json(path, value, **dumps_kwargs) -> None:
    """Write ``json.dumps(value, **dumps_kwargs)`` and a newline to ``path``, atomically."""
    write_text(path, json.dumps(value, **dumps_kwargs) + "\n")


def write_pickle(path, value) -> None:
    """Pickle ``value`` (the highest protocol) to ``path``, atomically."""
    import pickle

    _replace_atomically(path, lambda fh: pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL), "wb")


def save_figure(fig, path, **savefig_kwargs) -> None:
    """``fig.savefig`` to ``path``, atomically; the format from the suffix (or ``format=``)."""
    suffix = os.path.splitext(os.fspath(path))[1].lstrip(".").lower()
    fmt = savefig_kwargs.pop("format", None) or suffix or None
    _replace_atomically(path, lambda fh: fig.savefig(fh, format=fmt, **savefig_kwargs), "wb")


# ---------------------------------------------------------------- the detector studies
def fit_bound_classifier(X, Y, seed: int = 0, max_iter: int = BOUND_TREES):
    """The bound study's classifier (``detector_bound.py``), fitted: scikit-learn's
    ``HistGradientBoostingClassifier`` (``max_iter`` iterations, 300 in the studies) on inputs
    ``X`` (n_samples, n_inputs) and gross-slip targets ``Y``, the classes balanced and a
    no-slip sample weighted ten times a slip sample (a false alarm costs more than a late
    detection)."""
    import numpy as np
    from sklearn.ensemble import HistGradientBoostingClassifier

    w = np.where(Y > 0.5, 0.5 / max(Y.sum(), 1.0), 5.0 / max(Y.size - Y.sum(), 1.0)) * Y.size
    return HistGradientBoostingClassifier(max_iter=max_iter, random_state=seed).fit(X, Y, sample_weight=w)


def on(executor) -> dict:
    """``{"executor": executor}`` for a lab function's keyword, or ``{}`` for None (this process)."""
    return {} if executor is None else {"executor": executor}


_QUICK_RESULTS: dict = {}


def quick_results(n: int, seed: int, kwargs: dict) -> list:
    """``simulate`` of ``scenes.random(n, seed=seed, **kwargs)``, one scene after the other in
    this process (a few scenes: no process pool, no cache file), kept for later calls with
    the same arguments. For ``--quick`` runs."""
    key = (n, seed, repr(sorted(kwargs.items())))
    if key not in _QUICK_RESULTS:
        from tactile_mirror import scenes
        from tactile_mirror.contact import simulate

        _QUICK_RESULTS[key] = [simulate(s) for s in scenes.random(n, seed=seed, **kwargs)]
    return list(_QUICK_RESULTS[key])


def simulated(n: int, seed: int, kwargs: dict, cache=None, progress: bool = True,
              quick: bool = False, executor=None) -> list:
    """The results of ``scenes.random(n, seed=seed, **kwargs)``: the build's
    ``simulate_cached`` (kept in ``cache``; on ``executor`` if given), or with ``quick``
    :func:`quick_results`."""
    if quick:
        return quick_results(n, seed, kwargs)
    from tactile_mirror.lab.detector import scene_cache

    return scene_cache.simulate_cached(n, seed, kwargs, cache, progress, **on(executor))


def study_training_scenes(cache, extra: int, progress: bool = True, n_train: int = 64,
                          quick: bool = False, executor=None) -> list:
    """The detector studies' training scenes: the build's ``n_train`` (64) training scenes and
    ``extra`` scenes drawn from the held-out ranges with ``build_options.EXTRA_TRAIN_SEED`` (cached in
    ``cache``, simulated on ``executor`` if given; with ``quick`` simulated here, :func:`quick_results`)."""
    from tactile_mirror.lab.detector import build_options

    train = simulated(n_train, build_options.TRAIN_SEED, build_options.TRAIN_KWARGS, cache, progress, quick, executor)
    if extra:
        train = train + simulated(extra, build_options.EXTRA_TRAIN_SEED, build_options.TEST_KWARGS, cache, progress,
                                  quick, executor)
    return train


def bank_training_set(train):
    """The detector studies' training set of the filter-bank net: the build's recipe (two noise
    copies of every scene, ``build_options.NOISE_RANGE``, then random gains 0.6-1.7)."""
    from tactile_mirror.lab.detector import build_options
    from tactile_mirror.lab.detector.augment import augment_gains, augment_noise
    from tactile_mirror.lab.detector.training import make_training_set

    seqs = augment_noise(train, build_options.NOISE_COPIES, build_options.NOISE_RANGE, seed=2)
    return augment_gains(make_training_set(seqs, "stress_rate_bank"), (0.6, 1.7), seed=1)


def bank_validation_conditions(results, estimator) -> dict:
    """``{"noise-free" | "1 mV rms": (bank features, results, onset kinds)}`` of validation
    scenes: their own noise removed, and 1 mV rms of white noise added (seed 4001)."""
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector.evaluation import noise_free, onset_kinds, with_noise

    clean = noise_free(results)
    noisy = with_noise(clean, "1 mV rms white", seed=4001)
    kinds = onset_kinds(results)
    return {name: ([features_from_result(r, "stress_rate_bank", estimator=estimator) for r in rr], rr, kinds)
            for name, rr in (("noise-free", clean), ("1 mV rms", noisy))}


def study_scenes(cache, extra: int, n_validation: int, n_train: int = 64,
                 quick: bool = False, executor=None) -> tuple[list, list]:
    """The detector studies' training scenes (:func:`study_training_scenes`) and the build's
    first ``n_validation`` validation scenes (``build_options.VALIDATION_SEED``), cached in ``cache``
    (simulated on ``executor`` if given; with ``quick`` simulated here)."""
    from tactile_mirror.lab.detector import build_options

    train = study_training_scenes(cache, extra, n_train=n_train, quick=quick, executor=executor)
    return train, simulated(n_validation, build_options.VALIDATION_SEED, build_options.TEST_KWARGS, cache,
                            quick=quick, executor=executor)
