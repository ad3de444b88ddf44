"""The pipeline tick in scipy and numpy: the reference :class:`MirrorPipeline` is tested against.

:class:`ReferencePipeline` takes a :attr:`MirrorPipeline.config
<tactile_mirror.pipeline.MirrorPipeline.config>` and steps the same laws, one tick per call, in
float64: scipy's ``sosfilt`` with carried state, the filter bank in numpy, the Jordan MLP in numpy
and the controller's own arithmetic. Tens of microseconds a tick: for tests and benchmarks.
"""
from __future__ import annotations

import math

import numpy as np

from tactile_mirror import _core
from tactile_mirror.pipeline.controller import controller_from_dict

__all__ = ["ReferencePipeline"]

_DEFAULTS = _core.pipeline_defaults()


class ReferencePipeline:
    """The pipeline tick in scipy + numpy (float64): the reference and the baseline.

    Same configuration, layout and semantics as :class:`MirrorPipeline` (built from
    its :attr:`~MirrorPipeline.config`): ``scipy.signal.sosfilt`` with carried ``zi``
    per path, the filter bank of a ``"jordan_bank"`` detector with
    :func:`~tactile_mirror.detector.bank.bank_features` (state carried), the Jordan MLP
    in numpy, the controller's :meth:`Controller.run` arithmetic. Slow (tens of microseconds per tick): for tests and benchmarks.
    """

    def __init__(self, config: dict):
        self.cfg = dict(config)
        c = self.cfg
        self.R = int(c["n_ridges"])
        self.nch = 2 * self.R
        self.n_voltages = self.nch * (2 if c["use_u"] else 1)
        self.force = bool(c.get("force_input", False))
        self.n_inputs = self.n_voltages + (1 if self.force else 0)
        self.n_outputs = 2 + 3 * self.R
        self.ctrl = controller_from_dict(c["controller"])
        self.reset()

    def reset(self, x0: float = 0.0):
        c = self.cfg
        self.zv = None if c["sos_v"] is None else np.zeros((c["sos_v"].shape[0], self.nch, 2))
        second = c["sos_u"] if c["use_u"] else c["sos_diff"]
        self.z2 = None if second is None else np.zeros((second.shape[0], self.nch, 2))
        self.p = np.zeros(self.R)
        self.bank_state = None
        if c.get("bank") is not None:
            from tactile_mirror.detector.bank import bank_state_size

            self.bank_state = np.zeros((self.R, bank_state_size(c["bank"])))
        self.det = np.zeros((self.R, 3))
        self.feat = np.zeros((self.R, 4))
        self.law = self.ctrl._start(x0)
        self.f_prev = None  # the last accepted force (force_input)
        self.x, self.v = self.law.x, 0.0
        self.slip = False
        self.consecutive = 0
        self.rejected = {"nonfinite": 0, "out_of_range": 0, "overflow": 0}
        self.out = np.zeros(self.n_outputs)
        self.out[3::3] = 1.0
        self.out[0] = self.x

    def step(self, x) -> np.ndarray:
        c = self.cfg
        x = np.asarray(x, dtype=np.float64)
        nch = self.nch
        nv = self.n_voltages
        ok = bool(np.all(np.abs(x[:nch]) <= c["v_limit"]))
        if c["use_u"]:
            ok &= bool(np.all(np.abs(x[nch:nv]) <= c["u_limit"]))
        if self.force:  # (a config without force_limit has the default, as MirrorPipeline.from_config)
            ok &= bool(abs(x[nv]) <= c.get("force_limit", _DEFAULTS["force_limit"]))
        reason = "" if ok else ("nonfinite" if not np.all(np.isfinite(x)) else "out_of_range")
        if ok:
            with np.errstate(all="ignore"):  # an overflow is detected below
                new = self._update(x)
            ok = all(np.all(np.isfinite(a)) for a in new if a is not None)
            if not ok:
                reason = "overflow"
        if ok:
            zv, z2, feat, p, det, bank_state = new
            sw = c.get("shear_weights")
            asym = float(np.sum(feat[:, 0] - feat[:, 1]) if sw is None else np.sum(sw * feat[:, :2]))
            if self.force:  # the load cell's force change, as pipeline.hpp
                asym = 0.0 if self.f_prev is None else (float(x[nv]) - self.f_prev) * c["fs"]
            slip = float(np.max(det[:, 0])) >= c["slip_threshold"]
            before = self.law.snapshot()
            if self.ctrl.kind != "none":
                with np.errstate(all="ignore"):
                    self.ctrl._tick(self.law, float(np.max(det[:, 2])), asym, False, slip, c["fs"])
            if not (math.isfinite(self.law.x) and math.isfinite(self.law.v) and math.isfinite(self.law.a)
                    and math.isfinite(self.law.w)):
                self.law.restore(before)
                ok, reason = False, "overflow"
            else:  # accepted: commit
                self.zv, self.z2, self.feat, self.p, self.det = zv, z2, feat, p, det
                self.bank_state = bank_state
                if self.force:
                    self.f_prev = float(x[nv])
                self.out[2:] = det.ravel()
                self.consecutive = 0
                self.slip = slip
        if not ok:
            self.consecutive += 1
            self.rejected[reason] += 1
            ypred = float(np.max(self.det[:, 2]))
            fault = self.consecutive > c["max_hold_ticks"]
            if fault:
                ypred = 0.0
            if self.ctrl.kind != "none":
                self.ctrl._tick(self.law, ypred, 0.0, fault, self.slip, c["fs"])
        self.x, self.v = self.ctrl.command(self.law, c["fs"]), self.law.v
        self.out[0] = self.x
        self.out[1] = self.v
        return self.out.copy()

    def _update(self, x):
        """The estimator and detector update of an accepted tick, not yet committed:
        (zv, z2, features, y_pred state, detector outputs, filter-bank state)."""
        from scipy.signal import sosfilt  # loaded with the first tick, not with the package

        c = self.cfg
        nch = self.nch
        zv, z2 = self.zv, self.z2
        v = x[:nch, None]
        if zv is not None:
            rate, zv = sosfilt(c["sos_v"], v, axis=-1, zi=zv)
        else:
            rate = v
        if c["use_u"]:
            u = x[nch:2 * nch, None]
            if z2 is not None:
                rate2, z2 = sosfilt(c["sos_u"], u, axis=-1, zi=z2)
            else:
                rate2 = u
        else:
            rate2, z2 = sosfilt(c["sos_diff"], rate, axis=-1, zi=z2)
        rate = rate[:, 0].reshape(self.R, 2)
        rate2 = rate2[:, 0].reshape(self.R, 2)
        feat = np.concatenate([rate, rate2], axis=1)
        net_in, bank_state = feat, None
        if self.bank_state is not None:
            from tactile_mirror.detector.bank import bank_features

            full, bank_state = bank_features(feat[:, :, None], c["fs"], c["bank"], state=self.bank_state,
                                             return_state=True)
            net_in = full[:, :, 0]
        nf = net_in.shape[1]
        xn = (net_in - c["input_mean"]) * c["input_gain"]
        clamp = 600.0 if np.dtype(c.get("detector_dtype") or c["dtype"]) == np.float64 else 80.0
        a1 = xn @ c["w1"][:, :nf].T + self.p[:, None] * c["w1"][:, nf] + c["b1"]
        h = 1.0 / (1.0 + np.exp(-np.clip(a1, -clamp, clamp)))
        o = h @ c["w2"].T + c["b2"]
        y = 1.0 / (1.0 + np.exp(-np.clip(o, -clamp, clamp)))
        det = np.stack([y[:, 0], 1.0 - y[:, 0], y[:, 1]], axis=1)
        return zv, z2, feat, y[:, 1].copy(), det, bank_state

    def process_block(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        return np.array([self.step(row) for row in x]).reshape(len(x), self.n_outputs)

