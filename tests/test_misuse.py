"""Impolite use: huge finite samples, refused calls, copies, setters, reads from another
thread, foreign weights and read-only files. Each case was a silent wrong result, a
changed object after an error, or an error naming nothing the caller wrote."""
from __future__ import annotations

import copy
import os
import pickle
import stat
import threading

import numpy as np
import pytest
import tactile_mirror as tm
from scipy import signal
from tactile_mirror.contact import ContactSolver, Pad, ridge_model
from tactile_mirror.detector.weights import DetectorWeights, WeightsError
from tactile_mirror.geometry import RidgeGeometry


def _rates(n_ridges, n, seed=0):
    return np.random.default_rng(seed).normal(0, 1e3, (n_ridges, 4, n))


# ------------------------------------------------------------------ detector state overflow
@pytest.mark.parametrize("make", [lambda: tm.SlipDetector.default(), lambda: tm.SlipDetector.memory(),
                                  lambda: tm.SlipDetector.pad(),
                                  lambda: tm.SlipDetector.default(backend="numpy"),
                                  lambda: tm.SlipDetector.memory(backend="numpy")])
def test_finite_features_that_overflow_a_filter_are_refused_with_the_state_kept(make):
    """1e308 is finite and passed the NaN/Inf check, but the filter bank's leaky integrals
    overflowed to inf and every later output was one constant (NaN in numpy) until reset()."""
    det, ref = make(), make()
    x = _rates(6, 40)
    det.run(x[..., :20])
    ref.run(x[..., :20])
    with pytest.raises(ValueError, match="overflow"):
        det.run(np.full((6, 4, 30), 1e308), reset=False)
    if det.backend == "cpp":
        with pytest.raises(ValueError, match="overflow"):
            for _ in range(200):  # a few ticks in a row: the integrals reach inf
                det.step(np.full((6, 4), 1e308))
    # the state is what it was: the continuation equals the undisturbed detector's
    for a, b in zip(det.run(x[..., 20:], reset=False), ref.run(x[..., 20:], reset=False)):
        np.testing.assert_array_equal(a, b)


def test_float32_detector_names_a_value_beyond_float32():
    det = tm.SlipDetector.default(dtype=np.float32)
    x = _rates(1, 12)
    x[0, 2, 7] = 1e300
    with pytest.raises(ValueError, match="fit float32.*ridge 0, channel 2, sample 7"):
        det.run(x)


def test_numpy_backend_runs_an_empty_block_as_the_compiled_one_does():
    for backend in ("numpy", "cpp"):
        det = tm.SlipDetector.paper(backend=backend)
        det.run(_rates(2, 10))
        ys, yn, yp = det.run(np.zeros((2, 4, 0)), reset=False)
        assert ys.shape == yn.shape == yp.shape == (2, 0)


# ------------------------------------------------------------------ float32 pipeline range
def test_float32_pipeline_refuses_a_sample_beyond_float32_as_out_of_range():
    """With v_limit = 1e308 a float32 pipeline counted 1e300 as accepted while its v filter
    dropped it: the filters fell a tick apart from the detector and controller."""
    def make():
        est = tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 2, dtype=np.float32)
        return tm.MirrorPipeline(tm.SlipDetector.default(), 1000.0, 1, estimator=est, dtype=np.float32,
                                 v_limit=1e308, u_limit=1e308)

    p, ref = make(), make()
    x = np.zeros((8, p.n_inputs))
    x[:, 0] = np.linspace(0, 1, 8)
    p.process_block(x)
    ref.process_block(x)
    bad = x[-1].copy()
    bad[0] = 1e300
    p.step(bad)
    assert not p.last_accepted
    assert p.status["out_of_range"] == 1
    # a rejected tick holds: the next ticks match a pipeline that saw the same hold
    ref.step(np.full(ref.n_inputs, np.nan))
    np.testing.assert_array_equal(p.process_block(x)[0], ref.process_block(x)[0])


# ------------------------------------------------------------------ SosFilter held output
def test_a_refused_block_keeps_the_held_output_step_returns():
    f = tm.SosFilter(signal.butter(2, 0.2, "highpass", output="sos"))
    held = f.process(np.ones((1, 5)))[0, -1]
    with pytest.raises(ValueError, match="unchanged"):
        f.process(np.array([[1.7e308, -1.7e308, 1.7e308]]))
    assert f.step(np.array([np.nan]))[0] == held
    # after a step refused for overflow, an accepted block's last output is the held one
    f.step(np.array([1.7e308]))
    y = f.process(np.array([[0.5, 0.25]]))
    assert f.step(np.array([np.nan]))[0] == y[0, -1]


