"""Stress-rate estimation: sampled PVDF circuit outputs -> stress rates in Pa/s.

``v_out`` is the load's stress rate seen through the charge amplifier's corner
``fc``; ``u_out`` is its 2nd-order rate seen through ``fc`` and the
differentiator's roll-off ``fd`` (see :mod:`tactile_mirror.circuit`). The
estimator undoes both and limits the bandwidth::

    rate  = E_v * v_out,   E_v(s) = (1 + s/wc)            / rate_gain  * L(s)
    rate2 = E_u * u_out,   E_u(s) = (1 + s/wc) (1 + s/wd) / rate2_gain * L(s)

with ``wc = 2 pi fc``, ``wd = 2 pi fd`` and ``L`` a low-pass of the chosen order
and -3 dB bandwidth (Butterworth or Bessel, unit DC gain; order >= 1 for
``E_v``, >= 2 for ``E_u`` so that the filters are proper). ``rate`` is in Pa/s
and ``rate2`` in Pa/s^2 of the circuit's load (the equivalent load of the strip's
stress state, :meth:`~tactile_mirror.circuit.PVDFCircuit.equivalent_load`).
Without ``u_out``, ``rate2`` is the output of a band-limited digital
differentiator ``s L_d(s)`` run on ``rate``.

Discretisation: the bilinear transform with ``c = 2 fs`` and the low-pass
cutoff prewarped (as :func:`scipy.signal.butter` does). The equalisers are then
the exact inverses of the circuit's default sections
(:meth:`~tactile_mirror.circuit.PVDFCircuit.sos`, bilinear), and the whole chain
from the sampled load to ``rate`` is the bilinear differentiator
``2 fs (z - 1)/(z + 1)`` times the digital low-pass: exact for slow loading,
band-limited above the bandwidth.

Mains notch (optional, off by default): ``notch=50.0`` (or ``(50.0, 150.0)``, one
notch per frequency) puts :func:`scipy.signal.iirnotch` sections of quality
``notch_q`` in front of both equalisers (:func:`notch_sos`), run in the same C++
section cascade. Each notch has unit gain at DC and Nyquist and a zero on the unit
circle at its frequency (a hum line there is removed entirely; the -3 dB width is
``f0 / notch_q``, 1.7 Hz for 50 Hz and Q = 30). Slow loading passes unchanged; a
step of the stress rate (a ramp starting) rings at the notch frequency for about
``notch_q / (pi f0)`` s, with a peak of about 3 % of the step at Q = 30 (measured
in ``tests/test_noise.py``).

Design (functions returning ``sos`` arrays) is kept apart from running:
:class:`StressRateEstimator` streams blocks or single samples through
:class:`tactile_mirror.SosFilter`; :func:`estimate_stress_rate` filters whole
recordings with :func:`tactile_mirror.sosfilt`.
"""
from __future__ import annotations

import math
import numbers
import threading

import numpy as np
import numpy.typing as npt

from tactile_mirror._owner import NotCopyable, claim
from tactile_mirror.checks import integer, real_number, real_numeric, sample_rate
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.filters import SosFilter, sosfilt

__all__ = [
    "StressRateEstimator",
    "differentiator_sos",
    "equalizer_sos",
    "estimate_stress_rate",
    "notch_sos",
]

_KINDS = ("butter", "bessel")


