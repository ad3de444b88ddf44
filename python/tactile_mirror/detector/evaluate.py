"""Evaluation of slip detectors on held-out scenes, against baselines.

Per sequence (one ridge of one scene) with gross-slip onset ``t_s`` (the first
sample whose ridge target ``y_slip`` is 1; none if the ridge never slips):

detection
    ``y_slip >= 0.8`` at some sample in ``[t_s, t_s + max_latency]``.
false alarm
    ``y_slip >= 0.8`` at any sample before ``t_s`` (the whole sequence if the
    ridge never slips): stops, slow loading and the press are all included.
latency
    First ``y_slip >= 0.8`` at or after ``t_s`` minus ``t_s``.
y_pred lead
    ``t_s`` minus the last upward crossing of ``y_pred >= pred_threshold`` that
    is still held at ``t_s`` (0 when ``y_pred`` is below the threshold at ``t_s``).

Rates are over sequences: detection rate over slipping sequences, false-alarm
rate over all sequences.

:func:`roc` sweeps the threshold: for any statistic a detector thresholds
(``y_slip``, a classifier's probability, a force ratio), a sequence is detected at
threshold ``c`` when the statistic reaches ``c`` within the detection window, and
raises a false alarm when it reaches ``c`` before ``t_s``; so each sequence needs
only two numbers (its largest statistic before ``t_s`` and within the window), and
the curve is exact at every threshold. At ``c = 0.8`` on ``y_slip`` it gives
:func:`evaluate`'s detection and false-alarm rates.

Reaching this module: the package exports the function :func:`evaluate` under the
module's own name, so the attribute ``tactile_mirror.detector.evaluate`` is the
function (``from tactile_mirror.detector import evaluate`` and ``tactile_mirror.evaluate``
give it, as they always have), and ``import tactile_mirror.detector.evaluate as m``
binds the function too. ``from tactile_mirror.detector.evaluate import roc`` (any name
of the module) works as usual; for the module object itself use
``importlib.import_module("tactile_mirror.detector.evaluate")`` (or
``sys.modules["tactile_mirror.detector.evaluate"]``).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from .._checks import real_number, real_range
from .data_prep import features_from_result, targets_from_result

__all__ = ["NOISE_CONDITIONS", "DetectionMetrics", "EvaluationReport", "ForceRatioDetector", "RocCurve",
           "analyse_sequence", "cached_features", "condition_estimator", "detection_by_onset", "evaluate", "noise_free",
           "onset_kinds", "roc", "sequence_extremes", "with_noise"]

#: The sensor conditions the detectors are evaluated in: name -> (white noise on ``v_out`` and
#: ``u_out``, V rms; mains hum at ``v_out``, V rms of the 50 Hz fundamental with harmonics over the
#: circuit's thermal floor (:class:`~tactile_mirror.noise.SensorNoise`), or None; the estimator's
#: notch frequencies, Hz, or None). Applied to noise-free outputs (:func:`noise_free`).
NOISE_CONDITIONS = {
    "noise-free": (0.0, None, None),
    "1 mV rms white": (1e-3, None, None),
    "thermal + 2 mV 50 Hz hum, notch": (0.0, 2e-3, (50.0, 100.0, 150.0)),
}


def _noise_condition(condition: str) -> tuple:
    """The entry of :data:`NOISE_CONDITIONS` for ``condition``; ValueError naming it if unknown."""
    if condition not in NOISE_CONDITIONS:
        raise ValueError(f"condition must be one of {sorted(NOISE_CONDITIONS)}, got {condition!r}")
    return NOISE_CONDITIONS[condition]


def noise_free(results) -> list:
    """Copies of simulation results with noise-free circuit outputs: their strip stresses through
    their own circuit (a scene's own sensor noise removed)."""
    out = []
    for r in results:
        v, u = r.scene.circuit.simulate(r.stress, r.fs)
        out.append(replace(r, v_out=v, u_out=u))
    return out


def with_noise(results, condition: str, seed: int) -> list:
    """Copies of ``results`` with the noise of ``condition`` (a key of :data:`NOISE_CONDITIONS`)
    added to ``v_out`` / ``u_out``, seeded per scene by ``(seed, index)``. Give it
    :func:`noise_free` results to evaluate in that condition alone."""
    from ..noise import SensorNoise

    white, hum, _ = _noise_condition(condition)
    out = []
    for k, r in enumerate(results):
        rng = np.random.default_rng([seed, k])
        v, u = np.asarray(r.v_out), np.asarray(r.u_out)
        if white:
            v = v + rng.normal(0.0, white, v.shape)
            u = u + rng.normal(0.0, white, u.shape)
        if hum is not None:
            v, u = SensorNoise(circuit=r.scene.circuit, hum=hum).apply(v, u, r.fs, seed=rng)
        out.append(replace(r, v_out=v, u_out=u))
    return out


def condition_estimator(detector, condition: str) -> dict:
    """The stress-rate estimator settings ``detector`` runs with in ``condition``: its own (the
    default estimator's for ``detector`` None), plus the condition's mains notch."""
    from .data_prep import DEFAULT_ESTIMATOR

    notch = _noise_condition(condition)[2]
    own = detector.metadata.get("estimator") if detector is not None else None
    est = dict(own or DEFAULT_ESTIMATOR)
    if notch is not None:
        est["notch"] = notch
    return est


@dataclass
class DetectionMetrics:
    """Metrics of one detector on one scene set (times in ms)."""

    name: str
    n_sequences: int
    n_slip: int
    detection_rate: float
    false_alarm_rate: float
    false_alarm_samples: float
    latency_mean_ms: float
    latency_max_ms: float
    pred_lead_mean_ms: float
    pred_lead_min_ms: float

    def as_dict(self) -> dict:
        return asdict(self)


class EvaluationReport:
    """Rows of :class:`DetectionMetrics`, the detector under test first."""

    def __init__(self, rows, settings):
        self.rows = list(rows)
        self.settings = dict(settings)

    def __getitem__(self, name) -> DetectionMetrics:
        for r in self.rows:
            if r.name == name:
                return r
        raise KeyError(name)

    def table(self) -> str:
        head = (f"{'detector':<22} {'seqs':>5} {'slips':>5} {'detect %':>9} {'false %':>8} {'lat ms':>8} "
                f"{'lat max':>8} {'lead ms':>8} {'lead min':>8}")
        lines = [head, "-" * len(head)]
        for r in self.rows:
            lines.append(f"{r.name:<22} {r.n_sequences:>5d} {r.n_slip:>5d} {100 * r.detection_rate:>9.1f} "
                         f"{100 * r.false_alarm_rate:>8.1f} {r.latency_mean_ms:>8.1f} {r.latency_max_ms:>8.1f} "
                         f"{r.pred_lead_mean_ms:>8.1f} {r.pred_lead_min_ms:>8.1f}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()


def _level(value, name: str) -> float:
    """A threshold on a sigmoid output or a share: a real number in (0, 1), else TypeError /
    ValueError naming ``name``."""
    if not 0 < real_number(value, name) < 1:
        raise ValueError(f"{name} must be in (0, 1), got {value!r}")
    return float(value)


class ForceRatioDetector:
    """Baseline: slip when the force ratio ``|F_y| / F_z`` exceeds a threshold.

    What a force sensor under the pad sees. ``y_slip`` is 1 while the ratio is
    at or above ``threshold``; ``y_pred`` is ``ratio / threshold`` clipped to [0, 1].
    Samples with ``F_z`` below ``min_fz_fraction`` of its peak have ratio 0.
    """

    name = "force ratio |Fy|/Fz"

    def __init__(self, threshold: float, min_fz_fraction: float = 0.05):
        threshold = real_number(threshold, "threshold")
        if not threshold > 0:
            raise ValueError(f"threshold must be positive, got {threshold!r}")
        min_fz_fraction = real_number(min_fz_fraction, "min_fz_fraction", nonnegative=True)
        if not min_fz_fraction < 1:
            raise ValueError(f"min_fz_fraction must be in [0, 1) (a share of the peak F_z), got {min_fz_fraction!r}")
        self.threshold = threshold
        self.min_fz_fraction = min_fz_fraction

    def ratio(self, result) -> np.ndarray:
        fy = np.abs(np.asarray(result.force_y, dtype=np.float64))
        fz = np.abs(np.asarray(result.force_z, dtype=np.float64))
        if fy.shape != fz.shape:
            raise ValueError(f"result.force_y {fy.shape} and force_z {fz.shape} differ in shape")
        peak = np.max(fz, axis=-1, keepdims=True) if fz.size else 1.0
        ok = fz > self.min_fz_fraction * peak
        return np.where(ok, fy / np.where(ok, fz, 1.0), 0.0)

    def outputs(self, result, n_ridges: int):
        r = self.ratio(result)
        r = np.broadcast_to(r if r.ndim == 2 else r[None], (n_ridges, r.shape[-1]))
        y_slip = (r >= self.threshold).astype(np.float64)
        return y_slip, np.clip(r / self.threshold, 0.0, 1.0)

    @classmethod
    def fit(cls, results, slip_threshold: float = 0.8, max_latency: float = 0.05, **kwargs):
        """Threshold that maximises detection rate minus false-alarm rate on ``results``.

        ``results`` must not be empty and must carry a positive force ratio somewhere
        (ValueError otherwise); ``slip_threshold`` in (0, 1) and ``max_latency`` (s, >= 0)
        are checked as :func:`evaluate` checks them.
        """
        _level(slip_threshold, "slip_threshold")
        real_number(max_latency, "max_latency", unit="s", nonnegative=True)
        results = list(results)
        if not results:
            raise ValueError("results must not be empty (the threshold is fitted on them)")
        probe = cls(1.0, **kwargs)
        ratios = np.concatenate([probe.ratio(r).ravel() for r in results])
        if not np.any(ratios > 0):
            raise ValueError("results: no sample has a positive force ratio |F_y| / F_z (no tangential load), "
                             "so there is no threshold to fit")
        cands = np.unique(np.quantile(ratios[ratios > 0], np.linspace(0.5, 0.999, 120)))
        best, best_score = float(cands[-1]), -np.inf
        for c in cands:
            det = cls(float(c), **kwargs)
            m = _metrics(det.name, [(det.outputs(r, targets_from_result(r)[0].shape[0]), r) for r in results],
                         slip_threshold, 0.5, max_latency)
            score = m.detection_rate - m.false_alarm_rate
            if score > best_score:
                best, best_score = float(c), score
        return cls(best, **kwargs)


def analyse_sequence(t, y_slip, y_pred, gross, slip_threshold=0.8, pred_threshold=0.5, max_latency=0.05):
    """Metrics of one sequence (see the module docstring).

    Returns
    -------
    dict with ``slip`` (bool), ``detected``, ``false_alarm`` (bool), ``false_samples`` (int),
    ``n_before`` (samples before onset), ``latency`` and ``lead`` (s, NaN when undefined).
    """
    t = np.asarray(t, dtype=np.float64)
    on = np.flatnonzero(np.asarray(gross) >= 0.5)
    i0 = int(on[0]) if on.size else t.size
    alarm = np.asarray(y_slip) >= slip_threshold
    out = {"slip": bool(on.size), "false_alarm": bool(alarm[:i0].any()), "false_samples": int(alarm[:i0].sum()),
           "n_before": i0, "detected": False, "latency": np.nan, "lead": np.nan}
    if on.size:
        ts = t[i0]
        hit = np.flatnonzero(alarm[i0:] & (t[i0:] <= ts + max_latency + 1e-12))
        if hit.size:
            out["detected"] = True
            out["latency"] = float(t[i0 + hit[0]] - ts)
        above = np.asarray(y_pred)[: i0 + 1] >= pred_threshold
        if above[-1]:
            below = np.flatnonzero(~above)
            start = int(below[-1]) + 1 if below.size else 0
            out["lead"] = float(ts - t[start])
        else:
            out["lead"] = 0.0
    return out


def _metrics(name, items, slip_threshold, pred_threshold, max_latency) -> DetectionMetrics:
    seqs = []
    for (y_slip, y_pred), result in items:
        gross, _ = targets_from_result(result)
        t = np.asarray(result.t)
        for r in range(y_slip.shape[0]):
            g = gross[min(r, gross.shape[0] - 1)]
            seqs.append(analyse_sequence(t, y_slip[r], y_pred[r], g, slip_threshold, pred_threshold, max_latency))
    slips = [s for s in seqs if s["slip"]]
    det = [s for s in slips if s["detected"]]
    lat = np.array([s["latency"] for s in det]) * 1e3
    lead = np.array([s["lead"] for s in slips]) * 1e3
    n_before = sum(s["n_before"] for s in seqs)
    return DetectionMetrics(
        name=name, n_sequences=len(seqs), n_slip=len(slips),
        detection_rate=len(det) / len(slips) if slips else float("nan"),
        false_alarm_rate=float(np.mean([s["false_alarm"] for s in seqs])) if seqs else float("nan"),
        false_alarm_samples=sum(s["false_samples"] for s in seqs) / max(n_before, 1),
        latency_mean_ms=float(lat.mean()) if lat.size else float("nan"),
        latency_max_ms=float(lat.max()) if lat.size else float("nan"),
        pred_lead_mean_ms=float(lead.mean()) if lead.size else float("nan"),
        pred_lead_min_ms=float(lead.min()) if lead.size else float("nan"),
    )


def _as_results(scenes, progress):
    out = []
    items = list(scenes)
    it = items
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(items, desc="simulate", leave=False)
    for s in it:
        if hasattr(s, "t") and hasattr(s, "slip_fraction"):
            out.append(s)
        else:
            from .. import simulate

            out.append(simulate(s))
    return out


def cached_features(detector, index: int, result, cache: dict) -> np.ndarray:
    """The features ``detector`` reads from ``result`` (its kind, its own estimator),
    kept in ``cache`` under (``index``, kind, estimator): the cache :func:`evaluate`'s
    ``features_cache`` holds."""
    est = detector.metadata.get("estimator")
    key = (index, detector.features, repr(sorted(est.items())) if isinstance(est, dict) else repr(est))
    if key not in cache:
        cache[key] = features_from_result(result, detector.features, estimator=est)
    return cache[key]


def evaluate(detector, scenes, baselines=None, slip_threshold: float = 0.8, pred_threshold: float = 0.5,
             max_latency: float = 0.05, progress: bool = False, features_cache=None) -> EvaluationReport:
    """Evaluate a detector (and baselines) on held-out scenes.

    Parameters
    ----------
    detector : SlipDetector
    scenes : iterable
        Simulation results (with ``t``, ``fs``, ``slip_fraction``, and ``v_out``/``u_out``
        or ready ``features``), or scenes, which are simulated first.
    baselines : dict of name -> detector, optional
        Other :class:`SlipDetector` objects (e.g. the no-feedback MLP) or
        :class:`ForceRatioDetector`; reported in the same table.
    slip_threshold : float
        Decision level of ``y_slip`` (0.8, paper).
    pred_threshold : float
        Level of ``y_pred`` for the lead time.
    max_latency : float
        Detection window after gross-slip onset, s.
    progress : bool
        Progress bar while simulating scenes.
    features_cache : dict, optional
        Detector features per (scene index, feature kind, estimator) kept between
        calls on the same ``scenes`` (e.g. scoring many candidate weights): pass the
        same dict each time and the features are computed once.

    Returns
    -------
    EvaluationReport
        ``str(report)`` is the table; ``report[name]`` one row (``"detector"`` is the first).
    """
    # (a NaN or negative level or window used to report 0 % detection, silently)
    _level(slip_threshold, "slip_threshold")
    _level(pred_threshold, "pred_threshold")
    real_number(max_latency, "max_latency", unit="s", nonnegative=True)
    results = _as_results(scenes, progress)
    if not results:
        raise ValueError("scenes must not be empty")
    dets = [("detector", detector)] + list((baselines or {}).items())
    feats_cache = {} if features_cache is None else features_cache
    rows = []
    for name, det in dets:
        items = []
        for k, res in enumerate(results):
            if isinstance(det, ForceRatioDetector):
                n_r = targets_from_result(res)[0].shape[0]
                try:
                    n_r = features_from_result(res, "circuit").shape[0]
                except (AttributeError, ValueError):
                    pass
                ys, yp = det.outputs(res, n_r)
            else:
                ys, _, yp = det.run(cached_features(det, k, res, feats_cache), fs=res.fs)
            items.append(((ys, yp), res))
        rows.append(_metrics(name, items, slip_threshold, pred_threshold, max_latency))
    return EvaluationReport(rows, {"slip_threshold": slip_threshold, "pred_threshold": pred_threshold,
                                   "max_latency_s": max_latency, "n_scenes": len(results)})


def onset_kinds(results, level: float = 1e8, window=(-0.003, 0.005)) -> list:
    """How each slipping sequence's gross slip starts: with a release or gradually.

    With static above kinetic friction, gross slip often frees shear the last
    stuck zone held: a sharp spike of the 2nd-order stress rate on both strips.
    When the slip zone has instead crept over the whole contact, the last nodes
    let go with little stored shear and the strips show no event at the onset;
    the rates only settle, as in a stop at the same load. This classifies the
    onset from the noise-free circuit output (the result's strip stresses
    through its scene's circuit and the default estimator, ``DEFAULT_ESTIMATOR``):
    ``"release"`` when ``|u_L + u_R|`` exceeds ``level`` (Pa/s^2) within
    ``window`` (s) of the onset, else ``"gradual"``; ``None`` for a sequence
    without gross slip.

    ``window`` is a pair ``(before, after)`` of finite times in s around the onset with
    ``before <= 0 <= after`` (so that it holds the onset's own sample); ``level`` is
    finite and non-negative. Anything else is a TypeError / ValueError naming it.

    Returns
    -------
    list of str or None, one per (result, ridge) sequence, in :func:`evaluate`'s order.
    """
    from types import SimpleNamespace

    real_number(level, "level", unit="Pa/s^2", nonnegative=True)
    window = real_range(window, "window", unit="s")
    if not window[0] <= 0.0 <= window[1]:
        raise ValueError(f"window must hold the onset: (before, after) with before <= 0 <= after (s), got {window!r}")
    kinds = []
    for res in results:
        gross, _ = targets_from_result(res)
        scene = getattr(res, "scene", None)
        if getattr(res, "stress", None) is None or scene is None:
            raise ValueError("onset_kinds needs results with strip stresses and their scene")
        v, u = scene.circuit.simulate(res.stress, res.fs)
        x = features_from_result(SimpleNamespace(v_out=v, u_out=u, fs=res.fs, circuit=scene.circuit))
        t = np.asarray(res.t)
        for r in range(x.shape[0]):
            on = np.flatnonzero(gross[min(r, gross.shape[0] - 1)] >= 0.5)
            if not on.size:
                kinds.append(None)
                continue
            win = (t >= t[on[0]] + window[0]) & (t <= t[on[0]] + window[1])
            peak = np.abs(x[r, 2] + x[r, 3])[win].max()
            kinds.append("release" if peak > level else "gradual")
    return kinds


def detection_by_onset(detector, results, slip_threshold: float = 0.8, max_latency: float = 0.05,
                       **kwargs) -> dict:
    """Detection rate of ``detector`` per onset kind (:func:`onset_kinds`).

    Returns ``{kind: (n_sequences, detection_rate)}`` for ``"release"`` and ``"gradual"``.
    """
    results = list(results)
    kinds = onset_kinds(results, **kwargs)
    hits = []
    for res in results:
        gross, _ = targets_from_result(res)
        feats = features_from_result(res, detector.features, estimator=detector.metadata.get("estimator"))
        ys, _, yp = detector.run(feats, fs=res.fs)
        for r in range(ys.shape[0]):
            a = analyse_sequence(res.t, ys[r], yp[r], gross[min(r, gross.shape[0] - 1)], slip_threshold,
                                 max_latency=max_latency)
            hits.append(a["detected"])
    out = {}
    for kind in ("release", "gradual"):
        sel = [h for h, k in zip(hits, kinds) if k == kind]
        out[kind] = (len(sel), float(np.mean(sel)) if sel else float("nan"))
    return out


# ---------------------------------------------------------------------- threshold sweep
def _running_min(x: np.ndarray, k: int) -> np.ndarray:
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
    gross : (n,) gross-slip target (onset: first sample >= 0.5), as :func:`analyse_sequence`
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
    x = _running_min(x, consecutive)
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
        Onset kind per sequence in :func:`evaluate`'s order (:func:`onset_kinds`);
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
