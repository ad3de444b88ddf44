"""Training the slip detector: exact BPTT in numpy, L-BFGS-B from scipy.optimize.

- the training data: :class:`TrainingSet` (padded sequences and their targets), made
  from simulation results by :func:`make_training_set` (its augmentations are
  :mod:`~tactile_mirror.lab.detector.augment`);
- the loss's per-sample weights: :func:`loss_weights` (class balance, the onset windows of
  :func:`onset_windows`), and :func:`hard_example_weights` for a further round;
- :func:`train_detector`, with the loss and gradient of the compiled kernel
  (:func:`cpp_loss`) or of numpy.
"""
from __future__ import annotations

import os
import time

import numpy as np
import scipy.optimize

from tactile_mirror.checks import real_array, real_number
from tactile_mirror.detector.bank import bank_config
from tactile_mirror.detector.data_prep import DEFAULT_ESTIMATOR, features_from_result, targets_from_result
from tactile_mirror.detector.memory import DEFAULT_LOAD_TAU
from tactile_mirror.detector.network import Params, init_params, loss_and_grad
from tactile_mirror.detector.normalisation import fit_normalisation
from tactile_mirror.detector.weights import FEATURE_KINDS, DetectorWeights, feature_channels, feature_units

__all__ = ["TrainingSet", "cpp_loss", "hard_example_weights", "loss_weights", "make_training_set", "onset_windows",
           "pad_sequences", "train_detector"]


def load_tau_of(features: str, load_tau: float | None) -> float | None:
    """The leak time constant of ``"stress_rate_memory"`` features (None for other kinds)."""
    if features != "stress_rate_memory":
        return None
    return DEFAULT_LOAD_TAU if load_tau is None else float(load_tau)


class TrainingSet:
    """Padded arrays of training sequences (one sequence per ridge and scene).

    Attributes
    ----------
    x : ndarray, shape (n_seq, 4, n)
        Raw features, zero-padded at the end.
    y_slip, y_pred : ndarray, shape (n_seq, n)
        Targets.
    mask : ndarray of bool, shape (n_seq, n)
        True on real (not padded) samples.
    fs : float
    features : str
        Feature kind.
    estimator : dict
        Estimator settings of ``"stress_rate"`` features.
    targets : dict
        How the targets were made (``gross_level``, ``pred_scale``).
    load_tau : float or None
        Leak time constant (s) of ``"stress_rate_memory"`` features.
    bank : dict or None
        Time constants of ``"stress_rate_bank"`` features (:func:`~.bank.bank_config`).
    """

    def __init__(self, x, y_slip, y_pred, mask, fs, features="stress_rate", estimator=None, targets=None,
                 load_tau=None, bank=None):
        self.x = np.asarray(x, dtype=np.float64)
        self.y_slip = np.asarray(y_slip, dtype=np.float64)
        self.y_pred = np.asarray(y_pred, dtype=np.float64)
        self.mask = np.asarray(mask, dtype=bool)
        self.fs = float(fs)
        self.features = features
        self.estimator = dict(DEFAULT_ESTIMATOR if estimator is None else estimator)
        self.targets = dict(targets or {})
        self.load_tau = load_tau_of(features, load_tau)
        self.bank = bank_config(bank) if features == "stress_rate_bank" else None
        n_ch = len(feature_units(features, self.bank)) if features in FEATURE_KINDS else 4
        if self.x.ndim != 3 or self.x.shape[1] != n_ch:
            raise ValueError(f"x must have shape (n_seq, {n_ch}, n) for {features!r} features, got {self.x.shape}")
        for name in ("y_slip", "y_pred", "mask"):
            if getattr(self, name).shape != (self.x.shape[0], self.x.shape[2]):
                raise ValueError(f"{name} must have shape {(self.x.shape[0], self.x.shape[2])}, "
                                 f"got {getattr(self, name).shape}")
        if not np.all(np.isfinite(self.x)):
            raise ValueError("x contains non-finite values")
        # (an empty set trained and returned weights made of no data; targets outside [0, 1]
        # or NaN reached the optimiser as "theta must be finite")
        if not self.mask.any():
            raise ValueError("the training set holds no real sample (mask is all False, or no sequence or sample)")
        for name in ("y_slip", "y_pred"):
            y = getattr(self, name)[self.mask]
            if not np.all((y >= 0) & (y <= 1)):  # (NaN fails too)
                raise ValueError(f"{name} targets must lie in [0, 1] on the real samples")

    @property
    def n_seq(self) -> int:
        """Number of sequences."""
        return self.x.shape[0]

    @property
    def n_inputs(self) -> int:
        """Number of input channels."""
        return self.x.shape[1]


