"""Slip detector evaluation: metrics, baselines, Figure 10 (synthetic and simulated scenes)."""
from __future__ import annotations

import numpy as np
import pytest
from tactile_mirror.detector import SlipDetector
from tactile_mirror.lab.detector import make_training_set, train_detector
from tactile_mirror.lab.detector.evaluation import ForceRatioDetector, analyse_sequence, evaluate
from tactile_mirror.lab.detector.figures import figure10, figure10_data
from tactile_mirror.lab.detector.synthetic import synthetic_scene

pytest.importorskip("tactile_mirror._core")


# -- metric definitions ---------------------------------------------------------------------

def test_analyse_sequence_definitions():
    t = np.arange(100) / 1000.0
    gross = (t >= 0.06).astype(float)
    y_slip = np.zeros(100)
    y_slip[63:] = 0.9  # detection 3 ms late
    y_pred = np.zeros(100)
    y_pred[20:] = 0.6  # held from 20 ms: 40 ms lead
    y_pred[30] = 0.1  # a dip restarts the lead
    m = analyse_sequence(t, y_slip, y_pred, gross)
    assert m["slip"] and m["detected"] and not m["false_alarm"]
    assert m["latency"] == pytest.approx(0.003)
    assert m["lead"] == pytest.approx(0.060 - 0.031)
    y_slip[10] = 0.85
    m = analyse_sequence(t, y_slip, y_pred, gross)
    assert m["false_alarm"] and m["false_samples"] == 1
    # No slip: any crossing is a false alarm, nothing to detect.
    m = analyse_sequence(t, y_slip, y_pred, np.zeros(100))
    assert not m["slip"] and m["false_alarm"] and np.isnan(m["latency"])
    # Detection later than max_latency is a miss.
    y_slip[:] = 0
    y_slip[95:] = 1
    assert not analyse_sequence(t, y_slip, y_pred, gross, max_latency=0.02)["detected"]


def test_force_ratio_detector():
    r = synthetic_scene(seed=3)
    det = ForceRatioDetector(0.3)
    ys, yp = det.outputs(r, 6)
    assert ys.shape == (6, r.t.size) and set(np.unique(ys)) <= {0.0, 1.0}
    assert np.all((yp >= 0) & (yp <= 1))
    with pytest.raises(ValueError, match="threshold"):
        ForceRatioDetector(-1.0)


def test_force_ratio_fit_refuses_what_it_cannot_fit_on():
    """fit([]) was numpy's "need at least one array to concatenate"; results without a
    tangential load an IndexError."""
    from types import SimpleNamespace

    with pytest.raises(ValueError, match="results must not be empty"):
        ForceRatioDetector.fit([])
    flat = SimpleNamespace(force_y=np.zeros(100), force_z=np.ones(100))
    with pytest.raises(ValueError, match="positive force ratio"):
        ForceRatioDetector.fit([flat])
    for kwargs, exc, name in (({"slip_threshold": 1.5}, ValueError, "slip_threshold"),
                              ({"max_latency": -1.0}, ValueError, "max_latency"),
                              ({"min_fz_fraction": 1.0}, ValueError, "min_fz_fraction"),
                              ({"min_fz_fraction": "0.1"}, TypeError, "min_fz_fraction")):
        with pytest.raises(exc, match=name):
            ForceRatioDetector.fit([flat], **kwargs)
    with pytest.raises(TypeError, match="threshold"):
        ForceRatioDetector("0.3")


def test_evaluation_module_is_not_hidden_by_its_function():
    import importlib
    import types

    from tactile_mirror.lab import detector

    module = importlib.import_module("tactile_mirror.lab.detector.evaluation")
    assert isinstance(module, types.ModuleType) and detector.evaluation is module
    assert detector.evaluate is module.evaluate


# -- synthetic end-to-end -------------------------------------------------------------------

@pytest.fixture(scope="module")
def synthetic_detectors():
    train = [synthetic_scene(seed=s, n_ridges=1, duration=1.8) for s in range(10)]
    train += [synthetic_scene(seed=100 + s, n_ridges=1, duration=1.8, stop_before_slip=True) for s in range(2)]
    ts = make_training_set(train)
    w = train_detector(ts, n_hidden=8, maxiter=80, seed=0, progress=False)
    w_nf = train_detector(ts, n_hidden=8, maxiter=40, seed=0, feedback=False, progress=False)
    return SlipDetector(w), SlipDetector(w_nf), train


