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

The threshold sweep is :func:`tactile_mirror.lab.detector.thresholds.roc`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from tactile_mirror.checks import real_number, real_range
from tactile_mirror.detector.data_prep import features_from_result, targets_from_result

__all__ = ["NOISE_CONDITIONS", "DetectionMetrics", "EvaluationReport", "ForceRatioDetector",
           "analyse_sequence", "cached_features", "condition_estimator", "detection_by_onset", "evaluate", "noise_free",
           "onset_kinds", "with_noise"]

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
    from tactile_mirror.noise import SensorNoise

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
    from tactile_mirror.detector.data_prep import DEFAULT_ESTIMATOR

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
            from tactile_mirror import simulate

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