def pad_sequences(xs, y_slips, y_preds):
    """Stack per-result features ``(n_ridges, n_in, n_k)`` and targets ``(n_ridges, n_k)``
    into zero-padded arrays: ``x (n_seq, n_in, n)``, ``y_slip``, ``y_pred`` and the
    ``mask`` of real samples, ``(n_seq, n)``, with ``n`` the longest result."""
    n = max(x.shape[2] for x in xs)
    n_seq = sum(x.shape[0] for x in xs)
    X = np.zeros((n_seq, xs[0].shape[1], n))
    S = np.zeros((n_seq, n))
    P = np.zeros((n_seq, n))
    M = np.zeros((n_seq, n), dtype=bool)
    i = 0
    for x, ys, yp in zip(xs, y_slips, y_preds):
        m, L = x.shape[0], x.shape[2]
        X[i:i + m, :, :L] = x
        S[i:i + m, :L] = ys
        P[i:i + m, :L] = yp
        M[i:i + m, :L] = True
        i += m
    return X, S, P, M


def make_training_set(results, features: str = "stress_rate", circuit=None, estimator=None,
                      gross_level: float = 0.999, pred_scale: float = 0.8,
                      pred_target: str = "load_ratio", load_tau: float | None = None,
                      bank: dict | None = None) -> TrainingSet:
    """Stack simulation results (all at one rate) into a :class:`TrainingSet`.

    Targets as :func:`~tactile_mirror.detector.data_prep.targets_from_result`
    (``gross_level``, ``pred_scale``, ``pred_target``).
    """
    results = list(results)
    if not results:
        raise ValueError("results must not be empty")
    fs = float(results[0].fs)
    xs, ss, ps = [], [], []
    for k, r in enumerate(results):
        if not np.isclose(float(r.fs), fs):
            raise ValueError(f"results[{k}].fs={r.fs} differs from results[0].fs={fs}")
        x = features_from_result(r, features, circuit, estimator, load_tau=load_tau, bank=bank)
        ys, yp = targets_from_result(r, gross_level, pred_scale, pred_target)
        if ys.shape[0] != x.shape[0]:
            ys = np.broadcast_to(ys[:1], (x.shape[0], ys.shape[1]))
            yp = np.broadcast_to(yp[:1], (x.shape[0], yp.shape[1]))
        xs.append(x)
        ss.append(ys)
        ps.append(yp)
    X, S, Pp, M = pad_sequences(xs, ss, ps)
    return TrainingSet(X, S, Pp, M, fs, features, estimator,
                       {"gross_level": float(gross_level), "pred_scale": float(pred_scale),
                        "pred_target": pred_target}, load_tau, bank)


_PRED_TARGET_TEXT = {
    "load_ratio": "pred_scale x |F_y| / (mu_k F_z) (tangential load over what the sliding contact carries), "
                  "1 during gross slip",
    "slip_zone": "pred_scale x slip-zone extent (running maximum of the ridge's slip fraction), 1 during gross slip",
}


