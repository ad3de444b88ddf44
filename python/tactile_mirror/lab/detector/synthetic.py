"""A toy stick-slip generator with the qualitative shapes of the paper's signals.

For tests and quick experiments only (the shipped weights are trained on the
contact simulation). One sequence per ridge: a press phase, a slide at constant
speed with optional stops, incipient slip spreading from the ridge edges as the
tangential load ratio grows (Cattaneo-Mindlin: stick half-width
``c/a = sqrt(1 - Q / (mu P))``), then gross slip with a damped stick-slip
oscillation. The strip stresses are built from the normal and tangential loads;
their first and second time derivatives are the features ``[v_L, v_R, u_L, u_R]``
in Pa/s and Pa/s^2 (the ``"stress_rate"`` feature kind).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SyntheticResult", "synthetic_scene"]


@dataclass
class SyntheticResult:
    """Result-like record of a synthetic scene (fields as in the simulation result).

    ``features`` (n_ridges, 4, n) are already the detector inputs; ``slip_fraction``
    (n_ridges, n) in [0, 1]; ``slip_time`` in s or None; ``force_y``, ``force_z``
    (n,) in N; ``stops`` lists (start, end) of plate stops in s.
    """

    t: np.ndarray
    fs: float
    features: np.ndarray
    slip_fraction: np.ndarray
    slip_time: float | None
    force_y: np.ndarray
    force_z: np.ndarray
    stops: list = field(default_factory=list)


def synthetic_scene(seed=0, fs: float = 1000.0, duration: float = 2.0, n_ridges: int = 6,
                    stops=None, slide_speed: float | None = None, mu: float | None = None,
                    noise: float = 0.02, stop_before_slip: bool = False) -> SyntheticResult:
    """Generate one synthetic scene.

    Parameters
    ----------
    seed : int
        Seed of all random choices (speed, friction, stop times, noise).
    fs : float
        Sample rate, Hz.
    duration : float
        Length, s.
    n_ridges : int
        Number of ridges (sequences), each with its own small gain spread.
    stops : list of (float, float), optional
        Plate stops (start, end) in s; random (0 to 2 stops of 50 ms) if None.
    slide_speed, mu : float, optional
        Relative slide speed (1 = nominal) and friction coefficient; random if None.
    noise : float
        Sensor noise, relative to the typical rate magnitude.
    stop_before_slip : bool
        End the slide (plate held) just before gross slip: no slip in the scene.
    """
    rng = np.random.default_rng(seed)
    n = round(duration * fs)
    t = np.arange(n) / fs
    dt = 1.0 / fs
    speed = rng.uniform(0.6, 1.6) if slide_speed is None else float(slide_speed)
    mu_ = rng.uniform(0.6, 1.2) if mu is None else float(mu)
    t_press = 0.5
    if stops is None:
        stops = []
        for _ in range(rng.integers(0, 3)):
            s0 = rng.uniform(0.6, 1.6)
            stops.append((s0, s0 + 0.05))
    # Plate tangential travel (relative units) with stops.
    vel = np.where(t >= t_press, speed, 0.0)
    for a, b in stops:
        vel[(t >= a) & (t < b)] = 0.0
    y = np.cumsum(vel) * dt
    P = np.clip(t / t_press, 0.0, 1.0)  # normal load (relative)
    # Tangential load while stuck; gross slip when Q reaches mu P.
    Q_stick = 1.2 * y
    ratio = Q_stick / (mu_ * np.maximum(P, 1e-9))
    idx = np.flatnonzero(ratio >= 1.0)
    slip_i = int(idx[0]) if idx.size else None
    if stop_before_slip and slip_i is not None:
        hold = max(slip_i - int(0.03 * fs), 1)
        vel[hold:] = 0.0
        y = np.cumsum(vel) * dt
        Q_stick = 1.2 * y
        ratio = Q_stick / (mu_ * np.maximum(P, 1e-9))
        slip_i = None
    ratio = np.clip(ratio, 0.0, 1.0)
    frac = 1.0 - np.sqrt(1.0 - ratio)  # slipping fraction of the contact width
    Q = Q_stick.copy()
    if slip_i is not None:
        frac[slip_i:] = 1.0
        ts = t[slip_i:] - t[slip_i]
        f_osc = rng.uniform(25, 60)
        mu_k = 0.8 * mu_
        Q[slip_i:] = mu_k * P[slip_i:] + 0.25 * mu_ * np.exp(-ts / 0.05) * np.cos(2 * np.pi * f_osc * ts) \
            + 0.03 * mu_ * np.sin(2 * np.pi * 11.0 * ts + rng.uniform(0, 6))
    # Strip stresses (relative): shear tilts L and R oppositely; spreading slip adds
    # a term growing like frac^2 (the stress rate grows before slip).
    feats = np.empty((n_ridges, 4, n))
    sfrac = np.empty((n_ridges, n))
    for r in range(n_ridges):
        g = rng.uniform(0.8, 1.2)
        sL = -1.0 * P + g * (0.8 * Q + 0.6 * frac ** 2)
        sR = -1.0 * P - g * (0.6 * Q + 0.4 * frac ** 2)
        for k, s in enumerate((sL, sR)):
            rate = np.gradient(s, dt)
            rate2 = np.gradient(rate, dt)
            feats[r, k] = 1e5 * (rate + noise * 2.0 * rng.standard_normal(n))
            feats[r, 2 + k] = 1e5 * (rate2 + noise * 100.0 * rng.standard_normal(n))
        sfrac[r] = frac
    slip_time = None if slip_i is None else float(t[slip_i])
    fz = 2.0 * P
    fy = 2.0 * Q * 0.5 + 0.01 * rng.standard_normal(n)
    return SyntheticResult(t, float(fs), feats, sfrac, slip_time, fy, fz, list(stops))
