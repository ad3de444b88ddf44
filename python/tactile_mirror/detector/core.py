"""The :class:`SlipDetector`: trained weights + the C++ kernel."""
from __future__ import annotations

import os
import threading
from importlib import resources

import numpy as np

from tactile_mirror._owner import NotCopyable, claim
from tactile_mirror.detector.bank import bank_features
from tactile_mirror.detector.memory import memory_features
from tactile_mirror.detector.network import forward
from tactile_mirror.detector.weights import DetectorWeights

__all__ = ["BANK_WEIGHTS", "DEFAULT_WEIGHTS", "EARLY_WEIGHTS", "MEMORY_WEIGHTS", "PAPER_WEIGHTS", "SlipDetector"]

#: File name of the paper's Jordan net (4 stress-rate inputs, one fed-back value), bundled.
PAPER_WEIGHTS = "paper_detector.npz"
#: File name of the bundled load-memory net (kind ``"jordan_memory"``).
MEMORY_WEIGHTS = "memory_detector.npz"
#: File name of the bundled filter-bank net (kind ``"jordan_bank"``).
BANK_WEIGHTS = "bank_detector.npz"
#: File name of the bundled pad net: the filter-bank net that also reads the pad's mean
#: (kind ``"jordan_bank"``, ``bank["pad_mean"]``, compressed inputs), trained on 6-ridge pads.
PAD_WEIGHTS = "pad_detector.npz"
#: File name of the bundled early net: the filter-bank net trained with the onsets of slip
#: weighted and chosen in the goals' sensor conditions, which finds a creeping slip about
#: twice as soon as :data:`BANK_WEIGHTS`' net (kind ``"jordan_bank"``, the same bank).
EARLY_WEIGHTS = "early_detector.npz"
#: File name of the default weights inside ``tactile_mirror.detector.data``: the filter-bank
#: net, which beats the paper's net on the build's held-out scenes (seed 777, 200 scenes:
#: 89.1 % detection at 2.0 % false alarms against 60.7 % at 12.5 %; bench/detector_heldout.py).
DEFAULT_WEIGHTS = BANK_WEIGHTS

_DTYPES = {np.dtype(np.float32): "JordanMLPf32", np.dtype(np.float64): "JordanMLPf64"}
_MEMORY_DTYPES = {np.dtype(np.float32): "MemoryJordanf32", np.dtype(np.float64): "MemoryJordanf64"}
_BANK_DTYPES = {np.dtype(np.float32): "BankJordanf32", np.dtype(np.float64): "BankJordanf64"}
#: The most ridges (instances) one kernel runs (the C++ kernels' bound).
MAX_RIDGES = 65536
#: Kinds whose kernel derives its inputs from the four stress rates itself.
_DERIVED = ("jordan_memory", "jordan_bank")


def _core():
    from tactile_mirror import _core

    return _core