def onset_windows(y_slip: np.ndarray, mask: np.ndarray, n_window: int) -> np.ndarray:
    """True on the first ``n_window`` samples of every run of ``y_slip >= 0.5`` (per row,
    within ``mask``): the samples where a slip is detected or missed (the evaluation's
    detection window, :func:`~tactile_mirror.lab.detector.evaluation.analyse_sequence`)."""
    pos = (np.asarray(y_slip) >= 0.5) & np.asarray(mask, dtype=bool)
    if n_window < 1:
        return np.zeros_like(pos)
    start = pos & ~np.concatenate([np.zeros((pos.shape[0], 1), dtype=bool), pos[:, :-1]], axis=1)
    # Samples since the last start: a running count, reset at each start.
    idx = np.arange(pos.shape[1])[None, :]
    last = np.maximum.accumulate(np.where(start, idx, -1), axis=1)
    return pos & (last >= 0) & (idx - last < n_window)


def loss_weights(ts: TrainingSet, pred_weight: float, negative_weight: float = 1.0, onset_weight: float = 0.0,
                  onset_window: float = 0.05):
    """The per-sample weights ``(w_slip, w_pred)`` of the ``y_slip`` and ``y_pred`` losses on
    ``ts``: slip and no-slip samples balanced (half the weight each, the no-slip half times
    ``negative_weight``), plus ``onset_weight`` on the first ``onset_window`` s of every
    slip (:func:`onset_windows`); ``y_pred`` weighs every real sample alike, ``pred_weight``
    in all. Padding weighs nothing."""
    m = ts.mask.astype(np.float64)
    pos = m * (ts.y_slip >= 0.5)
    neg = m - pos
    n_pos, n_neg = pos.sum(), neg.sum()
    w_slip = 0.5 * pos / max(n_pos, 1.0) + 0.5 * negative_weight * neg / max(n_neg, 1.0)
    if onset_weight:
        # Most positive samples are steady sliding, which any net gets right; whether a
        # slip is found is decided in the first samples after its onset, where a creeping
        # slip's signals are weakest. This term weights that window as a class of its own.
        win = onset_windows(ts.y_slip, ts.mask, _window_samples(onset_window, ts.fs)).astype(np.float64)
        w_slip = w_slip + 0.5 * onset_weight * win / max(win.sum(), 1.0)
    w_pred = pred_weight * m / max(m.sum(), 1.0)
    return w_slip, w_pred


def _warm_start(init, mean, scale, n_in: int, n_hidden: int) -> Params:
    """The parameters of ``init`` (DetectorWeights) as a starting point, checked against this training."""
    if not isinstance(init, DetectorWeights):
        raise TypeError(f"init must be DetectorWeights, got {type(init).__name__}")
    p = init.params
    if p.w1.shape != (n_hidden, n_in + 1):
        raise ValueError(f"init has {p.w1.shape[0]} hidden units and {p.w1.shape[1] - 1} inputs; this training "
                         f"has n_hidden = {n_hidden} and {n_in} inputs")
    if not (np.allclose(init.input_mean, mean, rtol=1e-12, atol=0.0)
            and np.allclose(init.input_scale, scale, rtol=1e-12, atol=0.0)):
        raise ValueError("init was normalised differently from this training's data (another training set or "
                         "normalisation): its weights would read other inputs")
    return Params(p.w1.copy(), p.b1.copy(), p.w2.copy(), p.b2.copy())


