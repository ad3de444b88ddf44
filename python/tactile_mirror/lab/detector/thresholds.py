"""Detection against false alarms over thresholds of any statistic a detector thresholds.

:func:`roc` sweeps the threshold: for any statistic a detector thresholds
(``y_slip``, a classifier's probability, a force ratio), a sequence is detected at
threshold ``c`` when the statistic reaches ``c`` within the detection window, and
raises a false alarm when it reaches ``c`` before ``t_s``; so each sequence needs
only two numbers (its largest statistic before ``t_s`` and within the window), and
the curve is exact at every threshold. At ``c = 0.8`` on ``y_slip`` it gives
:func:`~tactile_mirror.lab.detector.evaluation.evaluate`'s detection and false-alarm rates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactile_mirror.checks import real_number
from tactile_mirror.detector.data_prep import targets_from_result

__all__ = ["RocCurve", "roc", "running_min", "sequence_extremes"]


def running_min(x: np.ndarray, k: int) -> np.ndarray:
    """``min(x[i-k+1 .. i])``, ``-inf`` for ``i < k - 1``: the statistic whose threshold
    crossing means ``k`` samples in a row at or above the threshold."""
    if k == 1:
        return x
    out = x.copy()
    for j in range(1, k):
        out[j:] = np.minimum(out[j:], x[:-j])
    out[: k - 1] = -np.inf
    return out


def sequence_extremes(t, score, gross, max_latency: float = 0.05, consecutive: int = 1) -> tuple[float, float, bool]:
    """The two numbers a sequence contributes to a threshold sweep.

    Parameters
    ----------
    t : (n,) s
    score : (n,) the statistic a detector thresholds (alarm when ``score >= c``)
    gross : (n,) gross-slip target (onset: first sample >= 0.5), as :func:`~tactile_mirror.lab.detector.evaluation.analyse_sequence`
    max_latency : float
        Detection window after the onset, s.
    consecutive : int
        Samples in a row the statistic must hold at or above the threshold for an alarm.

    Returns
    -------
    pre : float
        Largest (held) statistic before the onset (``-inf`` when there is no sample
        before it): a false alarm at every threshold ``c <= pre``.
    window : float
        Largest (held) statistic in ``[t_s, t_s + max_latency]`` (``-inf`` without slip):
        detected at every ``c <= window``.
    slip : bool
        Whether the sequence has a gross-slip onset.
    """
    pre, held, _, slip = _held_window(t, score, gross, max_latency, consecutive)
    return pre, float(held[-1]) if slip else -np.inf, slip


def _held_window(t, score, gross, max_latency, consecutive):
    """:func:`sequence_extremes`'s ``pre`` and ``slip``, and in the detection window the
    running maximum of the (held) statistic with each sample's time after the onset, s:
    the alarm at threshold ``c`` comes at the first sample whose running maximum is >= c."""
    t = np.asarray(t, dtype=np.float64)
    x = np.asarray(score, dtype=np.float64)
    if x.shape != t.shape:
        raise ValueError(f"score must have the shape of t {t.shape}, got {x.shape}")
    if np.isnan(x).any():
        raise ValueError("score must not contain NaN")
    x = running_min(x, consecutive)
    on = np.flatnonzero(np.asarray(gross) >= 0.5)
    i0 = int(on[0]) if on.size else t.size
    pre = float(x[:i0].max()) if i0 else -np.inf
    if not on.size:
        return pre, np.empty(0), np.empty(0), False
    win = (t[i0:] <= t[i0] + max_latency + 1e-12)
    return pre, np.maximum.accumulate(x[i0:][win]), t[i0:][win] - t[i0], True


@dataclass
class RocCurve:
    """Detection and false-alarm rates of one detector over thresholds of its statistic.

    Attributes
    ----------
    name : str
    thresholds : (m,) decreasing; point ``j`` alarms where the statistic >= ``thresholds[j]``
    detection_rate : (m,) over slipping sequences, non-decreasing along the curve
    false_alarm_rate : (m,) over all sequences, non-decreasing along the curve
    detection_by_kind : dict kind -> (m,) detection rate over that kind's sequences
    n_by_kind : dict kind -> number of sequences of that kind
    n_sequences, n_slip : int
    """

    name: str
    thresholds: np.ndarray
    detection_rate: np.ndarray
    false_alarm_rate: np.ndarray
    detection_by_kind: dict
    n_by_kind: dict
    n_sequences: int
    n_slip: int
    window_max: np.ndarray | None = None
    window_dt: np.ndarray | None = None
    slip_kinds: tuple | None = None

    def at_false_alarm(self, rate: float) -> dict:
        """The operating point with the most detections among those with a false-alarm
        rate <= ``rate`` (the lowest such threshold): ``threshold``, ``detection_rate``,
        ``false_alarm_rate``, ``detection_<kind>`` per onset kind and the mean latency
        of the detected slips, ``latency_ms`` and ``latency_<kind>_ms`` (NaN when none)."""
        ok = np.flatnonzero(self.false_alarm_rate <= rate + 1e-12)
        return self._point(int(ok[-1]) if ok.size else 0)

    def at_threshold(self, threshold: float) -> dict:
        """Rates and latencies at one threshold (alarm where the statistic >= ``threshold``)."""
        ok = np.flatnonzero(self.thresholds >= threshold)
        if not ok.size:
            out = {"threshold": float(threshold), "detection_rate": 0.0, "false_alarm_rate": 0.0}
            out.update({f"detection_{k}": 0.0 for k in self.detection_by_kind})
            out.update({"latency_ms": np.nan}, **{f"latency_{k}_ms": np.nan for k in self.detection_by_kind})
            return out
        # the rates are those of the curve's point; the latency is the threshold's own (the
        # statistic can cross values between two points of the curve inside a window)
        return self._point(int(ok[-1]), float(threshold))

    def latencies(self, threshold: float) -> np.ndarray:
        """Latency (s) of each slipping sequence's alarm at ``threshold``, NaN where it is
        missed, in the order of the slipping sequences (``slip_kinds``)."""
        if self.window_max is None:
            raise ValueError("this curve was built without its detection windows (RocCurve from roc() has them)")
        hit = self.window_max >= threshold
        first = np.argmax(hit, axis=1)
        lat = self.window_dt[np.arange(first.size), first]
        return np.where(hit.any(axis=1), lat, np.nan)

    def _point(self, j: int, threshold: float | None = None) -> dict:
        threshold = float(self.thresholds[j]) if threshold is None else threshold
        out = {"threshold": threshold, "detection_rate": float(self.detection_rate[j]),
               "false_alarm_rate": float(self.false_alarm_rate[j])}
        for kind, d in self.detection_by_kind.items():
            out[f"detection_{kind}"] = float(d[j])
        if self.window_max is not None:
            lat = self.latencies(threshold) * 1e3

            def mean(sel):
                v = lat[sel & np.isfinite(lat)]
                return float(v.mean()) if v.size else float("nan")

            out["latency_ms"] = mean(np.ones(lat.size, bool))
            for kind in self.detection_by_kind:
                out[f"latency_{kind}_ms"] = mean(np.array([k == kind for k in self.slip_kinds], dtype=bool))
        return out

    def as_dict(self) -> dict:
        return {"name": self.name, "n_sequences": self.n_sequences, "n_slip": self.n_slip,
                "n_by_kind": dict(self.n_by_kind), "thresholds": self.thresholds.tolist(),
                "detection_rate": self.detection_rate.tolist(), "false_alarm_rate": self.false_alarm_rate.tolist(),
                "detection_by_kind": {k: v.tolist() for k, v in self.detection_by_kind.items()}}


def roc(scores, results, kinds=None, thresholds=None, max_latency: float = 0.05, consecutive: int = 1,
        name: str = "") -> RocCurve:
    """Detection rate against false-alarm rate over the thresholds of a statistic.

    Parameters
    ----------
    scores : sequence of arrays, one per result, shape (n_ridges, n) or (n,)
        The statistic a detector thresholds (``y_slip`` of a :class:`SlipDetector`,
        a classifier's probability, :meth:`ForceRatioDetector.ratio`), per ridge and
        sample of each result. A 1-D score serves every ridge of its result; fewer rows
        than the result has ridges score its first ridges.
    results : sequence of simulation results
        With ``t`` and the slip targets (:func:`targets_from_result`), in the order of
        ``scores``.
    kinds : sequence of str or None, optional
        Onset kind per sequence in :func:`~tactile_mirror.lab.detector.evaluation.evaluate`'s order
        (:func:`~tactile_mirror.lab.detector.evaluation.onset_kinds`);
        the curve is then split by kind as well.
    thresholds : array_like, optional
        Thresholds to evaluate. Default: every value at which a rate changes (the
        exact curve), plus one above the largest, where nothing alarms.
    max_latency : float
        Detection window after the onset, s (as :func:`evaluate`).
    consecutive : int
        Samples in a row at or above the threshold for an alarm (1: :func:`evaluate`'s rule).
    name : str
        Label of the curve.

    Returns
    -------
    RocCurve
        Points ordered by decreasing threshold: from no alarm to the most alarms.
    """
    results = list(results)
    scores = list(scores)
    if len(scores) != len(results):
        raise ValueError(f"scores must have one entry per result: {len(scores)} scores, {len(results)} results")
    if not results:
        raise ValueError("results must not be empty")
    if isinstance(consecutive, bool) or int(consecutive) != consecutive or consecutive < 1:
        raise ValueError(f"consecutive must be a positive integer, got {consecutive!r}")
    real_number(max_latency, "max_latency", unit="s", nonnegative=True)
    pre, win, slip, held, dts = [], [], [], [], []
    for k, (sc, res) in enumerate(zip(scores, results)):
        gross, _ = targets_from_result(res)
        x = np.asarray(sc, dtype=np.float64)
        if x.ndim == 1:
            x = np.broadcast_to(x, gross.shape)
        if x.ndim != 2 or x.shape[0] > gross.shape[0]:
            # (fewer rows score the result's first ridges; more had been scored against its last)
            raise ValueError(f"scores[{k}] must have shape (n_ridges <= {gross.shape[0]}, n) or (n,) for a result "
                             f"with {gross.shape[0]} ridges, got {np.shape(sc)}")
        for r in range(x.shape[0]):
            p, h, dt, s = _held_window(res.t, x[r], gross[r], max_latency, int(consecutive))
            pre.append(p)
            win.append(float(h[-1]) if s else -np.inf)
            slip.append(s)
            if s:
                held.append(h)
                dts.append(dt)
    pre_a, win_a, slip_a = np.array(pre), np.array(win), np.array(slip)
    if kinds is not None:
        kinds = list(kinds)
        if len(kinds) != pre_a.size:
            raise ValueError(f"kinds must have one entry per sequence ({pre_a.size}), got {len(kinds)}")
    if thresholds is None:
        vals = np.concatenate([pre_a, win_a])
        vals = np.unique(vals[np.isfinite(vals)])[::-1]
        top = vals[0] + max(1.0, abs(vals[0])) if vals.size else 1.0
        thr = np.concatenate([[top], vals])
    else:
        thr = np.sort(np.asarray(thresholds, dtype=np.float64).ravel())[::-1]
        if not thr.size or np.isnan(thr).any():
            raise ValueError("thresholds must be a non-empty array of numbers")
    alarm = pre_a[None, :] >= thr[:, None]
    hit = win_a[None, :] >= thr[:, None]
    n_slip = int(slip_a.sum())
    det = hit[:, slip_a].mean(axis=1) if n_slip else np.full(thr.size, np.nan)
    by_kind, n_by_kind = {}, {}
    if kinds is not None:
        for kind in ("release", "gradual"):
            sel = np.array([k == kind for k in kinds])
            n_by_kind[kind] = int(sel.sum())
            by_kind[kind] = hit[:, sel].mean(axis=1) if sel.any() else np.full(thr.size, np.nan)
    # The windows padded to one length (-inf: no alarm there) for the latency at any threshold.
    width = max((h.size for h in held), default=1)
    window_max = np.full((len(held), width), -np.inf)
    window_dt = np.full((len(held), width), np.nan)
    for i, (h, dt) in enumerate(zip(held, dts)):
        window_max[i, : h.size] = h
        window_dt[i, : h.size] = dt
    slip_kinds = tuple(k for k, s in zip(kinds, slip) if s) if kinds is not None else ("",) * len(held)
    return RocCurve(name=name, thresholds=thr, detection_rate=det, false_alarm_rate=alarm.mean(axis=1),
                    detection_by_kind=by_kind, n_by_kind=n_by_kind, n_sequences=int(pre_a.size), n_slip=n_slip,
                    window_max=window_max, window_dt=window_dt, slip_kinds=slip_kinds)