class SlipDetector(NotCopyable):
    """Recurrent MLP slip detector (one instance per ridge).

    Two kinds of weights (:attr:`kind`): ``"jordan"``, the paper's Jordan net on the
    four stress rates of each ridge (:meth:`paper`), and ``"jordan_memory"``, the same
    net on the stress rates plus the load-memory channels of
    :mod:`tactile_mirror.detector.memory` (the ridge's shear and normal load and the
    pad's shear rate and load), which the kernel computes itself from the same four
    inputs (C++ ``detector_memory.hpp``), and ``"jordan_bank"`` (:meth:`bank`), the same
    net on the stress rates plus a bank of IIR filters over them
    (:mod:`tactile_mirror.detector.bank`: low-passed rates, rate energy, load and peak
    load; C++ ``detector_bank.hpp``). All take ``[v_L, v_R, u_L, u_R]`` per ridge;
    a ``"jordan_memory"`` detector must be given all ridges of one pad at once.

    Parameters
    ----------
    weights : DetectorWeights
    dtype : {numpy.float64, numpy.float32}
        Precision of the C++ kernel. Output error against the float64 numpy
        recurrence, measured with the bundled weights: about 2e-13 in float64;
        in float32 1.8e-5 (exact) / 2.2e-5 (fast) on simulated scenes and up to
        5e-5 on the benchmark's synthetic stick-slip input (the recurrence
        amplifies round-off; random weights stay within 1e-5 over 1e6 steps).
    activation : {"exact", "fast"}
        Sigmoid of the kernel: ``"exact"`` (``exp``) or ``"fast"`` (polynomial
        ``2^x``; |error| <= 5e-10 in float64, about 2e-7 in float32).
    backend : {"cpp", "numpy"}
        ``"numpy"`` runs the float64 reference recurrence (slow; for checks).

    Examples
    --------
    >>> det = SlipDetector.default()                        # doctest: +SKIP
    >>> y_slip, y_non, y_pred = det.run(features)           # features (n_ridges, 4, n)
    """

    _copy_hint = "make a new one with SlipDetector(det.weights, ...) (weights copy and pickle)"

    slip_threshold = 0.8

    def __init__(self, weights: DetectorWeights, dtype=np.float64, activation: str = "exact",
                 backend: str = "cpp"):
        if not isinstance(weights, DetectorWeights):
            raise TypeError(f"weights must be DetectorWeights, got {type(weights).__name__}")
        weights.validate()
        dt = np.dtype(dtype)
        if dt not in _DTYPES:
            raise TypeError(f"dtype must be float32 or float64, got {dt}")
        if activation not in ("exact", "fast"):
            raise ValueError(f"activation must be 'exact' or 'fast', got {activation!r}")
        if backend not in ("cpp", "numpy"):
            raise ValueError(f"backend must be 'cpp' or 'numpy', got {backend!r}")
        self.weights = weights
        self.dtype = dt
        self.activation = activation
        self.backend = backend
        self._kernels = {}
        self._state = None  # numpy backend: y_pred(t-1) per ridge (and the load state)
        # Owner flag: one thread at a time runs the detector (its state carries over);
        # a second thread gets an error, it never waits.
        self._owner = threading.Lock()

    # -- construction -------------------------------------------------------------------
    @classmethod
    def default(cls, **kwargs) -> SlipDetector:
        """The default detector: the filter-bank net (:meth:`bank`), bundled weights.

        It won on the held-out scenes (89.1 % detection at 2.0 % false alarms noise-free, 74 %
        of the gradual onsets, with its decision point calibrated on 480 validation scenes;
        the paper's net: 60.7 % at 12.5 %, 1 %). The paper's net stays as
        :meth:`paper` (its Fig. 10)."""
        return cls._bundled(DEFAULT_WEIGHTS, **kwargs)

    @classmethod
    def paper(cls, **kwargs) -> SlipDetector:
        """The paper's Jordan net (4 stress-rate inputs, ``y_pred`` fed back), bundled weights."""
        return cls._bundled(PAPER_WEIGHTS, **kwargs)

    @classmethod
    def memory(cls, **kwargs) -> SlipDetector:
        """The load-memory net (kind ``"jordan_memory"``), bundled weights."""
        return cls._bundled(MEMORY_WEIGHTS, **kwargs)

    @classmethod
    def bank(cls, **kwargs) -> SlipDetector:
        """The filter-bank net (kind ``"jordan_bank"``), bundled weights."""
        return cls._bundled(BANK_WEIGHTS, **kwargs)

    @classmethod
    def early(cls, **kwargs) -> SlipDetector:
        """The early net, bundled weights: the filter-bank net (:meth:`bank`'s bank and size)
        trained with the first 50 ms of every slip weighted (``--onset-weight 1``) and chosen
        among its candidates by its detection noise-free and with 1 mV rms of noise rather than
        in the validation scenes' own noise (``--select-conditions``): it finds the slips that
        creep in about twice as soon as :meth:`default`, for 1-2 points of detection on the
        build's held-out scenes.

        Held-out scenes (seed 777), at ``y_slip >= 0.8``: noise-free 88.0 % at 1.5 % false
        alarms, gradual onsets found 14.5 ms after the onset (:meth:`default`: 89.1 % at 2.0 %,
        22.9 ms); 1 mV rms 88.5 % at 2.5 %, 12.7 ms; thermal floor + 2 mV hum, notched, 89.1 %
        at 3.0 %, 10.0 ms; release onsets within 0.5 ms. On 200 fresh scenes (seed 27183):
        89.1 % at 1.0 %, 13.3 ms (:meth:`default`: 91.4 % at 2.0 %, 22.5 ms). See
        docs/detector.md, "How soon"."""
        return cls._bundled(EARLY_WEIGHTS, **kwargs)

    @classmethod
    def pad(cls, **kwargs) -> SlipDetector:
        """The pad net, bundled weights: the filter-bank net that also reads the mean of the
        bank over the pad's ridges (``bank["pad_mean"]``), its inputs compressed
        (``bank["knee"]``), trained and calibrated on six-ridge pads. Run it on all six
        ridges of a pad at once: each ridge's outputs depend on the others' signals.

        On 320 pad scenes no choice has seen (seed 60604; ridges 0-2: 541 release, 340 gradual
        onsets; ``bench/detector_pad_net.py --weights``), at ``y_slip >= 0.8`` noise-free:
        87.9 % detection at 0.9 % false alarms, 73.8 % of the gradual onsets found 15 ms after
        the onset (:meth:`default` on the same pads: 86.4 % at 1.5 %, 70.9 %, 24 ms); at 2 %
        false alarms along its curve 95.3 % (90.3 % of the gradual onsets). With 1 mV rms of
        noise: 88.4 % at 1.6 %. On a single ridge (or a pad of another size) its pad channels
        read what it was not trained on: use :meth:`default` there."""
        return cls._bundled(PAD_WEIGHTS, **kwargs)

    @classmethod
    def _bundled(cls, name, **kwargs) -> SlipDetector:
        ref = resources.files("tactile_mirror.detector").joinpath("data", name)
        with resources.as_file(ref) as path:
            if not os.path.exists(path):
                raise FileNotFoundError(f"bundled detector weights {name} are missing")
            return cls(DetectorWeights.load(path), **kwargs)

    @classmethod
    def load(cls, path, **kwargs) -> SlipDetector:
        """Load weights saved with :meth:`save` (or :meth:`DetectorWeights.save`)."""
        return cls(DetectorWeights.load(path), **kwargs)

    def save(self, path) -> None:
        self.weights.save(path)

    # -- properties ---------------------------------------------------------------------
    @property
    def fs(self) -> float:
        """Sample rate (Hz) the weights were trained for."""
        return self.weights.fs

    @property
    def features(self) -> str:
        """Feature kind of the inputs (``"stress_rate"`` or ``"circuit"``): what :meth:`run` takes.
        ``"jordan_memory"`` and ``"jordan_bank"`` nets take ``"stress_rate"`` and derive their other
        channels."""
        return "stress_rate" if self.weights.kind in _DERIVED else self.weights.features

    @property
    def kind(self) -> str:
        """``"jordan"`` (the paper's net), ``"jordan_memory"`` (load-memory inputs) or ``"jordan_bank"``
        (filter-bank inputs)."""
        return self.weights.kind

    @property
    def n_channels(self) -> int:
        """Input channels per ridge that :meth:`run` and :meth:`step` take (4)."""
        return 4 if self.weights.kind in _DERIVED else self.weights.n_inputs

    @property
    def n_hidden(self) -> int:
        return self.weights.n_hidden

    @property
    def metadata(self) -> dict:
        return self.weights.metadata

    @property
    def simd_path(self) -> str:
        """Code variant the C++ kernel runs, named as :func:`tactile_mirror.simd_path`
        (``"avx2+fma"``, ``"sse2"``, ``"native"`` or ``"generic"``); ``set_simd_path`` of
        :meth:`kernel` also takes ``"generic"`` for the baseline."""
        if self.backend != "cpp":
            return "numpy"
        return self._kernel(1).simd_path

    def kernel(self, n_ridges: int):
        """The C++ kernel object for ``n_ridges`` instances (created once, then reused)."""
        return self._kernel(n_ridges)

    def _kernel(self, n_ridges: int):
        k = self._kernels.get(n_ridges)
        if k is None:
            if isinstance(n_ridges, (bool, np.bool_)) or not isinstance(n_ridges, (int, np.integer)) \
                    or not 1 <= n_ridges <= MAX_RIDGES:
                raise ValueError(f"n_ridges must be an integer in [1, {MAX_RIDGES}], got {n_ridges!r}")
            n_ridges = int(n_ridges)
            w = self.weights
            p = w.params
            if w.kind == "jordan_memory":
                cls = getattr(_core(), _MEMORY_DTYPES[self.dtype])
                k = cls(p.w1, p.b1, p.w2, p.b2, w.input_mean, w.input_gain, n_ridges, w.fs, w.load_tau,
                        self.activation)
            elif w.kind == "jordan_bank":
                b = w.bank
                cls = getattr(_core(), _BANK_DTYPES[self.dtype])
                k = cls(p.w1, p.b1, p.w2, p.b2, w.input_mean, w.input_gain, n_ridges, w.fs,
                        np.asarray(b["lp_taus"], dtype=np.float64), np.asarray(b["abs_taus"], dtype=np.float64),
                        b["load_tau"], b["peak_tau"], self.activation, b.get("knee"), bool(b.get("pad_mean")))
            else:
                cls = getattr(_core(), _DTYPES[self.dtype])
                k = cls(p.w1, p.b1, p.w2, p.b2, w.input_mean, w.input_gain, n_ridges, self.activation)
            self._kernels[n_ridges] = k
        return k

    # -- running ------------------------------------------------------------------------
    def _claim(self):
        return claim(self._owner, "SlipDetector", "detector")

    @staticmethod
    def _check_finite(x, name="features"):
        """Refuse NaN/Inf features (the sigmoid would turn them into a confident
        number), naming the first one by sample, then ridge, then channel."""
        finite = np.isfinite(x)
        if not finite.all():
            r, c, t = np.argwhere(~finite.transpose(2, 0, 1))[0][[1, 2, 0]]
            raise ValueError(f"{name} must be finite: ridge {r}, channel {c}, sample {t} is {x[r, c, t]}")

    def _check_features(self, features, name="features"):
        x = np.asarray(features)
        if x.dtype.kind not in "biuf":
            raise TypeError(f"{name} must hold real numbers, got dtype {x.dtype}")
        single = x.ndim == 2
        if single:
            x = x[None]
        nc = self.n_channels
        if x.ndim != 3 or x.shape[1] != nc:
            raise ValueError(f"{name} must have shape (n_ridges, {nc}, n) or ({nc}, n), got {np.shape(features)}")
        if x.shape[0] < 1:
            raise ValueError(f"{name} must hold at least one ridge")
        return x, single

    def run(self, features, fs=None, reset: bool = True):
        """Run the detector over a block of samples.

        Parameters
        ----------
        features : array_like, shape (n_ridges, 4, n) or (4, n)
            ``[v_L, v_R, u_L, u_R]`` per ridge in the units of :attr:`features`
            (Pa/s and Pa/s^2 for ``"stress_rate"``), time last, sampled at :attr:`fs`.
        fs : float, optional
            Sample rate of ``features`` in Hz; if given it must equal :attr:`fs`.
        reset : bool
            Start from a zero feedback state (default). ``False`` continues from the
            state left by the previous call with the same number of ridges.

        Returns
        -------
        y_slip, y_non, y_pred : ndarray, shape (n_ridges, n) (or (n,) for 2-D input)
            Slip now (slip when >= 0.8), ``1 - y_slip``, and the slip prediction.

        Raises
        ------
        ValueError
            A NaN/Inf feature (both backends; the message names ridge, channel and
            sample); the state is unchanged.
        RuntimeError
            Another thread is running this detector (one thread at a time; nothing
            waits).
        """
        x, single = self._check_features(features)
        if fs is not None:
            self.weights.check_compatible(fs=fs)
        n_r = x.shape[0]
        if x.shape[2] == 0:  # nothing to run: empty outputs, the state as it was
            e = np.zeros((n_r, 0), dtype=np.float64 if self.backend == "numpy" else self.dtype)
            out = (e, e.copy(), e.copy())
            return tuple(a[0] for a in out) if single else out
        if self.backend != "numpy" and self.dtype == np.float32 and x.dtype.itemsize > 4 and x.dtype.kind == "f":
            # values beyond float32's range would be cast to inf and named as such
            big = np.abs(x) > np.finfo(np.float32).max
            if big.any():
                r, c, t = np.argwhere(big.transpose(2, 0, 1))[0][[1, 2, 0]]
                raise ValueError(f"features must fit float32 (this detector's dtype): ridge {r}, channel {c}, "
                                 f"sample {t} is {x[r, c, t]:.6g}")
        with self._claim():
            if self.backend == "numpy":
                self._check_finite(x)
                w = self.weights
                fresh = reset or self._state is None or self._state[0].size != n_r
                p0, l0 = (None, None) if fresh else self._state
                xf = x.astype(np.float64)
                l1 = None
                with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused below
                    if w.kind == "jordan_memory":
                        xf, l1 = memory_features(xf, w.fs, w.load_tau, state=l0, return_state=True)
                    elif w.kind == "jordan_bank":
                        xf, l1 = bank_features(xf, w.fs, w.bank, state=l0, return_state=True)
                    xn = (xf - w.input_mean[None, :, None]) * w.input_gain[None, :, None]
                    ys, yp = forward(w.params, xn, p0)
                p1 = yp[:, -1].copy() if yp.shape[1] else (np.zeros(n_r) if p0 is None else p0)
                if not (np.isfinite(ys).all() and np.isfinite(p1).all() and (l1 is None or np.isfinite(l1).all())):
                    raise ValueError("features overflow the detector's filter states (finite values too large "
                                     "for float64 once filtered); the state is unchanged")
                self._state = (p1, l1)
                out = (ys, 1.0 - ys, yp)
            else:
                k = self._kernel(n_r)
                xc = np.ascontiguousarray(x, dtype=self.dtype)
                y = k.run(xc, reset=reset)  # refuses NaN/Inf features (ValueError), state unchanged
                out = (y[0], y[1], y[2])
        if single:
            out = tuple(a[0] for a in out)
        return out

    def step(self, sample):
        """One tick: ``sample`` (n_ridges, 4) -> array (n_ridges, 3) [y_slip, y_non, y_pred]."""
        s = np.asarray(sample)
        if s.dtype.kind not in "biuf":  # (a complex sample would lose its imaginary part unseen)
            raise TypeError(f"sample must hold real numbers, got dtype {s.dtype}")
        if s.ndim != 2 or s.shape[1] != self.n_channels:
            raise ValueError(f"sample must have shape (n_ridges, {self.n_channels}), got {s.shape}")
        if self.backend == "numpy":
            ys, yn, yp = self.run(s[:, :, None], reset=False)
            return np.stack([ys[:, 0], yn[:, 0], yp[:, 0]], axis=1)
        with self._claim():
            return self._kernel(s.shape[0]).step(np.ascontiguousarray(s, dtype=self.dtype))

    def reset(self) -> None:
        """Zero the feedback state of every kernel."""
        with self._claim():
            for k in self._kernels.values():
                k.reset()
            self._state = None

    def detect(self, features, fs=None):
        """Boolean slip decision ``y_slip >= 0.8`` per ridge and sample."""
        return self.run(features, fs=fs)[0] >= self.slip_threshold

    def __repr__(self) -> str:
        return (f"SlipDetector(kind={self.kind!r}, H={self.n_hidden}, features={self.features!r}, fs={self.fs:g} Hz, "
                f"dtype={self.dtype.name}, activation={self.activation!r}, backend={self.backend!r})")


def reference_run(weights: DetectorWeights, features, dtype=np.float64):
    """Numpy reference of :meth:`SlipDetector.run` (float64 math, or float32 with its clamp)."""
    x = np.asarray(features, dtype=np.float64)
    if weights.kind == "jordan_memory":
        x = memory_features(x if x.ndim == 3 else x[None], weights.fs, weights.load_tau)
    elif weights.kind == "jordan_bank":
        x = bank_features(x if x.ndim == 3 else x[None], weights.fs, weights.bank)
    xn = (x - weights.input_mean[None, :, None]) * weights.input_gain[None, :, None]
    ys, yp = forward(weights.params, xn)
    return ys, 1.0 - ys, yp