def test_evaluate_reports_all_rows(synthetic_detectors):
    det, det_nf, train = synthetic_detectors
    test = [synthetic_scene(seed=1000 + s, n_ridges=2) for s in range(8)]
    test += [synthetic_scene(seed=2000 + s, n_ridges=2, stop_before_slip=True) for s in range(3)]
    force = ForceRatioDetector.fit(train)
    rep = evaluate(det, test, {"no feedback": det_nf, "force ratio": force})
    assert [r.name for r in rep.rows] == ["detector", "no feedback", "force ratio"]
    row = rep["detector"]
    assert row.n_sequences == 22 and row.n_slip == 16
    assert 0 <= row.false_alarm_rate <= 1 and 0 <= row.detection_rate <= 1
    # The (briefly) trained net finds the slips of this easy set, quickly.
    assert row.detection_rate >= 0.9
    assert row.latency_mean_ms <= 10
    assert np.isfinite(row.pred_lead_mean_ms)
    assert "detect %" in str(rep)
    with pytest.raises(KeyError):
        rep["missing"]
    with pytest.raises(ValueError, match="scenes must not be empty"):
        evaluate(det, [])


def test_validation_selection_prefers_fewer_false_alarms(synthetic_detectors):
    from tactile_mirror.lab.detector.selection import ValidationScorer, select_candidate

    det, _, _ = synthetic_detectors
    val = [synthetic_scene(seed=3000 + s, n_ridges=1) for s in range(4)]
    alarm = det.weights.params.copy()
    alarm.b2[0] = 50.0  # y_slip ~ 1 everywhere: detects everything, false alarm everywhere
    w_alarm = type(det.weights)(alarm, det.weights.input_mean, det.weights.input_scale, det.weights.fs,
                                det.metadata)
    scorer = ValidationScorer(val, fa_cost=10.0)
    s_alarm = scorer(w_alarm)
    assert s_alarm["false_alarm_rate"] == 1.0 and s_alarm["score"] == pytest.approx(
        s_alarm["detection_rate"] - 10.0)
    quiet = det.weights.params.copy()
    quiet.b2[0] = -50.0  # never fires: no detection, no false alarm
    w_quiet = type(det.weights)(quiet, det.weights.input_mean, det.weights.input_scale, det.weights.fs,
                                det.metadata)
    best, k, scores = select_candidate([w_alarm, w_quiet], scorer)
    assert k == 1 and best is w_quiet and len(scores) == 2
    assert scores[1] == {**scores[1], "detection_rate": 0.0, "false_alarm_rate": 0.0, "score": 0.0}
    with pytest.raises(ValueError, match="candidates must not be empty"):
        select_candidate([], scorer)
    with pytest.raises(ValueError, match="fa_cost"):
        ValidationScorer(val, fa_cost=-1.0)


def test_hidden_size_study_uses_the_build_selection():
    from tactile_mirror.lab.detector.selection import ValidationScorer, train_selected
    from tactile_mirror.lab.detector.size_study import hidden_size_study

    ts = make_training_set([synthetic_scene(seed=s, n_ridges=1, duration=1.2) for s in range(2)])
    scorer = ValidationScorer([synthetic_scene(seed=50 + s, n_ridges=1, duration=1.2) for s in range(2)])
    rows = hidden_size_study(ts, scorer, sizes=(2, 3), maxiter=4, candidates=2, checkpoint_every=2, progress=False)
    assert [r["n_hidden"] for r in rows] == [2, 3]
    for r in rows:
        assert {"seconds", "iterations", "seed", "detection_rate", "false_alarm_rate", "score"} <= set(r)
        assert r["seed"] in (0, 1) and 1 <= r["iterations"] <= 4
    # The study's row for a size is the build's selection for that size.
    w, k, scores = train_selected(ts, 3, 4, 0, 2, 2, scorer, progress=False)
    assert scores[k] == {key: rows[1][key] for key in scores[k]}
    assert w.n_hidden == 3


