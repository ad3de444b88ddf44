"""Inputs of the filter-bank detector: low-passed stress rates, rate energy and load per ridge.

Why: the bound study's causal classifier (``bench/detector_bound.py``) tells a creeping
slip from a stop by the recent *history* of the rates (the signals at lags of 1-256 ms
and their integrals since contact), which the paper's net, with one fed-back value,
cannot hold. A slip that creeps in does not stop the shear rate at once: the ridge's
shear load approaches what the contact carries and its rate fades over tens of ms, while
a stop stills the rate within a few ms wherever the load happens to be. First-order
low-passes of the rates at a few time constants keep that history in a handful of numbers
(the differences of two of them are band-passes: how fast the rate has been falling), so
a small recurrent net can read it. Per ridge, from ``d = v_L - v_R`` (the shear rate) and
``s = v_L + v_R`` (the normal rate), with ``a(tau) = exp(-1 / (fs tau))``:

``shear_lp(tau)``, ``normal_lp(tau)`` (Pa/s), one pair per ``lp_taus``
    ``y_t = a y_{t-1} + (1 - a) x_t``: unit-gain low-passes of ``d`` and ``s``.
``shear_abs(tau)`` (Pa/s), one per ``abs_taus``
    The same low-pass of ``|d|``: the recent shear-rate energy (a stop and a creeping
    slip differ in how it fades).
``load``, ``press`` (Pa)
    Leaky integrals of ``d`` and ``s``, ``y_t = b y_{t-1} + x_t / fs`` with
    ``b = a(load_tau)``: the shear and normal load (as the load-memory net's).
``load_peak`` (Pa)
    ``p_t = max(|load_t|, c p_{t-1})`` with ``c = a(peak_tau)``: the largest shear load
    held recently; a ridge whose load stalls at its peak while the rates fade is creeping
    into slip, one whose rate stops below it has been stopped.

The net (the Jordan kernel, ``jordan_mlp.hpp``) then reads the four stress rates and
these channels, :func:`bank_channels` in order. This module is the specification of the
C++ feature stage ``detector_bank.hpp``. Ridges are independent, unless the bank has
``pad_mean``: then the net also reads, after a ridge's own channels, their mean over the
pad's ridges (the same for every ridge). A stop stills every ridge at once; a slip that
creeps in reaches the ridges one after another, in order of their normal load, so a ridge
creeping while the pad's mean still carries load is what the mean shows
(``bench/detector_pad_net.py`` measures what it gives the net on 6-ridge pads).

Optionally every channel is compressed before the net reads it (a bank with a ``knee``,
one per channel: :func:`log_compress`): ``sign(x) log(1 + |x| / knee)``, linear below the
knee and logarithmic above. The channels are heavy-tailed: a release of stored shear or a
stop moves the rates and their low-passes tens of times further than a slip that creeps in,
and a linear scale fitted to all of them (the net's normalisation) squeezes the range a
creeping onset lives in next to zero (``bench/detector_input_study.py`` measures what the
compression gives the net). The logarithm is a cheap one whose every step is exact or one
rounding, so that this module and the C++ stage give the same bits in float64.
"""
from __future__ import annotations

import math

import numpy as np

from tactile_mirror.detector.normalisation import fit_normalisation

__all__ = ["DEFAULT_BANK", "bank_channels", "bank_config", "bank_features", "bank_state_size", "bank_units",
           "fit_knees", "log_compress"]

#: The bank of the bundled filter-bank net: time constants in s.
DEFAULT_BANK = {"lp_taus": [0.004, 0.016, 0.064, 0.256], "abs_taus": [0.016, 0.064], "load_tau": 0.5,
                "peak_tau": 2.0}
#: Bounds of a bank (the C++ stage's limits).
MAX_TAUS = 8
#: The quadratic's curvature in :func:`log_compress` (11/32, exact in float32 and float64).
COMPRESS_CURVATURE = 0.34375


def _tau(name, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) \
            or not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")
    return float(value)


