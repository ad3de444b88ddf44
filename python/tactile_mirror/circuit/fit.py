"""Identifying the PVDF circuit's components from a measured gain curve:
:func:`fit_circuit` (:func:`scipy.optimize.least_squares` over their logarithms).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from tactile_mirror.circuit.checks import finite_array
from tactile_mirror.circuit.pvdf import PVDFCircuit

__all__ = ["fit_circuit"]

_FIT_FIELDS = ("Rf", "Cf", "Rd", "Rs")


def fit_circuit(freqs: npt.ArrayLike, gain_v_db: npt.ArrayLike, gain_u_db: npt.ArrayLike | None = None,
                initial: PVDFCircuit | None = None) -> PVDFCircuit:
    """Identify the circuit components from a measured gain curve (paper Eq. 1).

    The gain curves fix only products of components: ``v_out`` gives ``q Rf``
    and ``Rf Cf``; ``u_out`` adds ``Rd Cd`` and ``Rs Cd``. The fit therefore
    adjusts ``Rf, Cf`` (and ``Rd, Rs`` when ``gain_u_db`` is given) and keeps the
    strip, the piezoelectric coefficients, the load and ``Cd`` at their values in
    ``initial``. It minimises the dB residuals with
    :func:`scipy.optimize.least_squares` over the logarithms of the components.
    The corners are identified when the frequencies span them (for the
    defaults, e.g. 0.1 Hz - 10 kHz: a bench sweep of the analog circuit).

    Parameters
    ----------
    freqs : array_like, shape (m,)
        Measurement frequencies, Hz, > 0.
    gain_v_db : array_like, shape (m,)
        Measured ``20 log10 |v_out / lo|``, dB re 1 V/Pa.
    gain_u_db : array_like, shape (m,), optional
        Measured ``20 log10 |u_out / lo|``, dB re 1 V/Pa.
    initial : PVDFCircuit, optional
        Known parameters and starting values of the fitted ones. Default
        ``PVDFCircuit()``.

    Returns
    -------
    PVDFCircuit
        ``initial`` with the fitted components.
    """
    import scipy.optimize


    f = finite_array(freqs, "freqs")
    if f.ndim != 1 or f.size < 2:
        raise ValueError(f"freqs must be 1-D with at least 2 points, got shape {f.shape}")
    if np.any(f <= 0):
        raise ValueError("freqs must be positive (Hz)")
    gv = finite_array(gain_v_db, "gain_v_db")
    if gv.shape != f.shape:
        raise ValueError(f"gain_v_db must have the shape of freqs {f.shape}, got {gv.shape}")
    gu = None
    if gain_u_db is not None:
        gu = finite_array(gain_u_db, "gain_u_db")
        if gu.shape != f.shape:
            raise ValueError(f"gain_u_db must have the shape of freqs {f.shape}, got {gu.shape}")
    if initial is None:
        initial = PVDFCircuit()
    elif not isinstance(initial, PVDFCircuit):
        raise TypeError(f"initial must be a PVDFCircuit, got {type(initial).__name__}")
    names = _FIT_FIELDS if gu is not None else _FIT_FIELDS[:2]
    x0 = np.log([getattr(initial, n) for n in names])

    def make(x):
        return dataclasses.replace(initial, **dict(zip(names, np.exp(x))))

    def residuals(x):
        c = make(x)
        r = c.gain(f, "v") - gv
        if gu is not None:
            r = np.concatenate([r, c.gain(f, "u") - gu])
        return r

    # Local fits from ``initial`` and from starts with the corners a decade away
    # on either side (ln 10 ~ 2.3); the best one wins.
    best = scipy.optimize.least_squares(residuals, x0, method="lm")
    for shift in (-2.3, 2.3):
        x1 = x0.copy()
        x1[1] += shift
        if gu is not None:
            x1[3] += shift
        r1 = scipy.optimize.least_squares(residuals, x1, method="lm")
        if r1.cost < best.cost:
            best = r1
    if not np.all(np.isfinite(best.x)):
        raise RuntimeError("fit_circuit did not converge")
    return make(best.x)
