"""Signals with known answers, for tests and benchmarks.

:func:`known_load` is a strip load whose first and second time derivatives are known
in closed form: run it through :meth:`tactile_mirror.PVDFCircuit.simulate` and the
stress-rate estimator should give those derivatives back.
"""
from __future__ import annotations

import numpy as np

__all__ = ["known_load"]


def known_load(t, transients: bool = True):
    """A load with analytic 1st and 2nd derivatives.

    Quintic loading (-40 kPa over 0.05-0.5 s), a 20 kPa/s ramp from 0.5 s with
    rounded corners, and with ``transients`` a 50 ms stop at 1.0 s and a slip at
    1.5 s (the ramp ends, a 10 ms drop of 8 kPa, a 20 ms rebound of 3 kPa); without
    them the ramp ends at 0.9 s with a 20 ms corner. Every part is smooth, so the
    derivatives hold at any sample rate.

    Parameters
    ----------
    t : array_like
        Times, s (2 s covers the whole load).
    transients : bool
        Include the stop and the slip (default).

    Returns
    -------
    load, rate, rate2 : ndarray
        Pa, Pa/s and Pa/s^2, each of the shape of ``t``.
    """
    t = np.asarray(t, dtype=np.float64)
    s = np.zeros_like(t)
    d = np.zeros_like(t)
    d2 = np.zeros_like(t)

    def load(a, t0, span):
        x = np.clip((t - t0) / span, 0, 1)
        return (a * x**3 * (10 - 15 * x + 6 * x**2), a / span * 30 * x**2 * (1 - x) ** 2,
                a / span**2 * 60 * x * (1 - x) * (1 - 2 * x))

    def ramp(a, t0, w):
        x = (t - t0) / w
        sg = 0.5 * (1 + np.tanh(x / 2))
        return a * w * np.logaddexp(0, x), a * sg, a / w * sg * (1 - sg)

    def step(a, t0, w):
        th = np.tanh((t - t0) / w)
        se = 1 - th**2
        return a / 2 * (1 + th), a / (2 * w) * se, -a / w**2 * se * th

    parts = [(load, (-40e3, 0.05, 0.45))]
    if transients:
        parts += [(ramp, (20e3, 0.5, 0.01)), (ramp, (-20e3, 1.0, 0.005)), (ramp, (20e3, 1.05, 0.005)),
                  (ramp, (-20e3, 1.5, 0.01)), (step, (-8e3, 1.5, 0.01)), (step, (3e3, 1.53, 0.02))]
    else:
        parts += [(ramp, (20e3, 0.5, 0.02)), (ramp, (-20e3, 0.9, 0.02))]
    for f, args in parts:
        a, b, c = f(*args)
        s += a
        d += b
        d2 += c
    return s, d, d2