def bank_config(bank=None) -> dict:
    """A checked copy of a bank description (``DEFAULT_BANK`` when None).

    Keys ``lp_taus`` (1-8 time constants), ``abs_taus`` (0-8), ``load_tau``, ``peak_tau``
    (s, positive and finite), optionally ``pad_mean`` (bool, default False: the pad's mean
    of the channels as more inputs) and ``knee``: one number in [1e-30, 1e30] per channel
    (:func:`bank_channels`, in their units, the pad's mean included), the compression's
    knees (:func:`log_compress`). Raises ``ValueError`` naming the key.
    """
    if bank is not None and not isinstance(bank, dict):
        raise ValueError(f"bank must be a dict, got {type(bank).__name__}")
    b = dict(DEFAULT_BANK if bank is None else bank)
    unknown = set(b) - set(DEFAULT_BANK) - {"knee", "pad_mean"}
    if unknown:
        raise ValueError(f"unknown bank keys {sorted(unknown)}; expected {sorted(DEFAULT_BANK)} and optionally "
                         "'pad_mean' and 'knee'")
    out = {}
    for key, lo in (("lp_taus", 1), ("abs_taus", 0)):
        v = b.get(key)
        if not isinstance(v, (list, tuple)) or not (lo <= len(v) <= MAX_TAUS):
            raise ValueError(f"bank['{key}'] must be a list of {lo} to {MAX_TAUS} time constants, got {v!r}")
        out[key] = [_tau(f"bank['{key}']", t) for t in v]
    for key in ("load_tau", "peak_tau"):
        out[key] = _tau(f"bank['{key}']", b.get(key))
    pad_mean = b.get("pad_mean")
    pad_mean = False if pad_mean is None else pad_mean  # (None: absent, as a knee of None)
    if not isinstance(pad_mean, (bool, np.bool_)):
        raise ValueError(f"bank['pad_mean'] must be True or False, got {pad_mean!r}")
    if pad_mean:
        out["pad_mean"] = True  # (absent when False: the files of banks without it stay as they were)
    if b.get("knee") is not None:
        n_ch = (2 if pad_mean else 1) * (4 + 2 * len(out["lp_taus"]) + len(out["abs_taus"]) + 3)
        k = b["knee"]
        try:
            kv = np.asarray(k, dtype=np.float64)
        except (TypeError, ValueError):
            kv = None
        # [1e-30, 1e30]: a float32 kernel multiplies by 1 / knee, which must stay a normal float
        if kv is None or kv.shape != (n_ch,) or not np.all((kv >= 1e-30) & (kv <= 1e30)):
            raise ValueError(f"bank['knee'] must be {n_ch} numbers in [1e-30, 1e30] (one per channel), got {k!r}")
        out["knee"] = [float(v) for v in kv]
    return out


def log_compress(x, knee, axis: int = -2, dtype=np.float64):
    """``sign(x) log(1 + |x| / knee)``, computed as the C++ bank computes it.

    With ``z = x * (1 / knee)`` and ``1 + |z| = 2^E (1 + t)`` (``E`` an integer, ``0 <= t < 1``,
    read off the floating-point exponent and mantissa), ``log2(1 + t)`` is taken as
    ``t (1 + c (1 - t))`` with ``c = 11/32``: the result is
    ``sign(x) ln 2 (E + t (1 + c (1 - t)))``. Continuous, odd, strictly increasing, slope 1
    at 0; within 0.0056 of ``log(1 + |z|)`` everywhere (exact where ``|z| = 2^k - 1``; ``c``
    minimises that bound); never subnormal. Every step is exact or one rounding, in this
    order in the C++ stage too (compiled without fused multiply-adds), so both give the same
    bits.

    Parameters
    ----------
    x : array_like
        Values; channels along ``axis``.
    knee : array_like, shape (n_channels,)
        Positive knee per channel (:func:`fit_knees`).
    axis : int
        The channel axis of ``x``. Default -2 (``(..., n_channels, n)``).
    dtype : numpy float dtype
        Arithmetic precision (float64, or float32 as the float32 kernel).
    """
    dtype = np.dtype(dtype)
    x = np.asarray(x, dtype=dtype)
    knee = np.asarray(knee, dtype=np.float64)
    if knee.ndim != 1 or knee.size != x.shape[axis]:
        raise ValueError(f"knee must have one entry per channel ({x.shape[axis]} along axis {axis}), "
                         f"got shape {knee.shape}")
    shape = [1] * x.ndim
    shape[axis] = knee.size
    ik = (1.0 / knee).astype(dtype).reshape(shape)
    one = dtype.type(1.0)
    y = one + np.abs(x * ik)
    m, e = np.frexp(y)  # y = m 2^e, 0.5 <= m < 1: E = e - 1, 1 + t = 2 m (exact)
    t = dtype.type(2.0) * m - one
    q = t * (one + dtype.type(COMPRESS_CURVATURE) * (one - t))
    g = ((e - 1).astype(dtype) + q) * dtype.type(math.log(2.0))
    return np.copysign(g, x)


def fit_knees(x, mask=None) -> np.ndarray:
    """Knees for :func:`log_compress`: the median ``|x|`` per channel over the samples.

    ``x`` has shape (n_seq, n_channels, n) (a training set's inputs, ``mask`` its real
    samples), or (n_channels, n). The L and R strips (and u_L, u_R) share a knee, as they
    share a normalisation scale (:func:`~tactile_mirror.detector.normalisation.fit_normalisation`),
    which keeps the pad's mirror symmetry. A channel that is zero throughout gets knee 1.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x[None]
    return fit_normalisation(x, mask, "median")[1]


def bank_channels(bank=None) -> tuple:
    """Names of the filter-bank net's input channels, in order (with ``pad_mean``, the
    ridge's own, then ``pad_mean_<name>`` for each)."""
    b = bank_config(bank)
    names = ["v_L", "v_R", "u_L", "u_R"]
    for t in b["lp_taus"]:
        names += [f"shear_lp_{1e3 * t:g}ms", f"normal_lp_{1e3 * t:g}ms"]
    names += [f"shear_abs_{1e3 * t:g}ms" for t in b["abs_taus"]]
    names += ["load", "press", "load_peak"]
    if b.get("pad_mean"):
        names += [f"pad_mean_{n}" for n in names]
    return tuple(names)


