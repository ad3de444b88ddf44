"""MirrorPipeline (C++ tick) against the scipy + numpy reference, and its contracts."""
from __future__ import annotations

import numpy as np
import pytest
import tactile_mirror as tm
from tactile_mirror import _core
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.detector.core import SlipDetector
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.loop.capi import CAPIError, CPipeline
from tactile_mirror.pipeline import (
    MirrorPipeline,
    NoController,
    PaperController,
    ReferencePipeline,
    VelocityController,
)
from tactile_mirror.pipeline.controller import controller_fields

FS = 1000.0
DBL_MAX = float(np.finfo(np.float64).max)


def weights(h=8, seed=0, fs=FS, features="stress_rate"):
    rng = np.random.default_rng(seed)
    return {"w1": rng.normal(size=(h, 5)), "b1": rng.normal(size=h), "w2": 2 * rng.normal(size=(2, h)),
            "b2": rng.normal(size=2), "input_mean": rng.normal(size=4) * 0.01,
            "input_gain": np.array([3e-3, 3e-3, 3e-5, 3e-5]) if features == "stress_rate" else np.full(4, 5.0),
            "fs": fs, "features": features}


def signals(n, n_inputs, seed=1, scale=0.05):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    base = np.sin(2 * np.pi * 3 * t)[:, None] * np.linspace(0.5, 1.5, n_inputs)[None]
    return scale * (base + 0.3 * rng.normal(size=(n, n_inputs)))


def make(n_ridges=3, use_u=True, controller=None, dtype=np.float64, activation="exact", **kw):
    est = StressRateEstimator(PVDFCircuit(), FS, 2 * n_ridges, use_u=use_u)
    return MirrorPipeline(weights(), FS, n_ridges, estimator=est, controller=controller, dtype=dtype,
                          activation=activation, v_limit=5.0, u_limit=5.0, **kw)


CONTROLLERS = [NoController(), PaperController(threshold=0.4, gain=0.02, arm_delay=0.2),
               VelocityController(threshold=0.3, y_full=0.8, v_max=0.01, a_max=0.5, x_min=-0.004, x_max=0.004),
               VelocityController(threshold=0.3, y_full=0.8, v_max=0.01, a_max=0.5, shear_gain=2e-3,
                                  direction_sign=-1.0, asym_tau=0.2),
               VelocityController(threshold=0.2, y_full=0.7, v_max=0.01, a_max=0.5, shear_gain=2e-3,
                                  asym_tau=0.2, ramp_gain=0.0, pred_boost=2.0)]


@pytest.mark.parametrize("use_u", [True, False])
@pytest.mark.parametrize("controller", CONTROLLERS,
                         ids=["none", "paper", "velocity", "velocity-shear", "velocity-boosted-shear"])
def test_matches_reference(use_u, controller):
    pipe = make(use_u=use_u, controller=controller)
    x = signals(1500, pipe.n_inputs)
    x[300, 2] = np.nan
    x[700, 0] = 9.0  # beyond v_limit
    out, acc = pipe.process_block(x, accepted=True)
    ref = ReferencePipeline(pipe.config).process_block(x)
    assert acc.sum() == 1498 and not acc[300] and not acc[700]
    np.testing.assert_allclose(out[:, 2:], ref[:, 2:], rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[:, :2], ref[:, :2], rtol=1e-9, atol=1e-12)
    if controller.kind != "none":
        assert np.ptp(out[:, 0]) > 0  # the stage was commanded


def test_slip_guard_matches_reference():
    base = {"threshold": 0.2, "y_full": 0.7, "v_max": 0.01, "a_max": 0.5, "shear_gain": 2e-3, "asym_tau": 0.2,
            "ramp_gain": 0.0, "pred_boost": 2.0}
    x = signals(1500, make().n_inputs)
    ys = make(controller=VelocityController(**base)).process_block(x)[0][:, 2::3].max(axis=1)
    thr = float(np.quantile(ys, 0.9))  # "slip" on ~10 % of the ticks
    pipe = make(controller=VelocityController(**base, slip_hold=0.02), slip_threshold=thr)
    (out,) = pipe.process_block(x)
    ref = ReferencePipeline(pipe.config).process_block(x)
    np.testing.assert_allclose(out[:, :2], ref[:, :2], rtol=1e-9, atol=1e-12)
    slip = out[:, 2::3].max(axis=1) >= thr
    assert 0 < slip.sum() < slip.size
    speed = np.abs(out[:, 1])
    assert speed.max() > 0
    k = np.flatnonzero(slip[1:] & slip[:-1]) + 1
    assert np.all(speed[k] <= speed[k - 1] + 1e-15)  # held: only decelerating while slipping