def test_training_checkpoints_reach_the_callback():
    ts = make_training_set([synthetic_scene(seed=s, n_ridges=1, duration=1.2) for s in range(2)])
    seen = []
    w = train_detector(ts, n_hidden=3, maxiter=6, seed=0, progress=False,
                       callback=lambda it, wk: seen.append((it, wk)), callback_every=2)
    assert [it for it, _ in seen] == [2, 4, 6][:len(seen)] and len(seen) >= 2
    assert all(wk.metadata["training"]["checkpoint"] for _, wk in seen)
    if w.metadata["training"]["iterations"] == 6:  # the last checkpoint is the final iterate
        np.testing.assert_array_equal(seen[-1][1].params.pack(), w.params.pack())
    with pytest.raises(TypeError, match="callback must be callable"):
        train_detector(ts, n_hidden=3, maxiter=1, progress=False, callback=3)
    with pytest.raises(ValueError, match="callback_every"):
        train_detector(ts, n_hidden=3, maxiter=1, progress=False, callback=print, callback_every=0)


def test_figure10_on_synthetic_scenes(synthetic_detectors, tmp_path):
    pytest.importorskip("matplotlib")
    import matplotlib

    matplotlib.use("Agg")
    det = synthetic_detectors[0]
    a = synthetic_scene(seed=5, n_ridges=1, stops=[], slide_speed=1.0, mu=0.9)
    b = synthetic_scene(seed=5, n_ridges=1, stops=[(1.0, 1.05)], slide_speed=1.0, mu=0.9)
    d = figure10_data(det, b)
    assert d["slip_time"] is not None and d["y_slip"].shape == d["t"].shape
    fig = figure10(det, a, b)
    fig.savefig(tmp_path / "fig10.png")
    assert (tmp_path / "fig10.png").stat().st_size > 1000


# -- the shipped detector on the simulated paper scenes (Figure 10 (a), (b)) -------------------

@pytest.fixture(scope="module")
def paper_results():
    scenes = pytest.importorskip("tactile_mirror.scenes")
    import tactile_mirror

    if not hasattr(scenes, "paper") or not hasattr(tactile_mirror, "simulate"):
        pytest.skip("contact simulation not available")
    return {name: tactile_mirror.simulate(scenes.paper(name)) for name in ("fig6", "fig7", "fig8")}


@pytest.fixture(scope="module")
def default_detector():
    """The paper's Jordan net (``SlipDetector.paper()``): the net of the paper's Fig. 10
    (``default()`` is the filter-bank net, which won on the held-out set)."""
    try:
        det = SlipDetector.paper()
    except FileNotFoundError:
        pytest.skip("bundled detector weights missing")
    assert det.kind == "jordan"
    return det


# -- training targets and noise copies on simulated scenes --------------------------------------


def test_load_ratio_target_follows_the_tangential_load(paper_results):
    from tactile_mirror.detector import targets_from_result

    r = paper_results["fig6"]
    t = np.asarray(r.t)
    ys, yp = targets_from_result(r)  # load_ratio, pred_scale 0.8
    i_slip = np.flatnonzero(ys[0] >= 1)[0]
    press = t < 0.5
    # the press alone: the edges slide (slip fraction > 0 through most of it; a small zone
    # with a nearly incompressible ridge) but there is no tangential load
    assert np.mean(np.asarray(r.slip_fraction)[0][press] > 0) > 0.5
    assert yp[0][press].max() < 0.02
    # grows with the pull, reaches ~pred_scale at gross slip, 1 while sliding
    pre = yp[0][(t >= 0.6) & (t < t[i_slip])]
    assert np.all(np.diff(pre) > -1e-3)
    assert 0.75 <= yp[0][i_slip - 1] <= 0.8 + 1e-12
    assert np.all(yp[0][ys[0] >= 1] == 1.0)
    # the old target: the slip zone of the press already counts as "slip coming"
    _, yz = targets_from_result(r, pred_target="slip_zone")
    assert yz[0][np.searchsorted(t, 0.49)] > 5 * yp[0][press].max()
    with pytest.raises(ValueError, match="pred_target"):
        targets_from_result(r, pred_target="zone")


def test_augment_noise_copies(paper_results):
    from tactile_mirror.lab.detector import augment_noise

    r = paper_results["fig7"]
    a = augment_noise([r], copies=3, noise=(1e-3, 2e-3), seed=4)
    b = augment_noise([r], copies=3, noise=(1e-3, 2e-3), seed=4)
    assert len(a) == 3
    clean_v, _ = r.scene.circuit.simulate(r.stress, r.fs)
    levels = []
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.v_out, y.v_out)  # deterministic for a seed
        assert x.v_out.shape == r.v_out.shape and x.slip_fraction is r.slip_fraction
        levels.append(np.std(x.v_out - clean_v))
    assert all(1e-3 * 0.9 < s < 2e-3 * 1.1 for s in levels)
    assert len(set(np.round(levels, 6))) == 3  # each copy its own noise
    with pytest.raises(ValueError, match="copies"):
        augment_noise([r], copies=0)
    with pytest.raises(ValueError, match="noise"):
        augment_noise([r], noise=(2e-3, 1e-3))


