"""Memory inputs of the load-memory detector: the load level and what the pad's other ridges do.

The paper's Jordan net reads four stress rates and remembers one number, its own
``y_pred``. A slip that starts with a release of stored shear is an event in those
rates; one that creeps in is not: the rates only settle, as in a stop at the same
load. What tells the two apart is state the rates do not carry at one instant:

``load`` (Pa)
    The ridge's shear load, the leaky integral of its shear rate ``v_L - v_R``
    (``load_t = a load_{t-1} + (v_L - v_R)_t / fs`` with ``a = exp(-1 / (fs tau))``).
    While the contact sticks it tracks the tangential load; when the ridge creeps
    into slip the load stalls at what the contact can carry, while a stop holds it
    wherever the finger stopped. The leak (``tau``) bounds the drift of the integrated
    estimator offset and noise.
``press`` (Pa)
    The same integral of ``v_L + v_R``: the normal load that sets what the contact
    carries.
``pad_rate`` (Pa/s), ``pad_load`` (Pa)
    The pad means over ridges of the shear rate and of ``load``. A stop stills every
    ridge at once, so a ridge's rate falling with the pad's is a stop; a creeping slip
    reaches the ridges one after another (in order of their normal load), so a ridge
    whose load stalls while the pad's still rises is slipping.

The net (the same Jordan kernel, ``jordan_mlp.hpp``) then reads the 8 channels
:data:`MEMORY_CHANNELS`. This module is the specification of the C++ feature stage
(``detector_memory.hpp``), which computes the same recurrence in the real-time path.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["DEFAULT_LOAD_TAU", "MEMORY_CHANNELS", "MEMORY_UNITS", "memory_features"]

#: Channels of the load-memory net's input, in order.
MEMORY_CHANNELS = ("v_L", "v_R", "u_L", "u_R", "load", "press", "pad_rate", "pad_load")
#: Units of :data:`MEMORY_CHANNELS` for stress-rate features.
MEMORY_UNITS = ("Pa/s", "Pa/s", "Pa/s^2", "Pa/s^2", "Pa", "Pa", "Pa/s", "Pa")
#: Leak time constant of the load integrals, s.
DEFAULT_LOAD_TAU = 0.5


def leak_factor(fs: float, tau: float) -> float:
    """``exp(-1 / (fs tau))``: the per-sample decay of the load integrals."""
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive number of Hz, got {fs!r}")
    if not (math.isfinite(tau) and tau > 0):
        raise ValueError(f"tau must be a positive number of seconds, got {tau!r}")
    return math.exp(-1.0 / (fs * tau))


def memory_features(x, fs: float, tau: float = DEFAULT_LOAD_TAU, state=None, return_state: bool = False):
    """The 8 memory-net channels from the 4 stress-rate channels of every ridge of a pad.

    Parameters
    ----------
    x : array_like, shape (n_ridges, 4, n)
        ``[v_L, v_R, u_L, u_R]`` of every ridge of one pad (Pa/s, Pa/s^2), time last.
    fs : float
        Sample rate, Hz.
    tau : float
        Leak time constant of the load integrals, s.
    state : array_like, shape (n_ridges, 2), optional
        ``[load, press]`` before the first sample (zero by default).
    return_state : bool
        Also return the state after the last sample.

    Returns
    -------
    ndarray, shape (n_ridges, 8, n), float64 (and the state, shape (n_ridges, 2))
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 3 or x.shape[1] != 4:
        raise ValueError(f"x must have shape (n_ridges, 4, n), got {x.shape}")
    a = leak_factor(float(fs), float(tau))
    n_r, _, n = x.shape
    s0 = np.zeros((n_r, 2)) if state is None else np.array(state, dtype=np.float64).reshape(n_r, 2)
    drive = np.stack([x[:, 0] - x[:, 1], x[:, 0] + x[:, 1]], axis=1) / float(fs)  # (n_r, 2, n)
    # y_t = a y_{t-1} + d_t, as a linear filter with initial condition a * s0.
    from scipy.signal import lfilter

    integ = lfilter([1.0], [1.0, -a], drive, axis=-1, zi=(a * s0)[..., None])[0]
    out = np.empty((n_r, 8, n))
    out[:, :4] = x
    out[:, 4:6] = integ
    out[:, 6] = (x[:, 0] - x[:, 1]).mean(axis=0)
    out[:, 7] = integ[:, 0].mean(axis=0)
    if return_state:
        end = integ[:, :, -1].copy() if n else s0
        return out, end
    return out