def hard_example_weights(y_slip_out, ts: TrainingSet, factor: float = 4.0, negative_level: float = 0.5,
                         onset_window: float = 0.05, previous=None) -> np.ndarray:
    """Per-sample multipliers of the ``y_slip`` loss that weight a net's hard examples
    (``train_detector(sample_weight=)``): hard-example mining.

    The detector is judged per scene: one excursion over the threshold anywhere outside a
    slip is a false alarm, a slip is missed when ``y_slip`` stays below it over the first
    ``onset_window`` s. A per-sample loss spends most of its weight on samples that every
    net gets right (quiet contact, steady sliding). Given the net's outputs on the training
    set, this multiplies by ``factor``

    - every no-slip sample where the output is at or above ``negative_level`` (the near and
      actual false alarms), and
    - the onset window of every slip whose output stays below 0.8 over that window (the
      near misses),

    on top of ``previous`` (the multipliers of the round before; default all 1), so that
    examples that stay hard gain weight round after round.

    Parameters
    ----------
    y_slip_out : ndarray, shape (n_seq, n)
        The net's ``y_slip`` on the training set's inputs (padding ignored).
    ts : TrainingSet
    factor : float
        >= 1.
    negative_level : float
        In (0, 1).
    onset_window : float
        s (> 0).
    previous : ndarray, shape (n_seq, n), optional
    """
    if not isinstance(ts, TrainingSet):
        raise TypeError(f"ts must be a TrainingSet, got {type(ts).__name__}")
    y = real_array(y_slip_out, "y_slip_out")
    if y.shape != ts.mask.shape:
        raise ValueError(f"y_slip_out must have the training set's shape {ts.mask.shape}, got {y.shape}")
    if not np.all(np.isfinite(y[ts.mask])):
        # (NaN compares false both ways: a diverged net would have had no hard example at all)
        raise ValueError("y_slip_out must be finite on the training samples (a diverged net?)")
    factor = real_number(factor, "factor")
    if not 1.0 <= factor <= 1e6:
        raise ValueError(f"factor must lie in [1, 1e6], got {factor}")
    if not 0.0 < real_number(negative_level, "negative_level") < 1.0:
        raise ValueError(f"negative_level must lie in (0, 1), got {negative_level}")
    m = np.ones(y.shape) if previous is None else real_array(previous, "previous").copy()
    if m.shape != y.shape:
        raise ValueError(f"previous must have shape {y.shape}, got {m.shape}")
    if not (np.all(np.isfinite(m)) and np.all(m >= 0)):
        raise ValueError("previous must be finite and >= 0")
    pos = (ts.y_slip >= 0.5) & ts.mask
    hard = ts.mask & ~pos & (y >= negative_level)
    n_win = _window_samples(onset_window, ts.fs)
    win = onset_windows(ts.y_slip, ts.mask, n_win)
    # one onset window per run: label the runs by their start's index, find the misses
    start = win & ~np.concatenate([np.zeros((win.shape[0], 1), dtype=bool), win[:, :-1]], axis=1)
    run_id = np.cumsum(start, axis=1) * win
    for i in np.flatnonzero(start.any(axis=1)):
        ids = run_id[i]
        for r in range(1, int(ids.max()) + 1):
            sel = ids == r
            if y[i, sel].max() < 0.8:
                hard[i, sel] = True
    m[hard] *= factor
    if not np.all(np.isfinite(m)):
        raise ValueError("the multipliers overflow: factor compounded over too many rounds")
    return m


def _window_samples(onset_window, fs: float) -> int:
    """``onset_window`` s in whole samples at ``fs``: at least one (a shorter window is empty)."""
    w = real_number(onset_window, "onset_window", unit="s", positive=True)
    n = round(w * fs)
    if n < 1:
        raise ValueError(f"onset_window = {w:g} s is shorter than one sample at {fs:g} Hz (it would weight nothing)")
    return n


def cpp_loss(xn, data, w_slip, w_pred, n_hidden, l2, feedback, n_threads):
    """``loss_and_grad`` for L-BFGS-B through the compiled kernel (same function, same packing)."""
    from tactile_mirror.kernels import jordan_loss_grad

    n_in = xn.shape[1]
    m = data.mask
    # Samples used of each sequence: up to its last real one (padding after it has zero weight).
    length = np.where(m.any(axis=1), m.shape[1] - np.argmax(m[:, ::-1], axis=1), 0).astype(np.intp)
    xn = np.ascontiguousarray(xn)
    args = [np.ascontiguousarray(a, dtype=np.float64) for a in (data.y_slip, data.y_pred, w_slip, w_pred)]
    fb = np.arange(n_hidden) * (n_in + 1) + n_in  # feedback column of w1 in the packed vector

    # Weight decay on w1 and w2 (not the biases), as in network.loss_and_grad.
    decay = Params.unpack(np.ones(n_hidden * (n_in + 1) + 3 * n_hidden + 2), n_in, n_hidden)
    decay.b1[:] = 0.0
    decay.b2[:] = 0.0
    decay = l2 * decay.pack()

    def fun(theta):
        theta = np.array(theta, dtype=np.float64)
        if not feedback:
            theta[fb] = 0.0
        loss, grad = jordan_loss_grad(theta, xn, *args, length, n_hidden, n_threads)
        loss += 0.5 * float(theta @ (decay * theta))
        grad += decay * theta
        if not feedback:
            grad[fb] = 0.0
        return float(loss), grad

    return fun


