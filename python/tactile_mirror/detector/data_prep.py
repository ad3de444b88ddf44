"""Features and training targets from simulation results.

Features (the detector's inputs) are ``[v_L, v_R, u_L, u_R]`` per ridge, shape
``(n_ridges, 4, n)``, time last, in one of two kinds (recorded in the weights):

``"stress_rate"`` (default)
    The stress-rate estimator's outputs (:func:`tactile_mirror.estimator.estimate_stress_rate`):
    stress rate in Pa/s (L, R) and 2nd-order stress rate in Pa/s^2 (L, R). The
    circuit is equalised away, so one set of weights serves pads whose PVDF
    circuits differ in component values. The estimator's settings are stored with
    the weights.
``"circuit"``
    The raw circuit voltages ``v_out``, ``u_out`` in V (as the paper's network).
    Cheaper, but tied to one circuit.

Targets (see :func:`targets_from_result`): ``y_slip`` is 1 while the ridge
slips grossly; ``y_pred`` is the extent of the ridge's slip zone (running
maximum of its slip fraction).
"""
from __future__ import annotations

import numpy as np

__all__ = ["DEFAULT_ESTIMATOR", "features_from_result", "targets_from_result"]

#: Estimator settings used for the ``"stress_rate"`` features (stored with the weights).
DEFAULT_ESTIMATOR = {"order": 2, "bandwidth": 100.0, "kind": "butter"}


def _circuit_of(result, circuit):
    if circuit is not None:
        return circuit
    c = getattr(result, "circuit", None)
    if c is None:
        c = getattr(getattr(result, "scene", None), "circuit", None)
    if c is not None:
        return c
    from ..circuit import PVDFCircuit

    return PVDFCircuit()


def features_from_result(result, features: str = "stress_rate", circuit=None, estimator=None) -> np.ndarray:
    """Detector features of one simulation result.

    Parameters
    ----------
    result
        A simulation result with ``fs`` and ``v_out``, ``u_out`` of shape
        (n_ridges, 2, n) [L, R strips]; or a record that carries ready
        ``features`` of shape (n_ridges, 4, n) (used as they are).
    features : {"stress_rate", "circuit"}
        Feature kind (see the module docstring).
    circuit : PVDFCircuit, optional
        Circuit for the estimator; default ``result.circuit``, ``result.scene.circuit``
        or ``PVDFCircuit()``.
    estimator : dict, optional
        Estimator settings; default :data:`DEFAULT_ESTIMATOR`.

    Returns
    -------
    ndarray, shape (n_ridges, 4, n), float64
    """
    ready = getattr(result, "features", None)
    if ready is not None:
        x = np.asarray(ready, dtype=np.float64)
        if x.ndim != 3 or x.shape[1] != 4:
            raise ValueError(f"result.features must have shape (n_ridges, 4, n), got {x.shape}")
        return x
    if features not in ("stress_rate", "circuit"):
        raise ValueError(f"features must be 'stress_rate' or 'circuit', got {features!r}")
    v = np.asarray(result.v_out, dtype=np.float64)
    u = np.asarray(result.u_out, dtype=np.float64)
    if v.ndim != 3 or v.shape[1] != 2:
        raise ValueError(f"result.v_out must have shape (n_ridges, 2, n), got {v.shape}")
    if u.shape != v.shape:
        raise ValueError(f"result.u_out must have the shape of v_out {v.shape}, got {u.shape}")
    if features == "stress_rate":
        from ..estimator import estimate_stress_rate

        est = dict(DEFAULT_ESTIMATOR if estimator is None else estimator)
        v, u = estimate_stress_rate(v, u, _circuit_of(result, circuit), float(result.fs), **est)
    return np.concatenate([v, u], axis=1)


def targets_from_result(result, gross_level: float = 0.999, pred_scale: float = 0.9):
    """Training targets of one result.

    ``y_slip`` = 1 while the ridge slips grossly: its slip fraction is at least
    ``gross_level`` (every contact node slides), or, for a result without a
    per-ridge slip fraction, from ``slip_time`` on.

    ``y_pred`` = ``pred_scale`` times the extent of the ridge's slip zone so far
    (the running maximum over time of its slip fraction), and 1 during gross slip.

    Why this target for ``y_pred``: it is the physical incipient-slip level.
    Local slip starts at the ridge edges and spreads inward as the tangential load
    approaches the friction limit (``c/a = sqrt(1 - Q/(mu P))``), so the slip
    zone grows before gross slip by an amount that measures how close the contact
    is to slipping, and it reaches 1 at gross slip. The strips see it: their
    stress rate grows as the zone spreads (paper Fig. 6). The running maximum
    makes the target hold while the plate stops: the instantaneous slip fraction
    drops to zero then (nothing moves, every node sticks) although the load, and
    so the risk of slip, is unchanged; holding is the paper's reading of
    ``y_pred`` ("a slip is likely to occur, but it does not actually occur").
    A binary "slip within the next d ms" target would instead need a horizon
    ``d`` that depends on the slide speed. (The scenes load monotonically; a
    scene that unloads would need a target that can fall.)

    Why ``pred_scale`` < 1: the slip zone covers 95-99 % of the contact for a
    long time before gross slip, so unscaled the feedback ``y_pred(t-1)`` would
    differ by ~1 % between "about to slip" and "slipping". The Jordan net's only
    memory is that feedback, and after the slip transient the strip signals are
    flat again (steady sliding), so ``y_slip`` must be held from it: with the
    scale, the feedback is <= 0.9 before and 1 during gross slip.

    Returns
    -------
    y_slip, y_pred : ndarray, shape (n_ridges, n), float64 in [0, 1]
    """
    frac = getattr(result, "slip_fraction", None)
    t = np.asarray(result.t, dtype=np.float64)
    if frac is not None:
        frac = np.clip(np.asarray(frac, dtype=np.float64), 0.0, 1.0)
        if frac.ndim == 1:
            frac = frac[None]
        y_slip = (frac >= gross_level).astype(np.float64)
        return y_slip, np.maximum(pred_scale * np.maximum.accumulate(frac, axis=-1), y_slip)
    st = getattr(result, "slip_time", None)
    n_r = np.asarray(result.v_out).shape[0]
    y_slip = np.zeros((n_r, t.size))
    if st is not None:
        y_slip[:, t >= st] = 1.0
    return y_slip, y_slip.copy()