@pytest.mark.parametrize("kwargs, exc, name", [
    ({"copies": 2.5}, TypeError, "copies"), ({"copies": True}, TypeError, "copies"),
    ({"copies": None}, TypeError, "copies"), ({"copies": 0}, ValueError, "copies"),
    ({"noise": 5e-3}, TypeError, "noise"), ({"noise": "low"}, TypeError, "noise"),
    ({"noise": (0.0, float("inf"))}, ValueError, "noise"), ({"noise": (-1e-3, 1e-3)}, ValueError, "noise"),
    ({"noise": (0.0, 1e-3, 2e-3)}, ValueError, "noise"), ({"noise": (2e-3, 1e-3)}, ValueError, "noise"),
])
def test_augment_noise_names_a_bad_count_or_range(kwargs, exc, name):
    from tactile_mirror.lab.detector.augment import augment_noise

    with pytest.raises(exc, match=name):
        augment_noise([object()], **kwargs)  # (refused before the result is read)


@pytest.mark.parametrize("gain_range, exc", [
    (1.5, TypeError), ("ab", TypeError), ((1, 2, 3), ValueError), ((0.0, 1.0), ValueError),
    ((-1.0, 1.0), ValueError), ((0.6, float("inf")), ValueError), ((1.7, 0.6), ValueError),
    ((True, 2.0), TypeError),
])
def test_augment_gains_names_a_bad_range(gain_range, exc):
    from tactile_mirror.lab.detector.augment import augment_gains

    with pytest.raises(exc, match="gain_range"):
        augment_gains(object(), gain_range)


def test_augment_gains_names_what_is_not_a_training_set():
    from tactile_mirror.lab.detector.augment import augment_gains

    with pytest.raises(TypeError, match="ts must be a TrainingSet"):
        augment_gains(None, (0.6, 1.7))


def test_onset_kinds_and_detection_by_onset(paper_results, default_detector):
    import tactile_mirror
    from tactile_mirror import scenes
    from tactile_mirror.lab.detector.evaluation import detection_by_onset, onset_kinds

    no_slip = tactile_mirror.simulate(scenes.paper("fig6", duration=1.0))
    # fig6 ends in a release of stored shear (the -1e8 Pa/s^2 spike of Fig. 10a)
    assert onset_kinds([paper_results["fig6"], no_slip]) == ["release", None]
    assert onset_kinds([paper_results["fig6"]], level=1e12) == ["gradual"]
    by = detection_by_onset(default_detector, [paper_results["fig6"], paper_results["fig7"]])
    assert by["release"] == (2, 1.0) and by["gradual"][0] == 0


def test_onset_kinds_checks_its_window_and_level_first():
    """A window that is not a pair, reversed or NaN was a TypeError or numpy's "zero-size
    array" deep inside; now the window is checked before any result is read."""
    from tactile_mirror.lab.detector.evaluation import onset_kinds

    for window, exc in ((5, TypeError), ("ab", TypeError), ((0.005, -0.003), ValueError),
                        ((float("nan"), 0.0), ValueError), ((0.001, 0.005), ValueError),
                        ((-0.003, 0.0, 0.005), ValueError)):
        with pytest.raises(exc, match="window"):
            onset_kinds([object()], window=window)
    for level, exc in ((float("nan"), ValueError), (-1.0, ValueError), ("1e8", TypeError)):
        with pytest.raises(exc, match="level"):
            onset_kinds([object()], level=level)
    assert onset_kinds([], window=(0.0, 0.0)) == []


def test_default_detector_metadata(default_detector):
    md = default_detector.metadata
    assert md["features"] in ("stress_rate", "circuit")
    assert default_detector.fs > 0 and md["feedback"] is True
    assert "training" in md and "evaluation" in md


def _first(mask, t):
    idx = np.flatnonzero(mask)
    return t[idx[0]] if idx.size else None


