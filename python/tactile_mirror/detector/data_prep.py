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
slips grossly; ``y_pred`` is the tangential load as a share of what the sliding
contact carries (``|F_y| / (mu_k F_z)``), scaled, and 1 in gross slip.
"""
from __future__ import annotations

import numpy as np

from tactile_mirror.checks import real_number

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
    from tactile_mirror.circuit import PVDFCircuit

    return PVDFCircuit()


def features_from_result(result, features: str = "stress_rate", circuit=None, estimator=None,
                         load_tau: float | None = None, bank: dict | None = None) -> np.ndarray:
    """Detector features of one simulation result.

    Parameters
    ----------
    result
        A simulation result with ``fs`` and ``v_out``, ``u_out`` of shape
        (n_ridges, 2, n) [L, R strips]; or a record that carries ready
        ``features`` of shape (n_ridges, 4, n) (used as they are).
    features : {"stress_rate", "circuit", "stress_rate_memory", "stress_rate_bank"}
        Feature kind (see the module docstring). ``"stress_rate_memory"``: the
        stress rates and the load-memory channels of
        :func:`~tactile_mirror.detector.memory.memory_features` (8 channels);
        ``"stress_rate_bank"``: the stress rates and the filter-bank channels of
        :func:`~tactile_mirror.detector.bank.bank_features`.
    circuit : PVDFCircuit, optional
        Circuit for the estimator; default ``result.circuit``, ``result.scene.circuit``
        or ``PVDFCircuit()``.
    estimator : dict, optional
        Estimator settings; default :data:`DEFAULT_ESTIMATOR`.
    load_tau : float, optional
        Leak time constant of the load integrals (``"stress_rate_memory"``), s;
        default :data:`~tactile_mirror.detector.memory.DEFAULT_LOAD_TAU`.
    bank : dict, optional
        Time constants of the filter bank (``"stress_rate_bank"``); default
        :data:`~tactile_mirror.detector.bank.DEFAULT_BANK`.

    Returns
    -------
    ndarray, shape (n_ridges, 4, n) (8 channels for ``"stress_rate_memory"``), float64
    """
    if features not in ("stress_rate", "circuit", "stress_rate_memory", "stress_rate_bank"):
        raise ValueError(f"features must be 'stress_rate', 'circuit', 'stress_rate_memory' or 'stress_rate_bank', "
                         f"got {features!r}")
    ready = getattr(result, "features", None)
    if ready is not None:
        x = np.asarray(ready, dtype=np.float64)
        if x.ndim != 3 or x.shape[1] != 4:
            raise ValueError(f"result.features must have shape (n_ridges, 4, n), got {x.shape}")
        if features == "stress_rate_memory":
            from tactile_mirror.detector.memory import DEFAULT_LOAD_TAU, memory_features

            return memory_features(x, float(result.fs), DEFAULT_LOAD_TAU if load_tau is None else load_tau)
        if features == "stress_rate_bank":
            from tactile_mirror.detector.bank import bank_features

            return bank_features(x, float(result.fs), bank)
        return x
    v = np.asarray(result.v_out, dtype=np.float64)
    u = np.asarray(result.u_out, dtype=np.float64)
    if v.ndim != 3 or v.shape[1] != 2:
        raise ValueError(f"result.v_out must have shape (n_ridges, 2, n), got {v.shape}")
    if u.shape != v.shape:
        raise ValueError(f"result.u_out must have the shape of v_out {v.shape}, got {u.shape}")
    if features != "circuit":
        from tactile_mirror.estimator import estimate_stress_rate

        est = dict(DEFAULT_ESTIMATOR if estimator is None else estimator)
        v, u = estimate_stress_rate(v, u, _circuit_of(result, circuit), float(result.fs), **est)
    x = np.concatenate([v, u], axis=1)
    if features == "stress_rate_memory":
        from tactile_mirror.detector.memory import DEFAULT_LOAD_TAU, memory_features

        x = memory_features(x, float(result.fs), DEFAULT_LOAD_TAU if load_tau is None else load_tau)
    elif features == "stress_rate_bank":
        from tactile_mirror.detector.bank import bank_features

        x = bank_features(x, float(result.fs), bank)
    return x


def targets_from_result(result, gross_level: float = 0.999, pred_scale: float = 0.8,
                        pred_target: str = "load_ratio", min_fz_fraction: float = 0.05):
    """Training targets of one result.

    ``y_slip`` = 1 while the ridge slips grossly: its slip fraction is at least
    ``gross_level`` (every contact node slides), or, for a result without a
    per-ridge slip fraction, from ``slip_time`` on.

    ``y_pred`` (``pred_target``), and 1 during gross slip:

    ``"load_ratio"`` (default)
        ``pred_scale * clip(|F_y| / (mu_k F_z), 0, 1)``: the tangential load as a
        share of what the contact carries once it slides (``mu_k`` = kinetic
        friction = ``scene.friction * scene.kinetic_ratio``). It is 0 while the finger
        only presses, grows as the finger pulls, holds through a stop (the load is
        held) and reaches ``pred_scale`` when gross slip starts; the pad-level force
        ratio serves every ridge of a pad. It is what "slip is coming" means, and the
        strips see it: the L-R stress rate is the rate of the ridge's bending, i.e.
        of the tangential load, so the Jordan feedback can integrate it. Samples with
        ``F_z`` below ``min_fz_fraction`` of its peak count as unloaded (0).
    ``"slip_zone"``
        ``pred_scale`` times the extent of the ridge's slip zone so far (the running
        maximum of its slip fraction). With static above kinetic friction the press
        alone makes the ridge edges slide (Poisson expansion under the normal load:
        slip fractions of 0.3-0.6 with no tangential load at all), so this target
        tells the net that slip is coming at the end of every press; nets trained on
        it raised false alarms there (22 of 33 false alarms of the previous bundled
        detector on the held-out set were within 50 ms of the end of the press).

    Why ``pred_scale`` < 1: the feedback ``y_pred(t-1)`` must differ between "about to
    slip" (at most ``pred_scale``) and "slipping" (1): it is the Jordan net's only
    memory, and in steady sliding the strip signals are flat again, so ``y_slip``
    must be held from it.

    Returns
    -------
    y_slip, y_pred : ndarray, shape (n_ridges, n), float64 in [0, 1]
    """
    if pred_target not in ("load_ratio", "slip_zone"):
        raise ValueError(f"pred_target must be 'load_ratio' or 'slip_zone', got {pred_target!r}")
    # (gross_level 2 or NaN made a target that never slips: a detector trained on it never alarms)
    if not 0 < real_number(gross_level, "gross_level") <= 1:
        raise ValueError(f"gross_level must be in (0, 1] (a share of the contact), got {gross_level!r}")
    if not 0 < real_number(pred_scale, "pred_scale") <= 1:
        raise ValueError(f"pred_scale must be in (0, 1], got {pred_scale!r}")
    frac = getattr(result, "slip_fraction", None)
    t = np.asarray(result.t, dtype=np.float64)
    if frac is None:
        st = getattr(result, "slip_time", None)
        n_r = np.asarray(result.v_out).shape[0]
        y_slip = np.zeros((n_r, t.size))
        if st is not None:
            y_slip[:, t >= st] = 1.0
        return y_slip, y_slip.copy()
    frac = np.clip(np.asarray(frac, dtype=np.float64), 0.0, 1.0)
    if frac.ndim == 1:
        frac = frac[None]
    y_slip = (frac >= gross_level).astype(np.float64)
    ratio = _load_ratio(result, frac.shape, min_fz_fraction) if pred_target == "load_ratio" else None
    if ratio is None:
        level = np.maximum.accumulate(frac, axis=-1)
    else:
        level = ratio
    return y_slip, np.maximum(pred_scale * level, y_slip)


def _load_ratio(result, shape, min_fz_fraction):
    """``clip(|F_y| / (mu_k F_z), 0, 1)`` broadcast to ``shape``; None without forces or friction."""
    fy, fz = getattr(result, "force_y", None), getattr(result, "force_z", None)
    scene = getattr(result, "scene", None)
    mu = getattr(scene, "friction", None)
    if fy is None or fz is None or mu is None:
        return None
    mu_k = float(mu) * float(getattr(scene, "kinetic_ratio", 1.0))
    fy = np.abs(np.asarray(fy, dtype=np.float64))
    fz = np.abs(np.asarray(fz, dtype=np.float64))
    peak = fz.max() if fz.size else 0.0
    ok = fz > min_fz_fraction * peak
    r = np.where(ok, fy / (mu_k * np.where(ok, fz, 1.0)), 0.0)
    return np.broadcast_to(np.clip(r, 0.0, 1.0), shape)