def _check_order(order, minimum: int, name: str = "order") -> int:
    if isinstance(order, bool) or not isinstance(order, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {type(order).__name__}")
    order = int(order)
    if order < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {order}")
    if order > 12:
        raise ValueError(f"{name} must be <= 12, got {order}")
    return order


def _check_bandwidth(bandwidth, fs: float, name: str = "bandwidth") -> float:
    bw = real_number(bandwidth, name, unit="Hz")
    if not 0 < bw < fs / 2:
        raise ValueError(f"{name} must lie in (0, fs/2) = (0, {fs / 2}) Hz, got {bandwidth}")
    return bw


def _check_circuit(circuit) -> PVDFCircuit:
    if not isinstance(circuit, PVDFCircuit):
        raise TypeError(f"circuit must be a PVDFCircuit, got {type(circuit).__name__}")
    return circuit


def _lowpass_zpk(order: int, bandwidth: float, fs: float, kind: str):
    """Analog low-pass (unit DC gain) whose bilinear image (c = 2 fs) has its
    -3 dB point at ``bandwidth``."""
    import scipy.signal

    if kind not in _KINDS:
        raise ValueError(f"kind must be one of {_KINDS}, got {kind!r}")
    wc = 2.0 * fs * math.tan(math.pi * bandwidth / fs)
    if kind == "butter":
        z, p, k = scipy.signal.butter(order, wc, analog=True, output="zpk")
    else:
        z, p, k = scipy.signal.bessel(order, wc, analog=True, output="zpk", norm="mag")
    return z, p, k


def equalizer_sos(circuit: PVDFCircuit, fs: float, output: str = "v", order: int = 2,
                  bandwidth: float = 100.0, kind: str = "butter") -> np.ndarray:
    """Equaliser from a sampled circuit output to the load's stress rate.

    Parameters
    ----------
    circuit : PVDFCircuit
        The circuit that produced the signal.
    fs : float
        Sample rate, Hz.
    output : {"v", "u"}
        ``"v"``: ``v_out`` (V) -> stress rate (Pa/s); ``"u"``: ``u_out`` (V) ->
        2nd-order stress rate (Pa/s^2).
    order : int
        Order of the band-limiting low-pass, >= 1 for ``"v"``, >= 2 for ``"u"``.
    bandwidth : float
        -3 dB frequency of the low-pass, Hz, ``0 < bandwidth < fs/2``.
    kind : {"butter", "bessel"}
        Low-pass family: Butterworth (flat) or Bessel (near-constant delay, less
        overshoot on steps).

    Returns
    -------
    ndarray, shape (n_sections, 6)
    """
    import scipy.signal

    circuit = _check_circuit(circuit)
    fs = sample_rate(fs)
    if output not in ("v", "u"):
        raise ValueError(f"output must be 'v' or 'u', got {output!r}")
    order = _check_order(order, 1 if output == "v" else 2)
    bandwidth = _check_bandwidth(bandwidth, fs)
    zl, pl, kl = _lowpass_zpk(order, bandwidth, fs, kind)
    _, p_circ, _ = circuit.zpk(output)  # real poles -w_i of the circuit
    w = -np.real(p_circ)
    gain = circuit.rate_gain if output == "v" else circuit.rate2_gain
    z = np.concatenate([zl, -w])
    k = kl / np.prod(w) / gain
    zd, pd, kd = scipy.signal.bilinear_zpk(z, pl, k, fs)
    return scipy.signal.zpk2sos(zd, pd, kd)


def differentiator_sos(fs: float, order: int = 1, bandwidth: float = 100.0, kind: str = "butter") -> np.ndarray:
    """Band-limited digital differentiator ``s L(s)`` (bilinear, ``c = 2 fs``).

    Turns a signal in X into its time derivative in X/s below ``bandwidth``.

    Parameters
    ----------
    fs : float
        Sample rate, Hz.
    order : int
        Order of the low-pass ``L``, >= 1.
    bandwidth : float
        -3 dB frequency of ``L``, Hz, ``0 < bandwidth < fs/2``.
    kind : {"butter", "bessel"}

    Returns
    -------
    ndarray, shape (n_sections, 6)
    """
    import scipy.signal

    fs = sample_rate(fs)
    order = _check_order(order, 1)
    bandwidth = _check_bandwidth(bandwidth, fs)
    zl, pl, kl = _lowpass_zpk(order, bandwidth, fs, kind)
    zd, pd, kd = scipy.signal.bilinear_zpk(np.concatenate([zl, [0.0]]), pl, kl, fs)
    return scipy.signal.zpk2sos(zd, pd, kd)


def _notch_freqs(notch, fs: float) -> tuple[float, ...]:
    if notch is None:
        return ()
    vals = [notch] if isinstance(notch, numbers.Real) and not isinstance(notch, bool) else notch
    try:
        vals = list(vals)
    except TypeError:
        raise TypeError(f"notch must be a frequency (Hz), a sequence of them, or None, got {notch!r}") from None
    if not vals:
        raise ValueError("notch must name at least one frequency (Hz), or be None")
    out = []
    for f in vals:
        if isinstance(f, bool) or not isinstance(f, numbers.Real):
            raise TypeError(f"notch must hold real frequencies (Hz), got {notch!r}")
        f = float(f)
        if not (math.isfinite(f) and 0 < f < fs / 2):
            raise ValueError(f"notch frequencies must lie in (0, fs/2) = (0, {fs / 2}) Hz, got {notch!r}")
        if f in out:
            raise ValueError(f"notch names {f:g} Hz twice, got {notch!r}")
        out.append(f)
    return tuple(out)


def _check_notch_q(q, freqs=(), fs=None) -> float:
    q = real_number(q, "notch_q", positive=True)
    for f0 in freqs:
        # the notch's -3 dB band, f0 / q wide, must fit between 0 and fs/2: a wider one has
        # its poles on the unit circle or beyond (scipy's iirnotch returns such sections,
        # and one of them zeroes the whole output)
        if not f0 / q < 2.0 * min(f0, fs / 2 - f0):
            raise ValueError(f"notch_q = {q:g} makes the {f0:g} Hz notch {f0 / q:g} Hz wide: its band must fit "
                             f"between 0 and fs/2 = {fs / 2:g} Hz (notch_q > {f0 / (2.0 * min(f0, fs / 2 - f0)):g})")
    return q


def notch_sos(fs: float, notch, notch_q: float = 30.0) -> np.ndarray:
    """Mains notch sections: one :func:`scipy.signal.iirnotch` per frequency.

    Parameters
    ----------
    fs : float
        Sample rate, Hz.
    notch : float or sequence of float
        Frequencies to remove, Hz, each in ``(0, fs/2)`` (e.g. 50, or 50 and its
        harmonics).
    notch_q : float
        Quality factor ``f0 / bandwidth`` (-3 dB) of each notch. Default 30. Each notch's
        band must fit between 0 and ``fs/2`` (``f0 / notch_q < 2 min(f0, fs/2 - f0)``);
        frequencies are distinct.

    Returns
    -------
    ndarray, shape (len(notch), 6)
    """
    import scipy.signal

    fs = sample_rate(fs)
    freqs = _notch_freqs(notch, fs)
    if not freqs:
        raise ValueError("notch must name at least one frequency (Hz)")
    q = _check_notch_q(notch_q, freqs, fs)
    return np.vstack([scipy.signal.tf2sos(*scipy.signal.iirnotch(f0, q, fs=fs)) for f0 in freqs])


class _Design:
    """The sections of one estimator configuration."""

    def __init__(self, circuit, fs, order, bandwidth, use_u, kind, diff_order, diff_bandwidth, notch=None,
                 notch_q=30.0):
        self.circuit = _check_circuit(circuit)
        self.fs = sample_rate(fs)
        if not isinstance(use_u, (bool, np.bool_)):  # (the string "False" was truthy)
            raise TypeError(f"use_u must be True or False, got {use_u!r}")
        self.use_u = bool(use_u)
        self.order = _check_order(order, 2 if self.use_u else 1)
        self.bandwidth = _check_bandwidth(bandwidth, self.fs)
        if kind not in _KINDS:
            raise ValueError(f"kind must be one of {_KINDS}, got {kind!r}")
        self.kind = kind
        self.sos_rate = equalizer_sos(circuit, self.fs, "v", self.order, self.bandwidth, kind)
        if self.use_u:
            self.sos_rate2 = equalizer_sos(circuit, self.fs, "u", self.order, self.bandwidth, kind)
            self.sos_diff = None
        else:
            self.diff_order = _check_order(diff_order, 1, "diff_order")
            dbw = self.bandwidth if diff_bandwidth is None else diff_bandwidth
            self.diff_bandwidth = _check_bandwidth(dbw, self.fs, "diff_bandwidth")
            self.sos_diff = differentiator_sos(self.fs, self.diff_order, self.diff_bandwidth, kind)
            self.sos_rate2 = None
        self.notch = _notch_freqs(notch, self.fs)
        self.notch_q = _check_notch_q(notch_q, self.notch, self.fs)
        self.sos_notch = notch_sos(self.fs, self.notch, self.notch_q) if self.notch else None
        if self.sos_notch is not None:
            longest = max(self.sos_rate.shape[0], 0 if self.sos_rate2 is None else self.sos_rate2.shape[0])
            if len(self.notch) + longest > 64:  # what a C++ cascade holds (pipeline.hpp)
                raise ValueError(f"notch: {len(self.notch)} notches and the equaliser's {longest} section(s) exceed "
                                 f"the 64 sections of a cascade")
            # in front of the equalisers: rate2 without u_out derives from the notched rate
            self.sos_rate = np.vstack([self.sos_notch, self.sos_rate])
            if self.sos_rate2 is not None:
                self.sos_rate2 = np.vstack([self.sos_notch, self.sos_rate2])


def _block(x, name: str, channels: int) -> np.ndarray:
    a = np.asarray(x)
    real_numeric(a, name)
    if a.ndim != 2 or a.shape[0] != channels:
        raise ValueError(f"{name} must have shape (channels, n) = ({channels}, n), got {a.shape}")
    return a


def _sample(x, name: str, channels: int, dtype) -> np.ndarray:
    a = np.asarray(x)
    real_numeric(a, name)
    if a.shape != (channels,):
        raise ValueError(f"{name} must have shape ({channels},), got {a.shape}")
    return a.astype(dtype, copy=False)


class StressRateEstimator(NotCopyable):
    """Streaming estimator of stress rate and 2nd-order stress rate.

    Parameters
    ----------
    circuit : PVDFCircuit
        The circuit that produced ``v_out`` and ``u_out``.
    fs : float
        Sample rate, Hz.
    channels : int
        Number of strips filtered together.
    order : int
        Low-pass order of the equalisers (>= 2 with ``use_u``, else >= 1). Default 2.
    bandwidth : float
        -3 dB bandwidth, Hz, ``0 < bandwidth < fs/2``. Default 100.
    use_u : bool
        Estimate the 2nd-order rate from ``u_out`` (default) or, if False, by the
        digital differentiator of the rate estimate.
    kind : {"butter", "bessel"}
        Low-pass family.
    diff_order, diff_bandwidth
        Low-pass of the digital differentiator (``use_u=False`` only); defaults 1
        and ``bandwidth``.
    dtype : numpy dtype
        Arithmetic of the filters, float64 (default) or float32.
    notch : float, sequence of float or None
        Mains frequencies (Hz) to notch out of ``v_out`` and ``u_out`` before the
        equalisers (:func:`notch_sos`). Default None: no notch.
    notch_q : float
        Quality factor of each notch. Default 30 (see :func:`notch_sos` for its bounds).

    Attributes
    ----------
    sos_rate, sos_rate2, sos_diff : ndarray or None
        The designed sections (``sos_rate2`` with ``use_u``, ``sos_diff`` without),
        the notch sections first when there is a notch.
    sos_notch : ndarray or None
        The notch sections alone.

    Notes
    -----
    :meth:`process` and :meth:`step` can be mixed freely; any chunking of a
    signal gives the result of :func:`estimate_stress_rate` on the whole signal.
    A call that raises leaves both filters as they were (a block refused by the
    second filter, for a NaN in ``u`` or an overflow, undoes the first); one call
    at a time: a second thread gets ``RuntimeError``.
    """

    def __init__(self, circuit: PVDFCircuit, fs: float, channels: int, order: int = 2, bandwidth: float = 100.0,
                 use_u: bool = True, kind: str = "butter", diff_order: int = 1,
                 diff_bandwidth: float | None = None, dtype: npt.DTypeLike = np.float64,
                 notch: float | tuple[float, ...] | None = None, notch_q: float = 30.0) -> None:
        integer(channels, "channels", 1)
        d = _Design(circuit, fs, order, bandwidth, use_u, kind, diff_order, diff_bandwidth, notch, notch_q)
        self.circuit = d.circuit
        self.fs = d.fs
        self.channels = int(channels)
        self.order = d.order
        self.bandwidth = d.bandwidth
        self.use_u = d.use_u
        self.kind = d.kind
        self.sos_rate = d.sos_rate
        self.sos_rate2 = d.sos_rate2
        self.sos_diff = d.sos_diff
        self.notch = d.notch
        self.notch_q = d.notch_q
        self.sos_notch = d.sos_notch
        self.dtype = np.dtype(dtype)
        self._rate = SosFilter(self.sos_rate, self.channels, dtype=self.dtype)
        second = self.sos_rate2 if self.use_u else self.sos_diff
        self._rate2 = SosFilter(second, self.channels, dtype=self.dtype)
        self._owner = threading.Lock()

    def _claim(self):
        # One call at a time: a call steps two filters, and a second thread between them
        # would leave them a tick apart.
        return claim(self._owner, "StressRateEstimator", "estimator")

    def reset(self) -> None:
        """Return to rest (zero state)."""
        with self._claim():
            self._rate.reset()
            self._rate2.reset()

    def _check_u(self, u):
        if self.use_u and u is None:
            raise ValueError("u is required: the estimator was built with use_u=True")
        if not self.use_u and u is not None:
            raise ValueError("u must be None: the estimator was built with use_u=False")

    def process(self, v: npt.ArrayLike, u: npt.ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Filter one block.

        Parameters
        ----------
        v : array_like, shape (channels, n)
            ``v_out``, V.
        u : array_like, shape (channels, n), optional
            ``u_out``, V; required with ``use_u``, must be None without.

        Returns
        -------
        rate : ndarray, shape (channels, n)
            Stress rate, Pa/s.
        rate2 : ndarray, shape (channels, n)
            2nd-order stress rate, Pa/s^2.
        """
        self._check_u(u)
        v = _block(v, "v", self.channels).astype(self.dtype, copy=False)
        if u is not None:
            u = _block(u, "u", self.channels).astype(self.dtype, copy=False)
            if u.shape != v.shape:
                raise ValueError(f"u must have the shape of v {v.shape}, got {u.shape}")
        with self._claim():
            before = self._rate._snapshot()
            try:
                rate = self._rate.process(v)
            except ValueError as exc:  # (the filter's message names the block, not which one)
                raise ValueError(f"v: {exc}") from None
            try:
                rate2 = self._rate2.process(u if self.use_u else rate)
            except ValueError as exc:
                # the second filter refused the block (a NaN/Inf in u, an overflow): the first
                # one goes back to where it was, so the estimator is as before the call
                self._rate._restore(before)
                which = "u" if self.use_u else "v (its differentiated stress rate)"
                raise ValueError(f"{which}: {exc}") from None
            except BaseException:
                self._rate._restore(before)
                raise
        return rate, rate2

    def step(self, v_sample: npt.ArrayLike,
             u_sample: npt.ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Filter one sample per channel.

        Parameters
        ----------
        v_sample : array_like, shape (channels,)
        u_sample : array_like, shape (channels,), optional

        Returns
        -------
        rate, rate2 : ndarray, shape (channels,)

        Notes
        -----
        A NaN/Inf sample is rejected by :class:`tactile_mirror.SosFilter` (its
        state is kept and it returns its previous output), as befits a real-time
        loop; :meth:`process` raises instead.
        """
        self._check_u(u_sample)
        # both samples checked and converted before either filter moves
        v = _sample(v_sample, "v_sample", self.channels, self.dtype)
        u = _sample(u_sample, "u_sample", self.channels, self.dtype) if self.use_u else None
        with self._claim():
            rate = self._rate.step(v)
            rate2 = self._rate2.step(u if self.use_u else rate)
        return rate, rate2


def estimate_stress_rate(v_out: npt.ArrayLike, u_out: npt.ArrayLike | None, circuit: PVDFCircuit, fs: float,
                         order: int = 2, bandwidth: float = 100.0, kind: str = "butter", diff_order: int = 1,
                         diff_bandwidth: float | None = None, axis: int = -1,
                         notch: float | tuple[float, ...] | None = None,
                         notch_q: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """Estimate stress rate and 2nd-order stress rate of whole recordings.

    Parameters
    ----------
    v_out : array_like
        ``v_out``, V, sampled at ``fs``, time on ``axis``.
    u_out : array_like or None
        ``u_out``, V, same shape; None to differentiate the rate estimate instead.
    circuit : PVDFCircuit
    fs : float
        Sample rate, Hz.
    order, bandwidth, kind, diff_order, diff_bandwidth
        As in :class:`StressRateEstimator`.
    axis : int
        Time axis. Default -1.
    notch, notch_q
        Mains notch, as in :class:`StressRateEstimator` (default None: none).

    Returns
    -------
    rate : ndarray
        Stress rate, Pa/s, shape of ``v_out``.
    rate2 : ndarray
        2nd-order stress rate, Pa/s^2, shape of ``v_out``.
    """
    d = _Design(circuit, fs, order, bandwidth, u_out is not None, kind, diff_order, diff_bandwidth, notch, notch_q)
    v = np.asarray(v_out)
    real_numeric(v, "v_out")
    if v.ndim == 0:
        raise ValueError("v_out must have at least one dimension")
    if isinstance(axis, (bool, np.bool_)) or not isinstance(axis, (int, np.integer)):
        raise TypeError(f"axis must be an int, got {type(axis).__name__}")
    try:
        ax = range(v.ndim)[axis]
    except (IndexError, TypeError):
        raise ValueError(f"axis {axis!r} is out of range for v_out with {v.ndim} dimensions") from None
    v = v.astype(np.float64, copy=False)
    u = None
    if u_out is not None:
        u = np.asarray(u_out)
        real_numeric(u, "u_out")
        if u.shape != v.shape:
            raise ValueError(f"u_out must have the shape of v_out {v.shape}, got {u.shape}")
        u = u.astype(np.float64, copy=False)

    def run(sos, x, name):
        try:
            return sosfilt(sos, x, axis=ax)
        except ValueError as exc:  # sosfilt names its own argument, x
            msg = str(exc)
            raise ValueError(f"{name}{msg[1:]}" if msg.startswith("x ") else f"{name}: {msg}") from None

    rate = run(d.sos_rate, v, "v_out")
    rate2 = run(d.sos_rate2, u, "u_out") if u is not None else run(d.sos_diff, rate, "v_out")
    return rate, rate2