def test_figure10a_no_stop(default_detector, paper_results):
    d = figure10_data(default_detector, paper_results["fig6"])
    t, ys, yp, ts = d["t"], d["y_slip"], d["y_pred"], d["slip_time"]
    assert ts is not None
    t_cross = _first(ys >= 0.8, t)
    assert t_cross is not None and ts - 1e-9 <= t_cross <= ts + 0.02  # crosses only at slip
    # y_pred rises before y_slip: low in the press (no tangential load), high 100 ms before the slip.
    i_before = np.searchsorted(t, ts - 0.1)
    assert yp[i_before] >= 0.5 and ys[i_before] < 0.8
    assert yp[i_before] > yp[np.searchsorted(t, 0.45)] + 0.2


def test_stop_at_A_is_not_judged_slip(default_detector, paper_results):
    d = figure10_data(default_detector, paper_results["fig7"], stops=[(1.00, 1.05)])
    t, ys, ts = d["t"], d["y_slip"], d["slip_time"]
    assert ts is not None
    assert np.all(ys[t < ts] < 0.8)  # not during the stop, nor anywhere before the slip
    t_cross = _first(ys >= 0.8, t)
    assert t_cross is not None and t_cross <= ts + 0.02


def test_figure10b_stop_at_B(default_detector, paper_results):
    d = figure10_data(default_detector, paper_results["fig8"], stops=[(1.40, 1.45)])
    t, ys, yp, ts = d["t"], d["y_slip"], d["y_pred"], d["slip_time"]
    assert ts is not None
    assert np.all(ys[t < ts] < 0.8)  # not during the stop at B, nor anywhere before the slip
    t_cross = _first(ys >= 0.8, t)
    assert t_cross is not None and t_cross <= ts + 0.02
    assert yp[np.searchsorted(t, ts - 0.1)] >= 0.5


def test_figure10_image(default_detector, paper_results, tmp_path):
    pytest.importorskip("matplotlib")
    import matplotlib

    matplotlib.use("Agg")
    fig = figure10(default_detector, paper_results["fig6"], paper_results["fig8"], stops_b=[(1.40, 1.45)])
    fig.savefig(tmp_path / "fig10.png")
    assert (tmp_path / "fig10.png").stat().st_size > 1000


def test_calibrate_slip_moves_the_decision_point_exactly(paper_results):
    """calibrate_slip shifts y_slip's output bias only: the calibrated net's y_slip >= 0.8
    alarms on exactly the samples where the original's y_slip reaches the threshold it
    found, y_pred is untouched, and the calibration is recorded."""
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector.calibration import calibrate_slip

    bank = SlipDetector.bank()
    before = (bank.weights.params.b2.copy(), dict(bank.weights.metadata.get("slip_calibration") or {}))
    val = [paper_results["fig7"], paper_results["fig8"]]
    w, info = calibrate_slip(bank.weights, val, 0.5, scenes="fig7, fig8")
    assert w.metadata["slip_calibration"] == info and info["validation"] == "fig7, fig8"
    # the input is not changed
    np.testing.assert_array_equal(bank.weights.params.b2, before[0])
    assert dict(bank.weights.metadata.get("slip_calibration") or {}) == before[1]
    p0, p1 = bank.weights.params, w.params
    for name in ("w1", "b1", "w2"):
        np.testing.assert_array_equal(getattr(p0, name), getattr(p1, name))
    assert p1.b2[1] == p0.b2[1] and p1.b2[0] == p0.b2[0] + info["b2_shift"]
    x = features_from_result(paper_results["fig6"], bank.features)
    ys0, _, yp0 = bank.run(x)
    ys1, _, yp1 = SlipDetector(w).run(x)
    np.testing.assert_array_equal(yp0, yp1)
    t = info["threshold"]
    near = np.abs(ys0 - t) < 1e-9  # ties at the threshold itself may round either way
    np.testing.assert_array_equal((ys1 >= 0.8)[~near], (ys0 >= t)[~near])