def train_detector(data, n_hidden: int = 16, feedback: bool = True, seed=0, maxiter: int = 400,
                   l2: float = 1e-4, pred_weight: float = 1.0, negative_weight: float = 1.0,
                   onset_weight: float = 0.0, onset_window: float = 0.05, features: str = "stress_rate",
                   estimator=None, circuit=None, progress: bool = True, metadata=None,
                   normalisation: str = "rms", backend: str = "cpp", n_threads=None, callback=None,
                   callback_every: int = 25, sample_weight=None, init=None) -> DetectorWeights:
    """Train a Jordan slip detector by exact BPTT and L-BFGS-B.

    Parameters
    ----------
    data : TrainingSet or iterable of simulation results
        Training sequences. Results are converted with :func:`make_training_set`.
    n_hidden : int
        Hidden units H.
    feedback : bool
        With the y_pred(t-1) input (the Jordan net). ``False`` trains the
        feed-forward baseline (its feedback weights are held at zero).
    seed : int
        Seed of the initial weights; training is deterministic for a seed.
    maxiter : int
        L-BFGS-B iterations.
    l2 : float
        Weight decay on w1, w2 (relative to the mean per-sample loss).
    pred_weight : float
        Weight of the y_pred loss relative to the (class-balanced) y_slip loss.
    negative_weight : float
        Extra weight of the no-slip samples of the y_slip loss (> 1 penalises
        false alarms more than late detections).
    onset_weight : float
        Weight of the first ``onset_window`` seconds of every gross slip in the y_slip
        loss, on top of their weight as slip samples, relative to the slip class (0:
        none, the default). The detection of a slip is decided there
        (:func:`~tactile_mirror.lab.detector.evaluation.evaluate`'s ``max_latency``).
    onset_window : float
        Length of that window, s. Default 0.05.
    features, estimator, circuit
        Feature kind and estimator settings (only used when ``data`` holds results).
    progress : bool
        Show a tqdm progress bar of the iterations.
    normalisation : {"median", "rms"}
        Input scale (see :func:`~tactile_mirror.detector.fit_normalisation`).
    metadata : dict, optional
        Extra entries stored under ``metadata["training"]``.
    backend : {"cpp", "numpy"}
        Where the loss and gradient are computed: ``"cpp"`` (the compiled
        ``tactile_mirror.kernels.jordan_loss_grad``, each sequence run only for its real samples,
        sequences spread over ``n_threads`` threads; 6-9x the numpy speed on one
        thread, 9-11x on two, ``bench/bench_detector.py``) or ``"numpy"``
        (:func:`~tactile_mirror.detector.network.loss_and_grad`, the specification).
        Both give the same loss and gradient to round-off (tested to 1e-12), so the
        trained weights agree closely but not bit for bit. Either is deterministic
        for a seed; the C++ sums do not depend on ``n_threads``.
    n_threads : int, optional
        Threads of the ``"cpp"`` backend; default ``min(2, os.cpu_count())``.
    callback : callable, optional
        ``callback(iteration, weights)`` with the :class:`DetectorWeights` of the
        iterate after every ``callback_every`` L-BFGS-B iterations: checkpoints for
        early stopping on a validation set (what :func:`~tactile_mirror.lab.detector.build.build_default`
        does; the training loss keeps falling after the validation false alarms
        have started to rise).
    sample_weight : array_like, shape (n_seq, n), optional
        Non-negative multipliers of the ``y_slip`` loss weights, per sample (after the class
        balance, ``negative_weight`` and ``onset_weight``): e.g. the hard examples of
        :func:`hard_example_weights`. Default: all 1.
    init : DetectorWeights, optional
        Start from these weights instead of a random draw of ``seed`` (a warm start: a
        second round of training on re-weighted samples). Their input normalisation must be
        the one this call fits on ``data`` (the same training set and ``normalisation``),
        their sizes ``n_hidden`` and the data's inputs.

    Returns
    -------
    DetectorWeights
    """
    if isinstance(n_hidden, bool) or not isinstance(n_hidden, (int, np.integer)) or n_hidden < 1:
        raise ValueError(f"n_hidden must be a positive integer, got {n_hidden!r}")
    if isinstance(maxiter, bool) or not isinstance(maxiter, (int, np.integer)) or maxiter < 1:
        raise ValueError(f"maxiter must be a positive integer, got {maxiter!r}")
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    # (a NaN here reached the optimiser as "theta must be finite"; a negative weight ran)
    for name, value in (("l2", l2), ("pred_weight", pred_weight), ("negative_weight", negative_weight),
                        ("onset_weight", onset_weight), ("onset_window", onset_window)):
        real_number(value, name, nonnegative=True)
    if backend not in ("cpp", "numpy"):
        raise ValueError(f"backend must be 'cpp' or 'numpy', got {backend!r}")
    if n_threads is None:
        n_threads = min(2, os.cpu_count() or 1)
    if isinstance(n_threads, bool) or not isinstance(n_threads, (int, np.integer)) or n_threads < 1:
        raise ValueError(f"n_threads must be a positive integer, got {n_threads!r}")
    if callback is not None and not callable(callback):
        raise TypeError(f"callback must be callable, got {type(callback).__name__}")
    if isinstance(callback_every, bool) or not isinstance(callback_every, (int, np.integer)) or callback_every < 1:
        raise ValueError(f"callback_every must be a positive integer, got {callback_every!r}")
    if not isinstance(data, TrainingSet):
        data = make_training_set(data, features, circuit, estimator)
    if data.features not in FEATURE_KINDS:
        raise ValueError(f"data.features must be one of {sorted(FEATURE_KINDS)}, got {data.features!r}")
    mean, scale = fit_normalisation(data.x, data.mask, normalisation)
    xn = (data.x - mean[None, :, None]) * (1.0 / scale)[None, :, None]
    xn *= data.mask[:, None, :]
    if not (np.isfinite(onset_weight) and onset_weight >= 0.0):
        raise ValueError(f"onset_weight must be finite and >= 0, got {onset_weight!r}")
    if not (np.isfinite(onset_window) and onset_window > 0.0):
        raise ValueError(f"onset_window must be finite and > 0 s, got {onset_window!r}")
    w_slip, w_pred = loss_weights(data, pred_weight, negative_weight, onset_weight, onset_window)
    if sample_weight is not None:
        sw = np.asarray(sample_weight)
        if sw.shape != w_slip.shape or sw.dtype.kind not in "iuf":
            raise ValueError(f"sample_weight must be a real array of shape {w_slip.shape} (n_seq, n), got "
                             f"{sw.dtype} of shape {sw.shape}")
        sw = sw.astype(np.float64)
        if not np.all(np.isfinite(sw)) or np.any(sw < 0):
            raise ValueError("sample_weight must be finite and >= 0")
        if not np.max(sw, initial=0.0) <= 1e12:
            raise ValueError(f"sample_weight must be at most 1e12 (the loss must stay finite), got up to {sw.max():g}")
        w_slip = w_slip * sw
        if not np.any(w_slip > 0) and not pred_weight > 0:
            raise ValueError("sample_weight leaves no sample of the y_slip loss and pred_weight is 0: nothing to train on")
    n_in = data.n_inputs
    if len(feature_units(data.features, data.bank)) != n_in:
        raise ValueError(f"data.features {data.features!r} have {len(feature_units(data.features, data.bank))} "
                         f"channels, "
                         f"data.x has {n_in}")
    if init is None:
        p0 = init_params(n_in, int(n_hidden), seed)
    else:
        p0 = _warm_start(init, mean, scale, n_in, int(n_hidden))
    if not feedback:
        p0.w1[:, -1] = 0.0
    theta0 = p0.pack()
    bounds = None
    if not feedback:
        bounds = [(None, None)] * theta0.size
        for j in range(int(n_hidden)):
            bounds[j * (n_in + 1) + n_in] = (0.0, 0.0)

    if backend == "numpy":
        def fun(theta):
            return loss_and_grad(theta, xn, data.y_slip, data.y_pred, w_slip, w_pred, n_in, int(n_hidden),
                                 l2=l2, feedback=feedback)
    else:
        fun = cpp_loss(xn, data, w_slip, w_pred, int(n_hidden), l2, feedback, int(n_threads))

    from tqdm.auto import tqdm

    bar = tqdm(total=maxiter, desc=f"train H={n_hidden}{'' if feedback else ' no-fb'}", disable=not progress,
               leave=False)
    t0 = time.perf_counter()

    def make_weights(theta, extra):
        params = Params.unpack(theta, n_in, int(n_hidden))
        if not feedback:
            params.w1[:, -1] = 0.0
        meta = {
            "features": data.features,
            "units": list(feature_units(data.features, data.bank)),
            "channels": list(feature_channels(data.features, data.bank)),
            "estimator": data.estimator if data.features != "circuit" else None,
            **({"load_tau": float(data.load_tau)} if data.features == "stress_rate_memory" else {}),
            **({"bank": data.bank} if data.features == "stress_rate_bank" else {}),
            "targets": {"y_slip": "1 while the ridge slips grossly (slip fraction >= gross_level)",
                        "y_pred": _PRED_TARGET_TEXT.get(data.targets.get("pred_target", "slip_zone"),
                                                        "see pred_target"),
                        **data.targets},
            "feedback": bool(feedback),
            "slip_threshold": 0.8,
            "training": {"n_sequences": int(data.n_seq), "n_samples": int(data.mask.sum()), "seed": int(seed),
                         "maxiter": int(maxiter), "l2": float(l2),
                         "pred_weight": float(pred_weight), "negative_weight": float(negative_weight),
                         **({"onset_weight": float(onset_weight), "onset_window": float(onset_window)}
                            if onset_weight else {}),
                         **({"sample_weight": "per-sample multipliers"} if sample_weight is not None else {}),
                         **({"warm_start": True} if init is not None else {}),
                         "normalisation": normalisation, "backend": backend,
                         "optimizer": "scipy.optimize L-BFGS-B, exact BPTT gradient", **extra, **(metadata or {})},
        }
        return DetectorWeights(params, mean, scale, data.fs, meta)

    count = [0]

    def on_iteration(xk):
        bar.update(1)
        count[0] += 1
        if callback is not None and count[0] % int(callback_every) == 0:
            callback(count[0], make_weights(np.array(xk, dtype=np.float64),
                                            {"iterations": count[0], "checkpoint": True}))

    res = scipy.optimize.minimize(fun, theta0, jac=True, method="L-BFGS-B", bounds=bounds, callback=on_iteration,
                                  options={"maxiter": int(maxiter), "maxfun": int(maxiter) * 2, "gtol": 1e-9,
                                           "ftol": 1e-12})
    bar.close()
    elapsed = time.perf_counter() - t0
    return make_weights(res.x, {"iterations": int(res.nit), "loss": float(res.fun), "seconds": round(elapsed, 2),
                                "optimizer_message": str(res.message)})
