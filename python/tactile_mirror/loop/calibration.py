"""The shear calibration's fits: from a known relative displacement and what the sensors said.

A calibration moves the finger and the pad against each other by a known amount (in
simulation the finger, on a rig the stage under a resting finger, read by its encoder) while
the contact sticks, and fits:

* :func:`fit_shear_weights`: the weights of each ridge's L-R stress-rate difference in the
  controller's shear signal (``MirrorPipeline(shear_weights=...)``), by least squares of the
  integrated differences on the displacement;
* :func:`fit_shear_scale`: the direction sign and the size per metre of a shear signal (the
  weighted strips' integrated rate, or a load cell's force: then N/m, the contact's
  tangential stiffness), the ``calibration`` of :func:`~tactile_mirror.loop.design.design_loop`.

:func:`triangle_path` is the calibration's motion: slow triangle cycles of growing amplitude.
"""
from __future__ import annotations

import numpy as np

__all__ = ["band_pass", "fit_shear_scale", "fit_shear_weights", "triangle_path"]


def triangle_path(amplitudes, step: float) -> np.ndarray:
    """0, then one cycle ``+a, -a`` per amplitude ``a`` (m), back to 0; ``step`` m per tick."""
    path, x = [np.zeros(1)], 0.0
    for target in [s * a for a in amplitudes for s in (1.0, -1.0)] + [0.0]:
        n = max(1, round(abs(target - x) / step))
        path.append(np.linspace(x, target, n + 1)[1:])
        x = target
    return np.concatenate(path)


def band_pass(x, band, fs: float) -> np.ndarray:
    """``x`` through a zero-phase (forward-backward) 2nd-order Butterworth band-pass ``band``
    (Hz) at the rate ``fs``, along axis 0: the filter of the fits' ``band``."""
    import scipy.signal

    x = np.asarray(x, dtype=np.float64)
    lo, hi = (float(b) for b in band)
    if not 0 < lo < hi < fs / 2:
        raise ValueError(f"band must satisfy 0 < low < high < fs / 2 = {fs / 2:g} Hz, got {band!r}")
    sos = scipy.signal.butter(2, [lo, hi], "bandpass", fs=fs, output="sos")
    return scipy.signal.sosfiltfilt(sos, x, axis=0)


def fit_shear_weights(features, displacement, fs: float, start: int = 0, band=None,
                      symmetric: bool = False) -> np.ndarray:
    """Weights ``(c_r, -c_r)`` per ridge of the strips' stress rates in the controller's shear signal.

    Parameters
    ----------
    features : array_like, shape (n, n_ridges, 4)
        The pipeline's features per tick (``rate_L, rate_R, rate2_L, rate2_R``:
        ``MirrorPipeline.process_block(x, features=True)``).
    displacement : array_like, shape (n,)
        The relative displacement ``finger - pad`` at each tick, m, 0 at tick ``start``.
    fs : float
        Tick rate, Hz.
    start : int
        First tick of the calibration motion (the contact settled, the displacement 0).
    band : (float, float), optional
        Hz: fit the integrated differences and the displacement both through the same
        zero-phase band-pass (a linear filter on both sides keeps their relation): sensor
        noise integrates into a slow drift, and mains hum lies far above the motion; on a rig
        with noise, e.g. ``(0.3, 15)``. None (default): as they are.
    symmetric : bool
        Fit one weight per pair of ridges mirrored about the pad's middle (``r`` and
        ``n_ridges - 1 - r``), as a symmetric pad gives them: half the unknowns, so noise
        has fewer combinations to fit.

    Returns
    -------
    ndarray, shape (n_ridges, 2)
        ``c_r`` scaled to ``max |c_r| = 1``: the per-ridge L-R differences of the integrated
        rate estimates fitted, by least squares, to the displacement from ``start`` on (so a
        change of the normal load, common to L and R, stays out of the shear signal).
    """
    feats = np.asarray(features, dtype=np.float64)
    d = np.asarray(displacement, dtype=np.float64)
    if feats.ndim != 3 or feats.shape[2] < 2 or d.shape != (feats.shape[0],):
        raise ValueError(f"features must have shape (n, n_ridges, 4) and displacement (n,), got {feats.shape} and "
                         f"{d.shape}")
    if not 0 <= start < d.size - 1:
        raise ValueError(f"start must leave at least two ticks of the {d.size}, got {start!r}")
    diff = np.cumsum(feats[:, :, 0] - feats[:, :, 1], axis=0) / fs  # integrated L-R rate per ridge
    if band is not None:
        diff, d = band_pass(diff, band, fs), band_pass(d, band, fs)
    diff = diff[start:] - diff[start]
    R = diff.shape[1]
    if symmetric:
        pairs = [(r, R - 1 - r) for r in range((R + 1) // 2)]
        m = np.stack([diff[:, a] + (diff[:, b] if b != a else 0.0) for a, b in pairs], axis=1)
        h = np.linalg.lstsq(m, d[start:], rcond=None)[0]
        c = np.empty(R)
        for (a, b), v in zip(pairs, h):
            c[a] = c[b] = v
    else:
        c = np.linalg.lstsq(diff, d[start:], rcond=None)[0]
    peak = np.max(np.abs(c))
    if not (np.isfinite(peak) and peak > 0):
        raise ValueError("the strips' rates do not follow the displacement (no fit): did the stage move, does "
                         "the finger touch the pad?")
    c = c / peak
    return np.stack([c, -c], axis=1)


def fit_shear_scale(signal, displacement, band=None, fs: float | None = None) -> tuple[float, float]:
    """``(direction_sign, size per metre)`` of a shear signal against the displacement.

    ``signal`` (the controller's shear signal integrated: the weighted strips' rate times
    the tick, or a load cell's force, N) and ``displacement`` (m) are taken from the same
    ticks, each relative to its value at the first; the slope of their least-squares line
    through 0 gives the sign (+1: the signal grows with ``finger - pad``) and the size
    (per metre; N/m for a force). ``band`` (Hz, with the tick rate ``fs``): both through the
    same band-pass first (see :func:`fit_shear_weights`). Raises ValueError if the
    displacement did not move or the slope is 0.
    """
    s = np.asarray(signal, dtype=np.float64)
    d = np.asarray(displacement, dtype=np.float64)
    if s.shape != d.shape or s.ndim != 1 or s.size < 2:
        raise ValueError(f"signal and displacement must be 1-D of equal length >= 2, got {s.shape} and {d.shape}")
    if band is not None:
        if fs is None:
            raise ValueError("band needs the tick rate fs")
        s, d = band_pass(s, band, fs), band_pass(d, band, fs)
    s = s - s[0]
    d = d - d[0]
    dd = float(d @ d)
    if not dd > 0:
        raise ValueError("the displacement did not change: nothing to calibrate on")
    k = float(s @ d) / dd
    if not (np.isfinite(k) and k != 0):
        raise ValueError(f"the shear signal does not follow the displacement (slope {k!r})")
    return (1.0 if k > 0 else -1.0), abs(k)