def test_calibration_per_condition_keeps_every_condition_within_its_bound(paper_results):
    """calibrate_slip(conditions=...) picks the lowest threshold that keeps each sensor
    condition's false alarms on the validation scenes within its own bound: the largest of
    the per-condition thresholds, recomputed here from the same noisy copies; uncalibrate
    gives the net as trained back, bit for bit."""
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector.calibration import calibrate_slip, uncalibrate
    from tactile_mirror.lab.detector.evaluation import (
        NOISE_CONDITIONS,
        condition_estimator,
        noise_free,
        onset_kinds,
        with_noise,
    )
    from tactile_mirror.lab.detector.thresholds import roc

    bank = SlipDetector.bank()
    raw = uncalibrate(bank.weights)
    assert "slip_calibration" not in raw.metadata and "slip_calibration" in bank.weights.metadata
    shift = bank.weights.metadata["slip_calibration"]["b2_shift"]
    np.testing.assert_allclose(raw.params.b2[0] + shift, bank.weights.params.b2[0], rtol=0, atol=1e-15)
    val = [paper_results["fig6"], paper_results["fig7"], paper_results["fig8"]]
    bounds = {"noise-free": 0.5, "1 mV rms white": 0.7}
    w, info = calibrate_slip(raw, val, None, conditions=bounds, seed=11)
    assert set(info["conditions"]) == set(bounds) and info["noise_seed"] == 11
    det0 = SlipDetector(raw)
    clean = noise_free(val)
    thresholds = []
    for k, (name, fa) in enumerate(bounds.items()):
        x = clean if k == 0 else with_noise(clean, name, 11 + k)
        scores = [det0.run(features_from_result(r, det0.features, estimator=condition_estimator(det0, name)),
                           fs=r.fs)[0] for r in x]
        curve = roc(scores, val, onset_kinds(val))
        thresholds.append(curve.at_false_alarm(fa)["threshold"])
        at = curve.at_threshold(info["threshold"])
        assert at["false_alarm_rate"] <= fa + 1e-12
        assert info["conditions"][name]["validation_false_alarm"] == at["false_alarm_rate"]
    assert info["threshold"] == pytest.approx(min(max(max(thresholds), 1e-6), 1 - 1e-6), abs=0)
    # the shift is relative to the net as trained
    assert w.params.b2[0] == raw.params.b2[0] + info["b2_shift"]
    with pytest.raises(ValueError, match="unknown condition"):
        calibrate_slip(raw, val, None, conditions={"2 mV": 0.01})
    with pytest.raises(ValueError, match="noise-free"):
        calibrate_slip(raw, val, None, conditions={"noise-free": True})
    with pytest.raises(ValueError, match="false_alarm or conditions"):
        calibrate_slip(raw, val, None)
    assert set(NOISE_CONDITIONS) >= set(bounds)


def test_noise_conditions_add_what_they_name(paper_results):
    """noise_free removes a scene's own noise (its stresses through its circuit);
    with_noise adds the condition's noise, seeded: white 1 mV rms on both outputs."""
    from tactile_mirror.lab.detector.evaluation import noise_free, with_noise

    r = paper_results["fig6"]
    clean = noise_free([r])[0]
    v, u = r.scene.circuit.simulate(r.stress, r.fs)
    np.testing.assert_array_equal(clean.v_out, v)
    np.testing.assert_array_equal(clean.u_out, u)
    a = with_noise([clean], "1 mV rms white", seed=3)[0]
    b = with_noise([clean], "1 mV rms white", seed=3)[0]
    c = with_noise([clean], "1 mV rms white", seed=4)[0]
    np.testing.assert_array_equal(a.v_out, b.v_out)
    assert not np.array_equal(a.v_out, c.v_out)
    for got, ref in ((a.v_out, clean.v_out), (a.u_out, clean.u_out)):
        d = np.asarray(got) - np.asarray(ref)
        assert abs(d.std() - 1e-3) < 0.05e-3 and abs(d.mean()) < 0.05e-3
    hum = with_noise([clean], "thermal + 2 mV 50 Hz hum, notch", seed=3)[0]
    d = np.asarray(hum.v_out) - np.asarray(clean.v_out)
    spec = np.abs(np.fft.rfft(d.reshape(-1, d.shape[-1])[0]))  # (ridges, strips, samples)
    f = np.fft.rfftfreq(d.shape[-1], 1.0 / r.fs)
    assert f[np.argmax(spec[1:]) + 1] == pytest.approx(50.0, abs=1.0)  # the hum's fundamental dominates
    with pytest.raises(ValueError, match="condition"):
        with_noise([clean], "3 mV", seed=0)


def test_build_options_check_the_calibration_conditions():
    from tactile_mirror.lab.detector.build_options import BuildOptions

    o = BuildOptions(calibrate_conditions={"noise-free": 0.015, "1 mV rms white": 0.025})
    assert o.calibrate_conditions == {"noise-free": 0.015, "1 mV rms white": 0.025}
    for bad, msg in (({}, "non-empty"), ({"pink": 0.01}, "unknown condition"), ({"noise-free": 1.5}, "noise-free"),
                     ({"noise-free": True}, "noise-free")):
        with pytest.raises(ValueError, match=msg):
            BuildOptions(calibrate_conditions=bad)
    with pytest.raises(ValueError, match="not both"):
        BuildOptions(calibrate_fa=0.01, calibrate_conditions={"noise-free": 0.01})
    with pytest.raises(ValueError, match="validation scenes"):
        BuildOptions(calibrate_conditions={"noise-free": 0.01}, candidates=1, checkpoint_every=0)


