"""The input normalisation of a detector's net: zero mean and one scale per signal pair."""
from __future__ import annotations

import numpy as np

__all__ = ["fit_normalisation"]


def fit_normalisation(x, mask=None, method: str = "rms"):
    """Zero mean and one shared scale per signal pair.

    The L and R strips share a scale (and so do u_L, u_R), which keeps the
    mirror symmetry of the pad in the normalised inputs; channels after the
    first four (the load-memory inputs) get a scale each. The mean is zero: the
    features are signed rates (and their integrals) whose sign carries the slide
    direction.

    Parameters
    ----------
    method : {"median", "rms"}
        ``"median"``: median of ``|x|`` (robust: the 2nd-order rates are spikes
        on a quiet background, and an RMS scale set by the spikes would squeeze
        the background into a tiny range); ``"rms"``: root mean square.

    Returns
    -------
    input_mean, input_scale : ndarray, shape (n_inputs,)
    """
    x = np.asarray(x, dtype=np.float64)
    if mask is None:
        mask = np.ones((x.shape[0], x.shape[2]), dtype=bool)
    if method not in ("median", "rms"):
        raise ValueError(f"method must be 'median' or 'rms', got {method!r}")
    sel = np.moveaxis(x, 1, 0)[:, mask]  # (n_inputs, n_samples)
    groups = [[0, 1], [2, 3]] + [[k] for k in range(4, x.shape[1])]
    scale = np.ones(x.shape[1])
    for g in groups:
        v = sel[g].reshape(-1)
        scale[g] = np.median(np.abs(v)) if method == "median" else np.sqrt(np.mean(v ** 2))
    scale = np.where(scale > 0, scale, 1.0)
    return np.zeros(x.shape[1]), scale
