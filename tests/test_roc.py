"""The threshold sweep (evaluate.roc) on small synthetic sequences."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from tactile_mirror.lab.detector.evaluation import _metrics, analyse_sequence
from tactile_mirror.lab.detector.thresholds import roc, sequence_extremes

FS = 1000.0


def _result(n, onset):
    """A one-ridge record whose gross slip starts at sample ``onset`` (None: no slip)."""
    frac = np.zeros((1, n))
    if onset is not None:
        frac[0, onset:] = 1.0
    return SimpleNamespace(t=np.arange(n) / FS, fs=FS, slip_fraction=frac)


def _synthetic(n_seq=40, n=500, seed=0):
    rng = np.random.default_rng(seed)
    results, scores, kinds = [], [], []
    for k in range(n_seq):
        onset = None if k % 4 == 3 else int(rng.integers(150, 350))
        res = _result(n, onset)
        y = np.clip(rng.normal(0.3, 0.2, n), 0, 1)
        if onset is not None:
            jump = int(rng.integers(0, 80))  # some rise after the 50 ms window: misses
            y[onset + jump:] = np.clip(rng.normal(0.85, 0.1, n - onset - jump), 0, 1)
        results.append(res)
        scores.append(y[None])
        kinds.append(None if onset is None else ("release" if k % 2 else "gradual"))
    return results, scores, kinds


def test_curve_is_monotonic_and_has_its_endpoints():
    results, scores, kinds = _synthetic()
    c = roc(scores, results, kinds)
    assert np.all(np.diff(c.thresholds) < 0)
    assert np.all(np.diff(c.detection_rate) >= 0)
    assert np.all(np.diff(c.false_alarm_rate) >= 0)
    for d in c.detection_by_kind.values():
        assert np.all(np.diff(d) >= 0)
    # above every score nothing alarms; at the lowest, every slip is detected and every
    # sequence with samples before its onset raises a false alarm
    assert c.detection_rate[0] == 0 and c.false_alarm_rate[0] == 0
    assert c.detection_rate[-1] == 1 and c.false_alarm_rate[-1] == 1
    assert c.n_sequences == 40 and c.n_slip == 30
    assert c.n_by_kind == {"release": kinds.count("release"), "gradual": kinds.count("gradual")}
    # all-slips detection is the kinds' weighted mean
    w = np.array([c.n_by_kind["release"], c.n_by_kind["gradual"]])
    mixed = (w[0] * c.detection_by_kind["release"] + w[1] * c.detection_by_kind["gradual"]) / w.sum()
    np.testing.assert_allclose(mixed, c.detection_rate)


def test_agrees_with_evaluate_at_every_threshold_and_at_08():
    results, scores, _ = _synthetic(seed=1)
    c = roc(scores, results)
    for thr in (0.5, 0.8, 0.9, float(c.thresholds[len(c.thresholds) // 2])):
        m = _metrics("x", [((s, s), r) for s, r in zip(scores, results)], thr, 0.5, 0.05)
        p = c.at_threshold(thr)
        assert p["detection_rate"] == pytest.approx(m.detection_rate, abs=1e-12)
        assert p["false_alarm_rate"] == pytest.approx(m.false_alarm_rate, abs=1e-12)
    # explicit thresholds give the same points
    c8 = roc(scores, results, thresholds=[0.8])
    m = _metrics("x", [((s, s), r) for s, r in zip(scores, results)], 0.8, 0.5, 0.05)
    assert c8.detection_rate[0] == pytest.approx(m.detection_rate)
    assert c8.false_alarm_rate[0] == pytest.approx(m.false_alarm_rate)
    assert 0 < m.detection_rate < 1 and 0 < m.false_alarm_rate < 1  # a point inside the curve


def test_latency_along_the_curve_agrees_with_evaluate():
    """The mean latency at a point of the sweep is evaluate's mean latency at its threshold,
    per onset kind too, and with K samples in a row the alarm comes at the K-th."""
    results, scores, kinds = _synthetic(seed=3)
    c = roc(scores, results, kinds)
    for thr in (0.6, 0.8, 0.95):
        p = c.at_threshold(thr)
        seqs = [analyse_sequence(r.t, s[0], s[0], r.slip_fraction[0], slip_threshold=thr) for s, r in
                zip(scores, results)]
        for kind in (None, "release", "gradual"):
            lat = [q["latency"] for q, k in zip(seqs, kinds) if q["detected"] and (kind is None or k == kind)]
            key = "latency_ms" if kind is None else f"latency_{kind}_ms"
            assert p[key] == pytest.approx(1e3 * np.mean(lat), abs=1e-9)
    assert c.at_false_alarm(0.1)["latency_ms"] == c.at_threshold(c.at_false_alarm(0.1)["threshold"])["latency_ms"]
    # a lower threshold never alarms later on any sequence
    lo, hi = c.latencies(0.6), c.latencies(0.9)
    both = np.isfinite(hi)
    assert np.all(np.isfinite(lo[both])) and np.all(lo[both] <= hi[both])
    # three in a row: the alarm comes two samples after the first of them
    t = np.arange(100) / FS
    res = SimpleNamespace(t=t, fs=FS, slip_fraction=(np.arange(100) >= 50)[None].astype(float))
    x = np.zeros(100)
    x[55:] = 1.0
    assert roc([x], [res], consecutive=3).latencies(0.5)[0] == pytest.approx(0.007)
    assert roc([x], [res]).latencies(0.5)[0] == pytest.approx(0.005)
    assert np.isnan(roc([x * 0], [res]).latencies(0.5)[0])


def test_operating_point_at_false_alarm_rate():
    results, scores, kinds = _synthetic(seed=2)
    c = roc(scores, results, kinds)
    for fa in (0.0, 0.05, 0.2):
        p = c.at_false_alarm(fa)
        assert p["false_alarm_rate"] <= fa
        # no threshold with at most that many false alarms detects more
        ok = c.false_alarm_rate <= fa
        assert p["detection_rate"] == c.detection_rate[ok].max()
        assert set(p) >= {"detection_release", "detection_gradual", "threshold"}


def test_sequence_extremes_and_consecutive_samples():
    t = np.arange(100) / FS
    gross = np.zeros(100)
    gross[60:] = 1
    x = np.zeros(100)
    x[10] = 0.9          # one sample before the onset
    x[70:72] = 0.95      # two samples in the window
    x[75:80] = 0.7       # five in a row
    assert sequence_extremes(t, x, gross) == (0.9, 0.95, True)
    # with 3 in a row the single spike is no alarm and the window's held level is 0.7
    assert sequence_extremes(t, x, gross, consecutive=3) == (0.0, 0.7, True)
    a = analyse_sequence(t, x, x, gross, slip_threshold=0.9)
    assert a["false_alarm"] and a["detected"]
    # the window ends max_latency after the onset
    x2 = np.zeros(100)
    x2[60 + 31] = 1.0
    assert sequence_extremes(t, x2, gross, max_latency=0.03)[1] == 0.0
    assert sequence_extremes(t, x2, gross, max_latency=0.031)[1] == 1.0
    # no slip: no window
    assert sequence_extremes(t, x, np.zeros(100)) == (0.95, -np.inf, False)


def test_bad_arguments_name_the_argument():
    results, scores, kinds = _synthetic(n_seq=4)
    with pytest.raises(ValueError, match="scores"):
        roc(scores[:3], results)
    with pytest.raises(ValueError, match="results"):
        roc([], [])
    with pytest.raises(ValueError, match="consecutive"):
        roc(scores, results, consecutive=0)
    with pytest.raises(ValueError, match="max_latency"):
        roc(scores, results, max_latency=-1.0)
    with pytest.raises(ValueError, match="kinds"):
        roc(scores, results, kinds=kinds[:2])
    with pytest.raises(ValueError, match="thresholds"):
        roc(scores, results, thresholds=[])
    with pytest.raises(ValueError, match="score"):
        roc([np.full((1, 500), np.nan)] + scores[1:], results)


def test_a_curve_without_slips_and_scores_with_extra_ridges():
    """A curve of sequences none of which slips gave a TypeError at its operating points
    (an empty float array as a mask); scores with more rows than the result has ridges were
    scored against its last ridge."""
    results, scores, kinds = _synthetic(n_seq=8)
    calm = [(r, s, k) for r, s, k in zip(results, scores, kinds) if k is None]
    c = roc([s for _, s, _ in calm], [r for r, _, _ in calm], [k for _, _, k in calm])
    p = c.at_false_alarm(0.02)
    assert c.n_slip == 0 and np.isnan(p["detection_rate"]) and np.isnan(p["latency_gradual_ms"])
    with pytest.raises(ValueError, match=r"scores\[0\].*1 ridges"):
        roc([np.vstack([scores[0]] * 3)] + scores[1:], results)
    # fewer rows score the first ridges
    two = SimpleNamespace(t=results[0].t, fs=FS, slip_fraction=np.vstack([results[0].slip_fraction] * 2))
    assert roc([scores[0]], [two]).n_sequences == 1


def test_evaluate_and_calibrate_refuse_levels_that_make_the_rates_meaningless():
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.lab.detector import evaluate
    from tactile_mirror.lab.detector.calibration import calibrate_slip

    det = SlipDetector.paper()
    results, _, _ = _synthetic(n_seq=2)
    for kwargs, name in (({"max_latency": -1.0}, "max_latency"), ({"max_latency": float("nan")}, "max_latency"),
                         ({"slip_threshold": float("nan")}, "slip_threshold"),
                         ({"slip_threshold": 1.5}, "slip_threshold")):
        with pytest.raises(ValueError, match=name):
            evaluate(det, results, **kwargs)
    with pytest.raises(TypeError, match="slip_threshold"):
        evaluate(det, results, slip_threshold="0.8")
    for fa in (-1, float("nan"), 5, True):
        with pytest.raises(ValueError, match="false_alarm"):
            calibrate_slip(det.weights, results, fa)
    for st in (0.0, 1.0):
        with pytest.raises(ValueError, match="slip_threshold"):
            calibrate_slip(det.weights, results, 0.02, slip_threshold=st)
    with pytest.raises(ValueError, match="validation"):
        calibrate_slip(det.weights, [], 0.02)


def test_targets_refuse_levels_that_never_slip():
    from tactile_mirror.detector.data_prep import targets_from_result

    res = _synthetic(n_seq=1)[0][0]
    for kwargs, name in (({"gross_level": 2.0}, "gross_level"), ({"gross_level": float("nan")}, "gross_level"),
                         ({"pred_scale": -1.0}, "pred_scale")):
        with pytest.raises(ValueError, match=name):
            targets_from_result(res, **kwargs)
    assert targets_from_result(res)[0].sum() > 0