@pytest.mark.parametrize("bad", [0.0, 1.0, -0.1, True, "0.02"])
def test_build_options_refuse_a_bad_calibration_rate(bad):
    from tactile_mirror.lab.detector.build_options import BuildOptions

    with pytest.raises(ValueError, match="calibrate_fa"):
        BuildOptions(calibrate_fa=bad)
    with pytest.raises(ValueError, match="calibrate_fa"):
        BuildOptions(calibrate_fa=0.02, candidates=1, checkpoint_every=0)


def test_scorer_at_false_alarm_scores_the_curve_not_the_threshold(synthetic_detectors):
    """A net calibrated afterwards is scored by its curve: shifting y_slip's bias moves the
    threshold-0.8 score but not the detection at a false-alarm rate."""
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector.selection import ValidationScorer
    from tactile_mirror.lab.detector.thresholds import roc

    det, _, _ = synthetic_detectors
    val = [synthetic_scene(seed=3000 + s, n_ridges=1) for s in range(4)]
    val += [synthetic_scene(seed=3100 + s, n_ridges=1, stop_before_slip=True) for s in range(2)]
    scorer = ValidationScorer(val, at_false_alarm=0.2)
    s0 = scorer(det.weights)
    scores = [det.run(features_from_result(r, det.features, estimator=det.metadata.get("estimator")),
                      fs=r.fs)[0] for r in val]
    expect = roc(scores, val).at_false_alarm(0.2)["detection_rate"]
    assert s0["score"] == s0["detection_at_false_alarm"] == expect
    shifted = det.weights.params.copy()
    shifted.b2[0] -= 15.0  # a monotone map of y_slip: the same curve, another threshold-0.8 point
    w_shift = type(det.weights)(shifted, det.weights.input_mean, det.weights.input_scale, det.weights.fs,
                                det.metadata)
    s1 = scorer(w_shift)
    assert s1["score"] == s0["score"]
    assert s1["false_alarm_rate"] < s0["false_alarm_rate"]  # the threshold score did move
    assert ValidationScorer(val)(det.weights)["score"] != s0["score"]
    for bad in (1.0, -0.1, True, "0.02"):
        with pytest.raises(ValueError, match="at_false_alarm"):
            ValidationScorer(val, at_false_alarm=bad)


def test_uncalibrate_undoes_a_threshold_only_record():
    """The pad net records only the threshold its y_slip >= 0.8 stands for: uncalibrate
    shifts b2[0] back so that the raw net's y_slip crosses that threshold where the bundled
    net crosses 0.8; a record with neither field, or a threshold outside (0, 1), is refused."""
    import copy

    import tactile_mirror as tm
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector.calibration import uncalibrate

    pad = SlipDetector.pad()
    t = pad.weights.metadata["slip_calibration"]["threshold"]
    assert "b2_shift" not in pad.weights.metadata["slip_calibration"]
    raw = uncalibrate(pad.weights)
    assert "slip_calibration" not in raw.metadata
    res = tm.simulate(tm.scenes.paper("fig6"))
    f = features_from_result(res)
    ys_cal = pad.run(f, fs=res.fs)[0]
    ys_raw = SlipDetector(raw).run(f, fs=res.fs)[0]
    # logit(y_raw) + shift == logit(y_cal): the raw net at t is the calibrated one at 0.8
    np.testing.assert_allclose(np.log(ys_raw / (1 - ys_raw)) + np.log(4.0) - np.log(t / (1 - t)),
                               np.log(ys_cal / (1 - ys_cal)), atol=1e-9)
    bad = copy.deepcopy(pad.weights)
    bad.metadata["slip_calibration"] = {"validation": "x"}
    with pytest.raises(ValueError, match="neither"):
        uncalibrate(bad)
    bad.metadata["slip_calibration"] = {"threshold": 1.5}
    with pytest.raises(ValueError, match="threshold"):
        uncalibrate(bad)