def test_raw_circuit_features():
    w = weights(features="circuit")
    pipe = MirrorPipeline(w, FS, 2, use_u=True, controller=PaperController(threshold=0.2), activation="exact")
    x = signals(500, pipe.n_inputs)
    out = pipe.process_block(x)[0]
    ref = ReferencePipeline(pipe.config).process_block(x)
    np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(pipe.features[:, :2], x[-1, :4].reshape(2, 2))


@pytest.mark.parametrize("dtypes", [(np.float32, None), (np.float64, np.float32)], ids=["f32", "mixed"])
def test_float32_close_to_reference(dtypes):
    pipe = make(dtype=dtypes[0], detector_dtype=dtypes[1], controller=CONTROLLERS[2], activation="fast")
    x = signals(1000, pipe.n_inputs)
    out = pipe.process_block(x)[0]
    ref = ReferencePipeline(pipe.config).process_block(x)
    np.testing.assert_allclose(out[:, 2:], ref[:, 2:], atol=2e-3)
    assert pipe.dtype == dtypes[0] and pipe.detector_dtype == np.float32
    with pytest.raises(TypeError, match="detector_dtype"):
        make(dtype=np.float32, detector_dtype=np.float64)


def test_step_equals_block_bit_for_bit():
    pipe = make(controller=CONTROLLERS[2], activation="fast")
    x = signals(400, pipe.n_inputs)
    x[50, 1] = np.inf
    block = pipe.process_block(x)[0]
    pipe.reset()
    o = np.zeros(pipe.n_outputs)
    steps = np.empty_like(block)
    for k in range(len(x)):
        cmd = pipe.step(np.ascontiguousarray(x[k]), o)
        assert cmd == o[0]
        steps[k] = o
    assert np.array_equal(steps.view(np.uint64), block.view(np.uint64))
    np.testing.assert_array_equal(pipe.outputs, block[-1])
    pipe.reset()
    parts = [pipe.process_block(c)[0] for c in np.array_split(x, [1, 7, 200])]
    assert np.array_equal(np.concatenate(parts), block)


def test_rejected_tick_keeps_state():
    pipe = make(controller=None)
    x = signals(300, pipe.n_inputs)
    clean = pipe.process_block(x)[0]
    pipe.reset()
    bad = np.insert(x, 100, x[100], axis=0)
    bad[100, 4] = np.nan
    out, f, acc = pipe.process_block(bad, features=True, accepted=True)
    assert not acc[100] and acc.sum() == 300
    # the rejected tick held the previous outputs; afterwards the run continues as if it never came
    np.testing.assert_array_equal(out[100], out[99])
    assert np.array_equal(np.delete(out, 100, axis=0), clean)
    np.testing.assert_array_equal(f[100], f[99])
    st = pipe.status
    assert st["rejected"] == 1 and st["nonfinite"] == 1 and st["out_of_range"] == 0
    assert st["last_bad_tick"] == 100 and st["last_bad_channel"] == 4 and st["ticks"] == 301


@pytest.mark.parametrize("shear_gain", [0.0, 1e-2])
def test_fault_after_consecutive_rejections_stops_the_stage(shear_gain):
    ctrl = VelocityController(threshold=0.0, y_full=0.01, v_max=0.01, a_max=1.0, x_min=-1, x_max=1,
                              shear_gain=shear_gain, asym_tau=5.0)
    pipe = make(controller=ctrl, max_hold_ticks=10)
    x = signals(200, pipe.n_inputs)
    pipe.process_block(x)
    v0 = pipe.controller_state["velocity"]
    assert abs(v0) > 0
    nan = np.full((100, pipe.n_inputs), np.nan)
    out = pipe.process_block(nan)[0]
    st = pipe.status
    assert st["fault"] and st["consecutive_rejected"] == 100
    # within max_hold_ticks the command keeps moving, then it decelerates at a_max to rest
    assert abs(out[5, 1]) > 0
    assert out[-1, 1] == 0.0
    ref = ReferencePipeline(pipe.config)
    np.testing.assert_allclose(ref.process_block(np.concatenate([x, nan]))[200:], out, rtol=1e-9, atol=1e-12)
    assert np.all(np.abs(np.diff(out[:, 1])) <= 1.0 / FS + 1e-12)
    pipe.step(np.ascontiguousarray(x[0]))
    assert not pipe.status["fault"]


