"""Helpers of the benchmark scripts (run as ``python bench/<script>.py``).

The measuring functions themselves live in :mod:`tactile_mirror.lab.measure`, shared with
``tactile-mirror bench``; this module only names them for the scripts and prints.
"""
from __future__ import annotations

from tactile_mirror.lab.measure import best_time, best_times, environment_line, markdown_table, timed

__all__ = ["best_time", "best_times", "environment_line", "fit_bound_classifier", "header", "study_training_scenes",
           "table", "timed"]


def table(title: str, header, rows) -> None:
    """Print a markdown table under a heading."""
    print(markdown_table(title, header, rows))


def header(what: str) -> None:
    """Print what is measured and where (versions, SIMD path, CPU model, threads)."""
    print(f"# {what}\n# {environment_line()}")


def fit_bound_classifier(X, Y, seed: int = 0):
    """The bound study's classifier (``detector_bound.py``), fitted: scikit-learn's
    ``HistGradientBoostingClassifier`` (300 iterations) on inputs ``X`` (n_samples, n_inputs)
    and gross-slip targets ``Y``, the classes balanced and a no-slip sample weighted ten
    times a slip sample (a false alarm costs more than a late detection)."""
    import numpy as np
    from sklearn.ensemble import HistGradientBoostingClassifier

    w = np.where(Y > 0.5, 0.5 / max(Y.sum(), 1.0), 5.0 / max(Y.size - Y.sum(), 1.0)) * Y.size
    return HistGradientBoostingClassifier(max_iter=300, random_state=seed).fit(X, Y, sample_weight=w)


def study_training_scenes(cache, extra: int, progress: bool = True) -> list:
    """The detector studies' training scenes: the build's 64 training scenes and ``extra``
    scenes drawn from the held-out ranges with ``build.EXTRA_TRAIN_SEED`` (cached in ``cache``)."""
    from tactile_mirror.lab.detector import build

    train = build.simulate_cached(64, build.TRAIN_SEED, build.TRAIN_KWARGS, cache, progress)
    if extra:
        train = train + build.simulate_cached(extra, build.EXTRA_TRAIN_SEED, build.TEST_KWARGS, cache, progress)
    return train


def bank_training_set(train):
    """The detector studies' training set of the filter-bank net: the build's recipe (two noise
    copies of every scene, ``build.NOISE_RANGE``, then random gains 0.6-1.7)."""
    from tactile_mirror.lab.detector import build
    from tactile_mirror.lab.detector.training import augment_gains, augment_noise, make_training_set

    seqs = augment_noise(train, build.NOISE_COPIES, build.NOISE_RANGE, seed=2)
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


def study_scenes(cache, extra: int, n_validation: int) -> tuple[list, list]:
    """The detector studies' training scenes (:func:`study_training_scenes`) and the build's
    first ``n_validation`` validation scenes (``build.VALIDATION_SEED``), cached in ``cache``."""
    from tactile_mirror.lab.detector import build

    train = study_training_scenes(cache, extra)
    return train, build.simulate_cached(n_validation, build.VALIDATION_SEED, build.TEST_KWARGS, cache)