def bank_units(bank=None) -> tuple:
    """Units of :func:`bank_channels` (stress-rate features)."""
    b = bank_config(bank)
    own = ("Pa/s", "Pa/s", "Pa/s^2", "Pa/s^2") + ("Pa/s",) * (2 * len(b["lp_taus"]) + len(b["abs_taus"])) \
        + ("Pa", "Pa", "Pa")
    return own * (2 if b.get("pad_mean") else 1)


def bank_state_size(bank=None) -> int:
    """Filter states per ridge: ``2 len(lp_taus) + len(abs_taus) + 3``."""
    b = bank_config(bank)
    return 2 * len(b["lp_taus"]) + len(b["abs_taus"]) + 3


def bank_features(x, fs: float, bank=None, state=None, return_state: bool = False):
    """The filter-bank net's channels from the 4 stress-rate channels of each ridge.

    Parameters
    ----------
    x : array_like, shape (n_ridges, 4, n)
        ``[v_L, v_R, u_L, u_R]`` per ridge (Pa/s, Pa/s^2), time last.
    fs : float
        Sample rate, Hz.
    bank : dict, optional
        Time constants (:func:`bank_config`); default :data:`DEFAULT_BANK`.
    state : array_like, shape (n_ridges, bank_state_size), optional
        Filter states before the first sample, in channel order after the four rates
        (the low-passes, the |d| low-passes, load, press, load_peak); zero by default.
    return_state : bool
        Also return the state after the last sample.

    Returns
    -------
    ndarray, shape (n_ridges, n_channels, n), float64 (and the state)
        :func:`bank_channels`: ``4 + bank_state_size`` per ridge, then with ``pad_mean``
        their mean over the ridges (summed in ridge order, then divided by ``n_ridges``,
        as the C++ stage). Compressed by :func:`log_compress` when the bank has a
        ``knee``; the state is the filters' own (uncompressed).
    """
    from scipy.signal import lfilter

    b = bank_config(bank)
    if not (isinstance(fs, (int, float, np.floating)) and math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive number of Hz, got {fs!r}")
    fs = float(fs)
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 3 or x.shape[1] != 4:
        raise ValueError(f"x must have shape (n_ridges, 4, n), got {x.shape}")
    n_r, _, n = x.shape
    ns = bank_state_size(b)
    s0 = np.zeros((n_r, ns)) if state is None else np.array(state, dtype=np.float64).reshape(n_r, ns)
    d = x[:, 0] - x[:, 1]
    s = x[:, 0] + x[:, 1]
    out = np.empty((n_r, 4 + ns, n))
    out[:, :4] = x
    k = 0

    def lowpass(src, a, gain, init):
        # y_t = a y_{t-1} + gain x_t, from y_{-1} = init
        return lfilter([gain], [1.0, -a], src, axis=-1, zi=(a * init)[:, None])[0]

    for tau in b["lp_taus"]:
        a = math.exp(-1.0 / (fs * tau))
        out[:, 4 + k] = lowpass(d, a, 1.0 - a, s0[:, k])
        out[:, 5 + k] = lowpass(s, a, 1.0 - a, s0[:, k + 1])
        k += 2
    ad = np.abs(d)
    for tau in b["abs_taus"]:
        a = math.exp(-1.0 / (fs * tau))
        out[:, 4 + k] = lowpass(ad, a, 1.0 - a, s0[:, k])
        k += 1
    a = math.exp(-1.0 / (fs * b["load_tau"]))
    out[:, 4 + k] = lowpass(d, a, 1.0 / fs, s0[:, k])
    out[:, 5 + k] = lowpass(s, a, 1.0 / fs, s0[:, k + 1])
    load = np.abs(out[:, 4 + k])
    k += 2
    c = math.exp(-1.0 / (fs * b["peak_tau"]))
    peak = out[:, 4 + k]
    p = s0[:, k].copy()
    for t in range(n):
        p = np.maximum(load[:, t], c * p)
        peak[:, t] = p
    end = out[:, 4:, -1].copy() if n else s0  # the filters' state: before any compression
    if b.get("pad_mean"):
        total = out[0].copy()
        for r in range(1, n_r):
            total += out[r]
        out = np.concatenate([out, np.broadcast_to(total / n_r, out.shape)], axis=1)
    if b.get("knee") is not None:
        out = log_compress(out, b["knee"])
    if return_state:
        return out, end
    return out