def test_estimator_errors_say_which_input_was_refused():
    est = tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 2)
    v = np.zeros((2, 5))
    with pytest.raises(ValueError, match="^u: "):
        est.process(v, np.full((2, 5), np.inf))
    with pytest.raises(ValueError, match="^v: "):
        est.process(np.full((2, 5), np.nan), v)
    with pytest.raises(ValueError, match="^u_out contains"):
        tm.estimate_stress_rate(np.zeros((1, 50)), np.full((1, 50), np.inf), tm.PVDFCircuit(), 1000.0)
    with pytest.raises(ValueError, match="^v_out contains"):
        tm.estimate_stress_rate(np.full((1, 50), np.nan), None, tm.PVDFCircuit(), 1000.0)


# ------------------------------------------------------------------ contact parameters
@pytest.fixture(scope="module")
def model():
    return ridge_model(RidgeGeometry())


@pytest.mark.parametrize("backend", ["cpp", "python"])
def test_contact_setters_check_and_keep_every_parameter_on_a_refusal(model, backend):
    s = ContactSolver(model, 1.0, mu_kinetic=0.8, backend=backend)
    before = (s.mu, s.mu_kinetic, s.tol, s.max_iter, s.max_active_set_iter)
    for name, value, exc in (("mu", float("nan"), ValueError), ("mu", -1.0, ValueError),
                             ("mu", 0.5, ValueError),  # below mu_kinetic
                             ("mu_kinetic", 5.0, ValueError), ("mu_kinetic", "0.5", TypeError),
                             ("tol", 0.5, ValueError), ("max_iter", 2**40, ValueError),
                             ("max_iter", 2.5, TypeError), ("max_active_set_iter", -1, ValueError)):
        with pytest.raises(exc, match=name):
            setattr(s, name, value)
        assert (s.mu, s.mu_kinetic, s.tol, s.max_iter, s.max_active_set_iter) == before
    s.mu = 0.9  # and the object still takes good values
    s.set_friction(0.5, 0.4)
    assert (s.mu, s.mu_kinetic) == (0.5, 0.4)
    with pytest.raises(ValueError, match="mu_kinetic"):
        s.set_friction(0.5, 0.6)
    assert (s.mu, s.mu_kinetic) == (0.5, 0.4)
    # NaN friction used to act as infinite friction: no slip where mu = 0.1 slides
    ref = ContactSolver(model, 0.1, backend=backend)
    s.set_friction(0.1)
    for solver in (s, ref):
        solver.reset()
    np.testing.assert_allclose(s.step(0.0, 20e-6).forces, ref.step(0.0, 20e-6).forces, rtol=0, atol=1e-9)


def test_pad_friction_changes_every_ridge_up_and_down(model):
    pad = Pad(model, 0.5, n_ridges=3, mu_kinetic=0.4)
    pad.mu = 1.0  # up: the kinetic coefficient passes the old static one on the way
    assert [(s.mu, s.mu_kinetic) for s in pad.solvers] == [(1.0, 0.8)] * 3
    pad.mu = 0.25
    assert [(s.mu, s.mu_kinetic) for s in pad.solvers] == [(0.25, 0.2)] * 3
    with pytest.raises(ValueError, match="mu"):
        pad.mu = float("inf")
    with pytest.raises(TypeError, match="mu"):
        pad.mu = "0.5"
    assert [(s.mu, s.mu_kinetic) for s in pad.solvers] == [(0.25, 0.2)] * 3


def test_contact_reads_from_another_thread_never_see_the_middle_of_a_follow(model):
    """get_state, solves and events read the kernel while a pad's follow ran without the
    GIL: values from the middle of a call. They are claimed now, as writes are."""
    pad = Pad(model, 0.7, n_ridges=2)
    y = 0.3e-3 * np.sin(np.linspace(0, 6 * np.pi, 6000))
    z = np.full(y.size, 20e-6)
    s0 = pad.solvers[0]
    before = (s0.get_state()["lam"].copy(), s0.solves, s0.events)
    errors, reads = [], []
    t = threading.Thread(target=lambda: pad.follow(y, z))
    t.start()
    while t.is_alive():
        try:
            reads.append((s0.get_state()["lam"].copy(), s0.solves, s0.events))
        except RuntimeError as e:
            errors.append(str(e))
    t.join()
    after = (s0.get_state()["lam"].copy(), s0.solves, s0.events)
    assert all("another thread" in e for e in errors)
    for lam, solves, events in reads:  # a whole state: of before or of after the call
        assert any(np.array_equal(lam, ref[0]) and (solves, events) == ref[1:] for ref in (before, after))
    assert after[1] > before[1]