def test_weights_for_another_rate_are_refused():
    est = StressRateEstimator(PVDFCircuit(), FS, 6)
    with pytest.raises(ValueError, match="trained for"):
        MirrorPipeline(weights(fs=2000.0), FS, 3, estimator=est)
    w = weights()
    args = (3, FS, True, est.sos_rate, est.sos_rate2, None, 5.0, 5.0, w["w1"], w["b1"], w["w2"], w["b2"],
            w["input_mean"], w["input_gain"])
    with pytest.raises(ValueError, match="another sample rate"):
        _core._MirrorPipelineF64(*args, 999.0, "exact", 0.8, 10, {})


@pytest.mark.parametrize("kwargs, match", [
    ({"n_ridges": 0}, "n_ridges"),
    ({"sos_v": np.ones((2, 5))}, "sos_v"),
    ({"controller": {"kind": "velocity", "v_max": -1.0}}, "v_max"),
    ({"controller": {"kind": "paper", "gain": -1.0}}, "gain"),
    ({"controller": {"kind": "paper", "threshold": 1.5}}, "threshold"),
    ({"controller": {"kind": "velocity", "threshold": 0.5, "y_full": 0.4}}, "y_full"),
    ({"controller": {"kind": "paper", "x_min": 0.01}}, "bracket"),
    ({"controller": {"kind": "paper", "direction_sign": 2.0}}, "direction_sign"),
    ({"controller": {"kind": "magic"}}, "kind"),
    ({"controller": {"kind": "velocity", "shear_gain": -1.0}}, "shear_gain"),
    ({"controller": {"kind": "velocity", "ramp_gain": -0.5}}, "ramp_gain"),
    ({"controller": {"kind": "velocity", "pred_boost": float("nan")}}, "pred_boost"),
    ({"controller": {"kind": "paper", "slip_hold": -0.1}}, "slip_hold"),
    ({"controller": {"kind": "paper", "arm_delay": -1.0}}, "arm_delay"),
    ({"v_limit": -1.0}, "v_limit"),
    ({"slip_threshold": 1.5}, "slip_threshold"),
    ({"max_hold_ticks": -3}, "max_hold_ticks"),
    ({"max_hold_ticks": 2**70}, "max_hold_ticks"),
    ({"activation": "slow"}, "activation"),
])
def test_bad_configuration_names_the_argument(kwargs, match):
    est = StressRateEstimator(PVDFCircuit(), FS, 6)
    base = {"n_ridges": 3}
    base.update(kwargs)
    n = base.pop("n_ridges")
    if "sos_v" in base:
        base.update(sos_u=est.sos_rate2)
    else:
        base["estimator"] = est
    with pytest.raises(ValueError, match=match):
        MirrorPipeline(weights(), FS, n, **base)


def test_core_validates_controller_itself():
    est = StressRateEstimator(PVDFCircuit(), FS, 2)
    w = weights()
    args = (1, FS, True, est.sos_rate, est.sos_rate2, None, 5.0, 5.0, w["w1"], w["b1"], w["w2"], w["b2"],
            w["input_mean"], w["input_gain"], FS, "exact", 0.8, 10)
    for bad in ({"kind": "velocity", "a_max": 0.0}, {"kind": "paper", "asym_tau": -1.0},
                {"kind": "paper", "x_max": float("nan")}, {"nonsense": 1.0}):
        with pytest.raises(ValueError):
            _core._MirrorPipelineF64(*args, bad)


def test_step_arguments_checked_and_state_unchanged():
    pipe = make()
    x = np.ascontiguousarray(signals(1, pipe.n_inputs)[0])
    pipe.step(x)
    before = (pipe.status, pipe.outputs.copy())
    with pytest.raises(TypeError, match="float64"):
        pipe.step(x.astype(np.float32))
    with pytest.raises(ValueError, match="shape"):
        pipe.step(x[:-1])
    with pytest.raises(ValueError, match="contiguous"):
        pipe.step(np.repeat(x, 2)[::2])
    with pytest.raises(TypeError):
        pipe.step(list(x))
    ro = np.zeros(pipe.n_outputs)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="writeable"):
        pipe.step(x, ro)
    with pytest.raises(ValueError, match="shape"):
        pipe.process_block(np.zeros((5, pipe.n_inputs + 1)))
    assert pipe.status == before[0]
    np.testing.assert_array_equal(pipe.outputs, before[1])
    with pytest.raises(ValueError):
        pipe.outputs[0] = 1.0


