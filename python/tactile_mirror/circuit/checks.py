"""The checks of what the PVDF circuit's functions take (shared by
:mod:`tactile_mirror.circuit`, :mod:`tactile_mirror.circuit.stream` and
:mod:`tactile_mirror.circuit.fit`): real finite arrays, strip stresses, noise levels.
"""
from __future__ import annotations

import math
import numbers

import numpy as np

__all__ = ["check_noise", "finite_array", "stress_array"]


def finite_array(x, name: str) -> np.ndarray:
    """``x`` as a float64 array of finite real numbers (bool and integers taken as
    numbers): TypeError for another dtype, ValueError for a NaN or Inf, naming ``name``."""
    a = np.asarray(x)
    if a.dtype.kind not in "biuf":
        raise TypeError(f"{name} must hold real numbers, got dtype {a.dtype}")
    a = a.astype(np.float64, copy=False)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (no NaN or Inf)")
    return a


def stress_array(stress) -> np.ndarray:
    """Strip stresses ``(..., 3, n)`` (``s1, s2, s3`` on axis -2, Pa) as a finite float64
    array; TypeError / ValueError naming ``stress``."""
    s = finite_array(stress, "stress")
    if s.ndim < 2 or s.shape[-2] != 3:
        raise ValueError(f"stress must have shape (..., 3, n) (s1, s2, s3 on axis -2), got {s.shape}")
    return s


def check_noise(noise) -> tuple[float, float]:
    """Sensor noise, V rms: one number for ``v_out`` and ``u_out`` or a pair
    ``(v_rms, u_rms)``, each real, finite and >= 0, as the pair."""
    vals = np.atleast_1d(np.asarray(noise, dtype=object))
    if vals.ndim != 1 or vals.size not in (1, 2):
        raise ValueError(f"noise must be a number or a pair (v_rms, u_rms), got {noise!r}")
    out = []
    for v in vals:
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise TypeError(f"noise must be real (V rms), got {noise!r}")
        v = float(v)
        if not math.isfinite(v) or v < 0:
            raise ValueError(f"noise must be finite and >= 0 (V rms), got {noise!r}")
        out.append(v)
    if len(out) == 1:
        out = out * 2
    return out[0], out[1]