# ------------------------------------------------------------------ copies
@pytest.mark.parametrize("make", [
    lambda: tm.SosFilter(signal.butter(2, 0.1, output="sos")),
    lambda: tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 2),
    lambda: tm.MirrorPipeline(tm.SlipDetector.default(), 1000.0, 1,
                              estimator=tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 2)),
    lambda: tm.SlipDetector.default(),
    lambda: ContactSolver(ridge_model(RidgeGeometry()), 0.5),
    lambda: Pad(ridge_model(RidgeGeometry()), 0.5, n_ridges=2),
])
def test_objects_with_a_running_state_refuse_copies_naming_their_class(make):
    """copy.copy shared the C++ state (two filters stepping one state); deepcopy and
    pickle named a private class."""
    obj = make()
    name = type(obj).__name__
    for do in (copy.copy, copy.deepcopy, pickle.dumps):
        with pytest.raises(TypeError, match=f"a {name} cannot be"):
            do(obj)
    # what the hint says works
    if isinstance(obj, tm.SlipDetector):
        assert pickle.loads(pickle.dumps(obj.weights)).params.w1.shape == obj.weights.params.w1.shape


# ------------------------------------------------------------------ files
def test_weights_with_a_subnormal_scale_are_refused_at_load_naming_the_file(tmp_path):
    """input_scale = 1e-320 passed "> 0", but the kernel's gain 1 / scale is inf: the first
    run failed naming input_gain, and the numpy backend returned NaN."""
    orig = str(tmp_path / "orig.npz")
    tm.SlipDetector.paper().weights.save(orig)
    with np.load(orig) as f:
        data = dict(f)
    data["input_scale"] = data["input_scale"].copy()
    data["input_scale"][1] = 1e-320
    path = str(tmp_path / "w.npz")
    np.savez(path, **data)
    with pytest.raises(WeightsError, match=r"w\.npz.*input_scale must be positive and normal"):
        DetectorWeights.load(path)


def test_a_read_only_file_is_not_replaced(tmp_path):
    w = tm.SlipDetector.paper().weights
    path = tmp_path / "kept.npz"
    path.write_bytes(b"keep me")
    os.chmod(path, stat.S_IRUSR | stat.S_IRGRP)
    try:
        with pytest.raises(PermissionError, match="read-only"):
            w.save(str(path))
        assert path.read_bytes() == b"keep me"
        assert sorted(os.listdir(tmp_path)) == ["kept.npz"]
    finally:
        os.chmod(path, stat.S_IRUSR | stat.S_IWUSR)


def test_time_step_ns_checks_its_counts():
    p = tm.MirrorPipeline(tm.SlipDetector.default(), 1000.0, 1,
                          estimator=tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 2))
    for bad, exc in ((2**63, ValueError), ("10", TypeError), (1.5, TypeError), (0, ValueError)):
        with pytest.raises(exc, match="n_iter"):
            p.time_step_ns(bad, 1)
    assert p.time_step_ns(100, 1) > 0


def test_a_status_cycle_at_high_friction_ends_in_both_backends(model, monkeypatch):
    """On a 0.6 mm sine at mu = 1 the node statuses cycle at one load point (the quasi-static
    problem has no solution there the law can follow). The compiled kernel raised; the
    Python reference looped for ever, its resolves leading back into the cycle through a
    set that was not their result. Both raise now, at the same point, the state kept."""
    from tactile_mirror.contact import reference_path as S

    y = 0.6e-3 * np.sin(np.linspace(0, 4 * np.pi, 8000))
    z = np.full(y.size, 0.00198)
    c = ContactSolver(model, 1.0)
    c.follow(y[:3686], z[:3686])
    state = c.get_state()
    monkeypatch.setattr(S, "SEEN_CAP", 40)  # (the bound, not its size, is under test: faster)
    messages = []
    for backend in ("cpp", "python"):
        s = ContactSolver(model, 1.0, backend=backend)
        s.set_state(state)
        with pytest.raises(S.ContactConvergenceError, match="cycle") as err:
            s.follow(y[3685:3687], z[3685:3687], stepping="every")
        messages.append(str(err.value).split("(")[0])
        np.testing.assert_array_equal(s.get_state()["lam"], state["lam"])
    assert messages[0] == messages[1]


# ------------------------------------------------------------------ detector evaluation and training
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


def test_force_ratio_fit_refuses_what_it_cannot_fit_on():
    """fit([]) was numpy's "need at least one array to concatenate"; results without a
    tangential load an IndexError."""
    from types import SimpleNamespace

    from tactile_mirror.lab.detector.evaluation import ForceRatioDetector

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


