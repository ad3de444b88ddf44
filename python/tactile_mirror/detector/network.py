"""The Jordan recurrent MLP in numpy: reference recurrence, loss and exact BPTT gradient.

Network (paper section 3.2, Figure 9). For one instance (one ridge) with
normalised input ``xn_t`` (``n_inputs`` values) and the previous prediction
``p_{t-1}`` (``p_{-1}`` is the initial state, zero by default)::

    a_t      = W1[:, :n_in] @ xn_t + W1[:, n_in] * p_{t-1} + b1     (n_hidden,)
    h_t      = sigmoid(a_t)
    o_t      = W2 @ h_t + b2                                         (2,)
    y_slip_t = sigmoid(o_t[0]),   y_pred_t = sigmoid(o_t[1]),   p_t = y_pred_t
    y_non_t  = 1 - y_slip_t

The feedback ``p`` is the network's own output (Jordan network), not a target:
training differentiates through it (backpropagation through time). Every
pre-activation is clamped to ``[-clamp, clamp]`` before the sigmoid in the C++
kernel (600 in float64, 80 in float32) so that outputs never become subnormal;
the numpy recurrence skips the clamp, which changes no output by more than
``sigmoid(-600) < 3e-261`` (float64) or ``sigmoid(-80) < 2e-35`` (float32).

This module is the specification that the C++ kernels are tested against: the
inference kernel (``jordan_mlp.hpp``) against :func:`forward`, and the training
kernel (``jordan_bptt.hpp``, ``_core.jordan_loss_grad``, the default backend of
``train_detector``) against :func:`loss_and_grad`. All functions are vectorised
over sequences: inputs have shape ``(n_seq, n_inputs, n)``, time last.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import expit as _expit

__all__ = [
    "Params",
    "forward",
    "init_params",
    "loss_and_grad",
    "sigmoid",
]

CLAMP64 = 600.0
CLAMP32 = 80.0


def sigmoid(a, clamp: float = CLAMP64):
    """Logistic function ``1 / (1 + exp(-a))`` of the clamped argument."""
    return _expit(np.clip(a, -clamp, clamp))


@dataclass
class Params:
    """Weights of the network (float64).

    Attributes
    ----------
    w1 : ndarray, shape (n_hidden, n_inputs + 1)
        Input-to-hidden weights; the last column multiplies ``y_pred(t-1)``.
    b1 : ndarray, shape (n_hidden,)
    w2 : ndarray, shape (2, n_hidden)
        Hidden-to-output weights, row 0 ``y_slip``, row 1 ``y_pred``.
    b2 : ndarray, shape (2,)
    """

    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray

    @property
    def n_hidden(self) -> int:
        return self.w1.shape[0]

    @property
    def n_inputs(self) -> int:
        return self.w1.shape[1] - 1

    def pack(self) -> np.ndarray:
        """All weights as one flat vector (w1, b1, w2, b2 in C order)."""
        return np.concatenate([self.w1.ravel(), self.b1, self.w2.ravel(), self.b2])

    @classmethod
    def unpack(cls, theta, n_inputs: int, n_hidden: int) -> Params:
        theta = np.asarray(theta, dtype=np.float64)
        h, m = n_hidden, n_inputs + 1
        sizes = [h * m, h, 2 * h, 2]
        if theta.shape != (sum(sizes),):
            raise ValueError(f"theta must have shape ({sum(sizes)},), got {theta.shape}")
        parts = np.split(theta, np.cumsum(sizes)[:-1])
        return cls(parts[0].reshape(h, m).copy(), parts[1].copy(), parts[2].reshape(2, h).copy(),
                   parts[3].copy())

    def copy(self) -> Params:
        return Params(self.w1.copy(), self.b1.copy(), self.w2.copy(), self.b2.copy())


def init_params(n_inputs: int, n_hidden: int, seed=0, feedback_gain: float = 2.0) -> Params:
    """Random initial weights (Glorot-uniform), deterministic for a seed.

    The feedback column starts at ``feedback_gain`` (positive) so that the net
    begins with some memory of its own prediction.
    """
    rng = np.random.default_rng(seed)
    lim1 = np.sqrt(6.0 / (n_inputs + 1 + n_hidden))
    w1 = rng.uniform(-lim1, lim1, (n_hidden, n_inputs + 1))
    w1[:, -1] = feedback_gain * rng.uniform(-1.0, 1.0, n_hidden)
    lim2 = np.sqrt(6.0 / (n_hidden + 2))
    w2 = rng.uniform(-lim2, lim2, (2, n_hidden))
    return Params(w1, np.zeros(n_hidden), w2, np.array([-2.0, -2.0]))


def _check_x(x, n_inputs: int) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x[None]
    if x.ndim != 3 or x.shape[1] != n_inputs:
        raise ValueError(f"x must have shape (n_seq, {n_inputs}, n), got {np.shape(x)}")
    return x


def forward(params: Params, xn, p0=None, return_hidden: bool = False):
    """Run the recurrence over normalised inputs.

    Parameters
    ----------
    params : Params
    xn : array_like, shape (n_seq, n_inputs, n) or (n_inputs, n)
        Normalised features (dimensionless), time last.
    p0 : array_like, shape (n_seq,), optional
        Initial feedback state ``y_pred(-1)``; zero by default.
    return_hidden : bool
        Also return the hidden activations, shape (n, n_seq, n_hidden).

    Returns
    -------
    y_slip, y_pred : ndarray, shape (n_seq, n)
    h : ndarray, only with ``return_hidden``.
    """
    x = _check_x(xn, params.n_inputs)
    s, _, n = x.shape
    p = np.zeros(s) if p0 is None else np.asarray(p0, dtype=np.float64).reshape(s).copy()
    w_in = params.w1[:, :-1].T  # (n_in, H)
    w_fb = params.w1[:, -1]  # (H,)
    # Input part of every pre-activation at once: (n, s, H).
    xt = np.ascontiguousarray(x.transpose(2, 0, 1)).reshape(n * s, -1)
    ax = (xt @ w_in + params.b1).reshape(n, s, params.n_hidden)
    w2t = np.ascontiguousarray(params.w2.T)
    ys = np.empty((n, s))
    yp = np.empty((n, s))
    hs = np.empty((n, s, params.n_hidden)) if return_hidden else None
    a = np.empty((s, params.n_hidden))
    h = np.empty((s, params.n_hidden))
    o = np.empty((s, 2))
    b2 = params.b2
    for t in range(n):
        np.multiply(p[:, None], w_fb, out=a)
        a += ax[t]
        ht = h if hs is None else hs[t]
        _expit(a, out=ht)
        np.matmul(ht, w2t, out=o)
        o += b2
        _expit(o, out=o)
        ys[t] = o[:, 0]
        p = yp[t]
        p[:] = o[:, 1]
    if return_hidden:
        return ys.T, yp.T, hs
    return ys.T, yp.T


def loss_and_grad(theta, xn, t_slip, t_pred, w_slip, w_pred, n_inputs: int, n_hidden: int,
                  l2: float = 0.0, feedback: bool = True):
    """Weighted cross-entropy of both outputs and its exact BPTT gradient.

    ``L = sum(w_slip * CE(y_slip, t_slip) + w_pred * CE(y_pred, t_pred)) + l2/2 * |W|^2``
    with ``CE(y, t) = -t log y - (1 - t) log(1 - y)``, evaluated from the logit
    ``o`` (``y = sigmoid(o)``) as ``softplus(o) - t o`` so that it stays exact when
    ``y`` rounds to 0 or 1 (the gradient ``y - t`` does not saturate either, and the
    line search needs both to agree). The weights ``w_*`` are
    already normalised by the caller (e.g. to sum to one). Biases are not
    regularised. With ``feedback=False`` the feedback column of ``w1`` is held
    at zero (the no-feedback baseline) and its gradient is zero.

    Parameters
    ----------
    theta : ndarray
        Packed parameters (:meth:`Params.pack`).
    xn : ndarray, shape (n_seq, n_inputs, n)
    t_slip, t_pred, w_slip, w_pred : ndarray, shape (n_seq, n)

    Returns
    -------
    loss : float
    grad : ndarray, same shape as ``theta``
    """
    prm = Params.unpack(theta, n_inputs, n_hidden)
    if not feedback:
        prm.w1[:, -1] = 0.0
    x = _check_x(xn, n_inputs)
    s, _, n = x.shape
    ys, yp, hs = forward(prm, x, return_hidden=True)
    ys, yp = ys.T, yp.T  # (n, s)
    ts, tp, ws, wp = (np.asarray(a, dtype=np.float64).T for a in (t_slip, t_pred, w_slip, w_pred))
    # Cross-entropy from the logits, softplus(o) - t o: exact where the output
    # rounds to 0 or 1 (log(1 - y) would not be), so loss and gradient agree.
    o = hs @ prm.w2.T + prm.b2  # (n, s, 2)
    loss = np.sum(ws * (np.logaddexp(0.0, o[..., 0]) - ts * o[..., 0]))
    loss += np.sum(wp * (np.logaddexp(0.0, o[..., 1]) - tp * o[..., 1]))
    # dL/do for sigmoid + cross-entropy.
    do_s = ws * (ys - ts)  # (n, s)
    do_p_direct = wp * (yp - tp)
    w_fb = prm.w1[:, -1]
    w2 = prm.w2
    dah = np.empty((n, s, n_hidden))
    do_p = np.empty((n, s))
    g_p = np.zeros(s)  # dL/dp_t coming from step t+1
    dsig_p = yp * (1.0 - yp)
    dsig_h = hs * (1.0 - hs)
    w2p = w2[1]
    # The y_slip part of dL/dh for all steps at once; the loop adds the y_pred part.
    np.multiply(do_s[:, :, None], w2[0], out=dah)
    tmp = np.empty((s, n_hidden))
    for t in range(n - 1, -1, -1):
        dp = do_p_direct[t] + g_p * dsig_p[t]
        do_p[t] = dp
        np.multiply(dp[:, None], w2p, out=tmp)
        da = dah[t]
        da += tmp
        da *= dsig_h[t]
        g_p = da @ w_fb
    # Previous feedback input per step: p_{t-1} (zero at t = 0).
    p_prev = np.vstack([np.zeros((1, s)), yp[:-1]])
    da2 = dah.reshape(n * s, n_hidden)
    xt = np.ascontiguousarray(x.transpose(2, 0, 1)).reshape(n * s, -1)
    g_w1 = np.empty_like(prm.w1)
    g_w1[:, :-1] = da2.T @ xt
    g_w1[:, -1] = p_prev.reshape(-1) @ da2 if feedback else 0.0
    g_b1 = da2.sum(axis=0)
    g_w2 = np.stack([do_s.reshape(-1), do_p.reshape(-1)]) @ hs.reshape(n * s, n_hidden)
    g_b2 = np.array([do_s.sum(), do_p.sum()])
    if l2:
        loss += 0.5 * l2 * (np.sum(prm.w1 ** 2) + np.sum(prm.w2 ** 2))
        g_w1 += l2 * prm.w1
        g_w2 += l2 * prm.w2
        if not feedback:
            g_w1[:, -1] = 0.0
    grad = Params(g_w1, g_b1, g_w2, g_b2).pack()
    return float(loss), grad