def test_validation_scorer_in_sensor_conditions_scores_their_curves(paper_results):
    """ValidationScorer(conditions=...) scores the threshold sweep in each named condition
    (the scenes' noise-free outputs plus the condition's noise, seeded noise_seed + its place),
    recomputed here from the same noisy copies; the score is the mean detection over them."""
    from tactile_mirror.detector.data_prep import features_from_result
    from tactile_mirror.lab.detector.build_options import BuildOptions
    from tactile_mirror.lab.detector.evaluation import (
        condition_estimator,
        noise_free,
        onset_kinds,
        with_noise,
    )
    from tactile_mirror.lab.detector.selection import ValidationScorer
    from tactile_mirror.lab.detector.thresholds import roc

    bank = SlipDetector.bank()
    val = [paper_results["fig6"], paper_results["fig7"], paper_results["fig8"]]
    names = ("noise-free", "1 mV rms white")
    scorer = ValidationScorer(val, at_false_alarm=0.5, conditions=names, noise_seed=21)
    s = scorer(bank.weights)
    assert set(s["conditions"]) == set(names)
    clean = noise_free(val)
    rates = []
    for k, name in enumerate(names):
        x = clean if k == 0 else with_noise(clean, name, 21 + k)
        scores = [bank.run(features_from_result(r, bank.features, estimator=condition_estimator(bank, name)),
                           fs=r.fs)[0] for r in x]
        p = roc(scores, val, onset_kinds(val)).at_false_alarm(0.5)
        assert s["conditions"][name]["detection_rate"] == p["detection_rate"]
        assert repr(s["conditions"][name]["latency_gradual_ms"]) == repr(p["latency_gradual_ms"])
        assert s["conditions"][name]["false_alarm_rate"] == p["false_alarm_rate"]
        rates.append(p["detection_rate"])
    assert s["score"] == s["detection_at_false_alarm"] == pytest.approx(np.mean(rates), abs=1e-15)
    assert repr(scorer(bank.weights)) == repr(s)  # the cached features give the same scores (NaN latencies too)
    # the scenes' own noise is what the plain scorer uses: another statistic on the same net
    assert "conditions" not in ValidationScorer(val, at_false_alarm=0.5)(bank.weights)
    for kw, msg in (({"conditions": ("pink",)}, "unknown condition"), ({"conditions": ()}, "at least one"),
                    ({"conditions": ("noise-free", "noise-free")}, "twice"),
                    ({"conditions": ("noise-free",), "at_false_alarm": None}, "at_false_alarm")):
        with pytest.raises(ValueError, match=msg):
            ValidationScorer(val, **{"at_false_alarm": 0.5, **kw})
    with pytest.raises(ValueError, match="select_conditions"):
        BuildOptions(select_conditions=("pink",))
    with pytest.raises(ValueError, match="select_fa"):
        BuildOptions(select_fa=1.5)
    with pytest.raises(ValueError, match="needs a false-alarm rate"):
        BuildOptions(select_conditions="noise-free")  # refused before any scene is simulated
    assert BuildOptions(select_conditions="noise-free", select_fa=0.02).select_conditions == ("noise-free",)


def test_the_early_net_is_the_bank_net_trained_for_the_onset_and_chosen_in_the_goals_conditions():
    """SlipDetector.early() ships what docs/detector.md says was built: the bundled bank and
    size, the onset weight, the choice in the goals' conditions and the bundled calibration."""
    early, bank = SlipDetector.early().weights, SlipDetector.bank().weights
    assert early.kind == bank.kind == "jordan_bank"
    assert early.metadata["bank"] == bank.metadata["bank"] and early.n_hidden == bank.n_hidden
    tr = early.metadata["training"]
    assert tr["onset_weight"] == 1.0 and tr["negative_weight"] == 30.0
    sel = tr["selection"]
    assert sel["conditions"] == ["noise-free", "1 mV rms white"] and sel["at_false_alarm"] == 0.02
    assert sel["chosen_score"]["score"] == sel["chosen_score"]["detection_at_false_alarm"] > 0.9
    cal = early.metadata["slip_calibration"]
    assert {k: v["false_alarm_bound"] for k, v in cal["conditions"].items()} == {
        "noise-free": 0.015, "1 mV rms white": 0.025, "thermal + 2 mV 50 Hz hum, notch": 0.025}
    assert all(v["validation_false_alarm"] <= v["false_alarm_bound"] for v in cal["conditions"].values())
    assert not np.array_equal(early.params.pack(), bank.params.pack())