def test_velocity_law_respects_limits():
    ctrl = VelocityController(threshold=0.1, y_full=0.5, v_max=0.02, a_max=0.5, x_min=-0.01, x_max=0.005)
    n = 3000
    x, v = ctrl.run(np.full(n, 0.9), np.full(n, 1.0), FS)
    assert np.all(np.abs(v) <= 0.02 + 1e-15)
    assert np.all(np.abs(np.diff(v)) <= 0.5 / FS + 1e-12)
    assert x.max() <= 0.005 and x[-1] == pytest.approx(0.005, abs=1e-5)
    assert abs(v[-1]) < 1e-3
    # shear feedback alone moves the stage against the asymmetry's sign convention
    xs, vs = VelocityController(threshold=0.5, y_full=0.9, shear_gain=0.01).run(np.zeros(50), np.full(50, 1.0), FS)
    assert xs[-1] > 0 and np.all(np.abs(vs) <= 0.02)
    # direction follows the asymmetry, and direction_sign flips it
    xm, _ = VelocityController(direction_sign=-1).run(np.full(100, 0.9), np.full(100, 1.0), FS)
    assert xm[-1] < 0


def test_paper_law_displacement_proportional_to_y_pred():
    ctrl = PaperController(threshold=0.5, gain=0.01)
    y = np.array([0.2, 0.6, 0.9, 0.4, 1.0])
    x, v = ctrl.run(y, np.ones(5), FS)
    steps = np.diff(np.concatenate([[0.0], x]))
    np.testing.assert_allclose(steps, [0, 0.6e-5, 0.9e-5, 0, 1e-5], atol=1e-18)
    np.testing.assert_allclose(v, steps * FS)


def test_reset_position_and_timing_restore_state():
    pipe = make(controller=CONTROLLERS[1])
    x = signals(300, pipe.n_inputs)
    a = pipe.process_block(x)[0]
    st = pipe.status
    ns = pipe.time_step_ns(2000, 1)
    assert ns > 0
    assert pipe.status == st
    b = pipe.process_block(x)[0]
    pipe.reset()
    pipe.process_block(x)
    c = pipe.process_block(x)[0]
    np.testing.assert_array_equal(b, c)
    pipe.reset(0.002)
    assert pipe.outputs[0] == 0.002 and pipe.outputs[3] == 1.0
    pipe.set_position(-0.001)
    assert pipe.controller_state["position"] == -0.001
    assert a.shape == (300, pipe.n_outputs)


def test_from_config_round_trip():
    pipe = make(controller=CONTROLLERS[2], activation="fast")
    other = MirrorPipeline.from_config(pipe.config)
    x = signals(200, pipe.n_inputs)
    assert np.array_equal(pipe.process_block(x)[0], other.process_block(x)[0])
    assert "MirrorPipeline(n_ridges=3" in repr(other)
    assert "filters" in other.simd_path
    partial = {k: v for k, v in pipe.config.items() if k != "w1"}
    with pytest.raises(ValueError, match="config lacks w1"):
        MirrorPipeline.from_config(partial)


# -- limits, overflow and refused samples (through pybind11 and the C ABI) ------------------------

def test_default_limits_are_the_front_end_swing_and_infinite_limits_are_refused(fast_pipeline):
    p = fast_pipeline(VelocityController(shear_gain=1e-4))
    assert p.config["v_limit"] == p.config["u_limit"] == 15.0
    for bad in (np.inf, np.nan, -1.0):
        with pytest.raises(ValueError, match="v_limit"):
            fast_pipeline(v_limit=bad)
    cfg = fast_pipeline().config
    cfg["v_limit"] = np.inf
    with pytest.raises(ValueError, match="v_limit"):
        CPipeline(cfg)  # checked in Python first
    with pytest.raises(CAPIError) as e:
        CPipeline(cfg, check=False)  # and by the C ABI itself
    assert e.value.code == -3 and "v_limit" in str(e.value)