# ------------------------------------------------------------------ figures' ridge index
def test_figures_refuse_a_ridge_the_result_has_not(tmp_path):
    """A ridge index out of range was an IndexError deep inside (or, negative, another ridge
    silently); now a ValueError naming ``ridge``, before anything runs or is drawn."""
    from types import SimpleNamespace

    import matplotlib.pyplot as plt
    from tactile_mirror.lab.detector.figures import figure10, figure10_data
    from tactile_mirror.lab.loop.figures import loop_figure
    from tactile_mirror.lab.plots import contact_scene_figure

    n = 50
    contact = SimpleNamespace(v_out=np.zeros((2, 2, n)), u_out=np.zeros((2, 2, n)), slip_fraction=np.zeros((2, n)))
    ready = SimpleNamespace(features=np.zeros((2, 4, n)), fs=1000.0, t=np.arange(n) / 1000.0)
    loop = SimpleNamespace(log={"v_out": np.zeros((2, 2, n))})
    figures = len(plt.get_fignums())
    for ridge in (2, -1, 99):
        with pytest.raises(ValueError, match=r"ridge must be in \[0, 1\]"):
            contact_scene_figure(contact, ridge=ridge)
        with pytest.raises(ValueError, match="ridge"):
            figure10_data(object(), ready, ridge=ridge)  # (the detector is never reached)
        with pytest.raises(ValueError, match="ridge"):
            figure10(object(), ready, ready, ridge=ridge)
        with pytest.raises(ValueError, match="ridge"):
            loop_figure(loop, tmp_path / "f.png", closed=False, ridge=ridge)
    with pytest.raises(TypeError, match="ridge"):
        contact_scene_figure(contact, ridge=1.0)
    assert len(plt.get_fignums()) == figures and not os.listdir(tmp_path)  # nothing drawn, nothing written


# ------------------------------------------------------------------ ridge counts
def test_a_pad_or_scene_of_more_ridges_than_a_finger_covers_is_refused_by_name(model):
    """Scene(n_ridges=100000) ran out of memory in simulate, with no message."""
    from tactile_mirror.contact import FemPad
    from tactile_mirror.contact.pad import MAX_RIDGES

    for n in (MAX_RIDGES + 1, 100_000):
        with pytest.raises(ValueError, match=f"n_ridges must be at most {MAX_RIDGES}"):
            tm.Scene(n_ridges=n)
        with pytest.raises(ValueError, match="n_ridges"):
            Pad(model, 0.5, n_ridges=n)
        with pytest.raises(ValueError, match="n_ridges"):
            FemPad(n)
    with pytest.raises(TypeError, match="n_ridges"):
        FemPad(6.7)  # (was 6 ridges)
    assert tm.Scene(n_ridges=MAX_RIDGES).n_ridges == MAX_RIDGES


# ------------------------------------------------------------------ the detector build's command line
@pytest.mark.parametrize("argv, option", [
    (["--n-train", "0"], "--n-train"), (["--hidden", "-1"], "--hidden"), (["--candidates", "0"], "--candidates"),
    (["--study", "8", "0"], "--study"), (["--noise-range", "0.002", "0"], "--noise-range"),
    (["--calibrate-fa", "2"], "--calibrate-fa"), (["--kind", "jordan_bank", "--lp-taus", "-1"], "--lp-taus"),
    (["--compress"], "--compress"), (["--negative-weight", "nan"], "--negative-weight"),
    (["--pred-weight", "-1"], "--pred-weight"), (["--onset-weight", "inf"], "--onset-weight"),
    (["--recalibrate", "in.npz", "--calibrate-goals", "0.01", "0.02", "--n-validation", "0"], "--n-validation"),
])
def test_build_command_line_refuses_bad_arguments_with_a_usage_line(argv, option, monkeypatch, capsys):
    """Bad arguments were a traceback (ValueError from BuildOptions, or from the training
    after the scenes were simulated); now argparse's usage line, exit status 2, nothing run."""
    from tactile_mirror.cli import main
    from tactile_mirror.lab.detector import build, calibration

    def never(*args, **kwargs):
        raise AssertionError("the build ran")

    monkeypatch.setattr(build, "build_default", never)
    monkeypatch.setattr(calibration, "recalibrate", never)
    with pytest.raises(SystemExit) as exc:
        main(["train", "--out", "unused.npz", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage:") and f"error: argument {option}" in err and "Traceback" not in err


# ------------------------------------------------------------------ the evaluation module and its function
def test_evaluation_module_is_not_hidden_by_its_function():
    import importlib
    import types

    from tactile_mirror.lab import detector

    module = importlib.import_module("tactile_mirror.lab.detector.evaluation")
    assert isinstance(module, types.ModuleType) and detector.evaluation is module
    assert detector.evaluate is module.evaluate
