"""Augmenting training data: more sequences from the same simulations.

:func:`augment_noise` reruns simulation results through their circuit with fresh sensor
noise (before :func:`~tactile_mirror.lab.detector.training.make_training_set`);
:func:`augment_gains` scales a :class:`~tactile_mirror.lab.detector.training.TrainingSet`'s
sequences by random gains; :func:`compress_training_set` log-compresses its filter-bank
inputs (after any gains).
"""
from __future__ import annotations

import numpy as np

from tactile_mirror.checks import integer, real_range
from tactile_mirror.detector.bank import bank_config
from tactile_mirror.lab.detector.training import TrainingSet

__all__ = ["augment_gains", "augment_noise", "compress_training_set"]


def augment_noise(results, copies: int = 2, noise=(0.0, 5e-3), seed=0) -> list:
    """Copies of simulation results with fresh sensor noise on ``v_out`` and ``u_out``.

    Each copy reruns the result's strip stresses through its scene's circuit
    (:meth:`~tactile_mirror.circuit.PVDFCircuit.simulate`) with a noise level drawn
    uniformly from ``noise`` (V rms) and its own seed, so one simulated contact
    gives ``copies`` sequences that differ only in noise. The contact simulation is
    the expensive part; this is cheap. Deterministic for a seed.

    Parameters
    ----------
    results : iterable of SimulationResult
        With ``stress`` and ``scene`` (simulated with the "stress" output).
    copies : int
        Copies per result (>= 1).
    noise : (float, float)
        Range of the noise level, V rms: ``0 <= low <= high``, finite.

    Raises TypeError / ValueError naming ``copies`` or ``noise`` (a bool, a float or a
    string is no count of copies) before any result is read.
    """
    import dataclasses

    copies = integer(copies, "copies", 1)
    lo, hi = real_range(noise, "noise", unit="V rms", nonnegative=True)
    rng = np.random.default_rng(seed)
    out = []
    for k, r in enumerate(results):
        if getattr(r, "stress", None) is None or getattr(r, "scene", None) is None:
            raise ValueError(f"results[{k}] has no strip stresses: simulate with the 'stress' output")
        for _ in range(copies):
            level = float(rng.uniform(lo, hi))
            v, u = r.scene.circuit.simulate(r.stress, r.fs, noise=level, seed=int(rng.integers(2**31)))
            out.append(dataclasses.replace(r, v_out=v, u_out=u))
    return out


def augment_gains(ts: TrainingSet, gain_range=(0.6, 1.7), seed=0) -> TrainingSet:
    """Scale each sequence's features by a random gain (log-uniform in ``gain_range``).

    Stress rates scale with the loading speed and depth; the gains let a net
    trained on one range of scenes meet larger and smaller signals (the held-out
    scenes are drawn from wider ranges). Targets are unchanged. Deterministic for
    a seed.

    ``gain_range`` is a pair ``(low, high)`` of positive finite gains (dimensionless),
    ``low <= high``; anything else is a TypeError / ValueError naming it, as is a ``ts``
    that is not a :class:`TrainingSet`.
    """
    lo, hi = real_range(gain_range, "gain_range", positive=True)
    if not isinstance(ts, TrainingSet):
        raise TypeError(f"ts must be a TrainingSet, got {type(ts).__name__}")
    rng = np.random.default_rng(seed)
    g = np.exp(rng.uniform(np.log(lo), np.log(hi), ts.n_seq))
    return TrainingSet(ts.x * g[:, None, None], ts.y_slip, ts.y_pred, ts.mask, ts.fs, ts.features, ts.estimator,
                       {**ts.targets, "gain_range": [lo, hi], "gain_seed": int(seed)}, ts.load_tau, ts.bank)


def compress_training_set(ts: TrainingSet, knee=None) -> TrainingSet:
    """The filter-bank inputs of ``ts`` compressed (:func:`~.bank.log_compress`), their bank
    given the knees: a net trained on the result reads compressed inputs wherever it runs.

    ``knee`` (one per input) defaults to :func:`~.bank.fit_knees` of ``ts``'s real samples.
    Apply it after any gain augmentation (gains scale the rates, which the compression
    does not commute with). Padding stays zero.
    """
    from tactile_mirror.detector.bank import fit_knees, log_compress

    if ts.features != "stress_rate_bank":
        raise ValueError(f"only filter-bank inputs ('stress_rate_bank') are compressed, got {ts.features!r}")
    if ts.bank.get("knee") is not None:
        raise ValueError("ts is compressed already (its bank has knees)")
    knee = fit_knees(ts.x, ts.mask) if knee is None else np.asarray(knee, dtype=np.float64)
    bank = bank_config({**ts.bank, "knee": [float(k) for k in knee]})
    x = log_compress(ts.x, bank["knee"], axis=1) * ts.mask[:, None, :]
    return TrainingSet(x, ts.y_slip, ts.y_pred, ts.mask, ts.fs, ts.features, ts.estimator, ts.targets,
                       ts.load_tau, bank)