@pytest.mark.parametrize("backend", ["pybind", "capi"])
@pytest.mark.parametrize("limit", [None, DBL_MAX], ids=["default", "dbl_max"])
@pytest.mark.parametrize("net", ["jordan", "jordan_bank"])
def test_one_huge_sample_does_not_poison_the_loop(backend, limit, net, fast_pipeline, wave_signals):
    """The issue's case: one sample of 1.7e308 V. With the default limits it is out
    of range; with no limit (DBL_MAX) the update overflows and the tick is rejected
    as such (for the filter-bank net, its bank's states too). Either way every later
    output is finite and equals the run without it."""
    kw = {} if limit is None else {"v_limit": limit, "u_limit": limit}
    if net == "jordan_bank":
        kw["detector"] = SlipDetector.bank()
    p = fast_pipeline(VelocityController(shear_gain=1e-4), **kw)
    clean = fast_pipeline(VelocityController(shear_gain=1e-4), **kw)
    if backend == "capi":
        p = CPipeline(p.config)
        clean = CPipeline(clean.config)
    x = wave_signals(600, p.n_inputs)
    x[100, 0] = 1.7e308
    x[101, :12:2] = 1.7e308   # L strips up, R strips down: the L-R asymmetry overflows
    x[101, 1:12:2] = -1.7e308
    out, acc = p.process_block(x, accepted=True)
    assert np.all(np.isfinite(out))
    s = p.status
    assert s["rejected"] == np.count_nonzero(~acc) >= 1
    assert s["rejected"] == s["nonfinite"] + s["out_of_range"] + s["overflow"]
    assert s["last_reason"] == ("out_of_range" if limit is None else "overflow")
    assert not s["fault"]
    # the state after a rejected tick is as if the tick never came (controller: the
    # held outputs drive it for that tick, as for a NaN tick)
    x2 = x.copy()
    x2[~acc] = np.nan
    ref, acc2 = clean.process_block(x2, accepted=True)
    np.testing.assert_array_equal(acc, acc2)
    np.testing.assert_array_equal(out, ref)


def test_reference_pipeline_rejects_the_same_overflow(fast_pipeline, wave_signals):
    p = fast_pipeline(VelocityController(shear_gain=1e-4), activation="exact", v_limit=DBL_MAX, u_limit=DBL_MAX)
    ref = ReferencePipeline(p.config)
    x = wave_signals(200, p.n_inputs)
    x[50, :12:2], x[50, 1:12:2] = DBL_MAX, -DBL_MAX
    x[51, :12:2], x[51, 1:12:2] = DBL_MAX, -DBL_MAX
    out = p.process_block(x)[0]
    r = ref.process_block(x)
    assert np.all(np.isfinite(r))
    assert ref.rejected["overflow"] == p.status["overflow"] >= 1
    np.testing.assert_allclose(r, out, rtol=1e-9, atol=1e-12)


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


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_positions_are_refused_on_both_paths(value, fast_pipeline, wave_signals):
    p = fast_pipeline(VelocityController())
    p.process_block(wave_signals(50, p.n_inputs))
    before = (p.controller_state, p.status)
    with pytest.raises(ValueError, match="x0"):
        p.reset(value)
    with pytest.raises(ValueError, match="x"):
        p.set_position(value)
    with pytest.raises(ValueError, match="x0"):
        p._core.reset(value)                # the binding itself refuses too
    with pytest.raises(ValueError, match="x"):
        p._core.set_position(value)
    assert (p.controller_state, p.status) == before
    out = np.zeros(p.n_outputs)
    p.step(np.zeros(p.n_inputs), out)
    assert np.all(np.isfinite(out))
    c = CPipeline(p.config)
    for call in (c.reset, c.set_position):
        with pytest.raises(CAPIError) as e:
            call(value)
        assert e.value.code == -3


def test_process_block_refuses_bool_samples_as_step_does():
    est = tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 4)
    pipe = tm.MirrorPipeline(tm.SlipDetector.default(), 1000.0, 2, estimator=est)
    x = np.zeros((5, pipe.n_inputs), dtype=bool)
    with pytest.raises(TypeError, match="x must hold real numbers"):
        pipe.process_block(x)
    with pytest.raises(TypeError):
        pipe.step(x[0])
    assert pipe.status["ticks"] == 0


def test_time_step_ns_checks_its_counts():
    p = tm.MirrorPipeline(tm.SlipDetector.default(), 1000.0, 1,
                          estimator=tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 2))
    for bad, exc in ((2**63, ValueError), ("10", TypeError), (1.5, TypeError), (0, ValueError)):
        with pytest.raises(exc, match="n_iter"):
            p.time_step_ns(bad, 1)
    assert p.time_step_ns(100, 1) > 0


# -- one definition of the controller parameters --------------------------------------------

def test_controller_dataclasses_take_fields_and_defaults_from_cpp(random_net):
    fields = [f[0] for f in _core.controller_fields()]
    assert list(controller_fields()) == fields
    for cls, kind in [(NoController, "none"), (PaperController, "paper"), (VelocityController, "velocity")]:
        d = _core.controller_defaults(kind)
        obj = cls()
        for k, v in obj.params().items():
            assert d[k] == v, (kind, k)
        law_fields = set(controller_fields(kind))
        assert law_fields <= set(obj.params()) - {"kind"}
    p = MirrorPipeline(random_net, FS, 6, estimator=StressRateEstimator(PVDFCircuit(), FS, 12),
                       controller=VelocityController())
    assert {k: v for k, v in p._core.controller.items()} == {**_core.controller_defaults("velocity")}
