"""Finger paths for the closed loop: seeded, band-limited, within a stage's limits.

Positions in m, speeds in m/s, accelerations in m/s^2, times in s, rates in Hz.
"""
from __future__ import annotations

import numpy as np

from tactile_mirror.checks import real_number

__all__ = ["finger_trajectory", "pressed_finger_path"]


def finger_trajectory(seed, duration: float, fs: float, amplitude: float = 3e-3, bandwidth: float = 1.0,
                      v_max: float = 0.015, a_max: float = 0.3, ramp: float = 0.3) -> np.ndarray:
    """A seeded band-limited random finger path, m, starting at rest at 0.

    White noise low-passed (4th-order Butterworth at ``bandwidth`` Hz, forward-backward),
    scaled to ``amplitude`` rms, faded in over ``ramp`` s, then scaled down if needed so
    that its speed and acceleration stay within ``v_max`` and ``a_max`` (a stage with those
    limits can follow it).
    """
    import scipy.signal

    fs = real_number(fs, "fs", unit="Hz", positive=True)
    duration = real_number(duration, "duration", unit="s", positive=True)
    # (a negative amplitude or limit mirrored the path; a zero ramp divided 0 by 0)
    for name, value in (("amplitude", amplitude), ("bandwidth", bandwidth), ("v_max", v_max), ("a_max", a_max),
                        ("ramp", ramp)):
        real_number(value, name, positive=True)
    n = round(duration * fs)
    if n < 2:
        raise ValueError(f"duration must last at least two samples at fs = {fs:g} Hz, got {duration!r} s")
    rng = np.random.default_rng(seed)
    pad = int(fs * 2)
    w = rng.standard_normal(n + 2 * pad)
    sos = scipy.signal.butter(4, bandwidth, fs=fs, output="sos")
    y = scipy.signal.sosfiltfilt(sos, w)[pad:pad + n]
    y = y / np.sqrt(np.mean(y**2)) * amplitude
    t = np.arange(n) / fs
    fade = np.clip(t / ramp, 0, 1)
    fade = fade * fade * (3 - 2 * fade)
    y = (y - y[0]) * fade
    v = np.gradient(y, 1 / fs)
    a = np.gradient(v, 1 / fs)
    s = min(1.0, v_max / max(np.abs(v).max(), 1e-12), a_max / max(np.abs(a).max(), 1e-12))
    return y * s


def pressed_finger_path(seed, duration: float, fs: float, press: float = 0.0, **trajectory) -> np.ndarray:
    """A finger path that rests for ``press`` s (while the finger presses in) and then
    follows :func:`finger_trajectory` for the remaining ``duration - press`` s, m.

    ``press = 0`` is :func:`finger_trajectory` itself. ``trajectory`` goes to it.
    """
    if press <= 0:
        return finger_trajectory(seed, duration, fs, **trajectory)
    if not duration > press:
        raise ValueError(f"duration must be longer than the press ({press:g} s), got {duration!r} s")
    n0 = round(press * fs)
    rest = finger_trajectory(seed, duration - press, fs, **trajectory)
    return np.concatenate([np.zeros(n0), rest])
