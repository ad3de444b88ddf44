"""Bad input at the real-time interfaces: overflowing samples, non-finite positions,
wrong output buffers, non-finite detector features, the controllers' one set of
defaults and the C header's contract (version, struct sizes)."""
from __future__ import annotations

import numpy as np
import pytest
from tactile_mirror import _core
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.detector.core import SlipDetector
from tactile_mirror.detector.network import init_params
from tactile_mirror.detector.weights import DetectorWeights
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.filters import SosFilter
from tactile_mirror.pipeline import MirrorPipeline, PaperController, ReferencePipeline, VelocityController
from tactile_mirror.pipeline.controller import NoController, controller_fields

cffi = pytest.importorskip("cffi")
from tactile_mirror.loop.capi import CAPIError, CPipeline, load, new_config

FS = 1000.0
DBL_MAX = float(np.finfo(np.float64).max)


def weights(h=8, seed=3):
    rng = np.random.default_rng(seed)
    return {"w1": rng.normal(size=(h, 5)), "b1": rng.normal(size=h), "w2": 2 * rng.normal(size=(2, h)),
            "b2": rng.normal(size=2), "input_mean": np.zeros(4),
            "input_gain": np.array([3e-3, 3e-3, 3e-5, 3e-5]), "fs": FS}


def make(controller=None, n_ridges=6, activation="fast", detector=None, **kw):
    est = StressRateEstimator(PVDFCircuit(), FS, 2 * n_ridges, use_u=True)
    return MirrorPipeline(weights() if detector is None else detector, FS, n_ridges, estimator=est,
                          controller=controller, activation=activation, **kw)


def signals(n, ni, seed=2):
    rng = np.random.default_rng(seed)
    return 0.05 * np.sin(np.arange(n)[:, None] * 0.01 * np.arange(1, ni + 1)) + 0.02 * rng.normal(size=(n, ni))


# -- one finite huge sample ---------------------------------------------------------

def test_default_limits_are_the_front_end_swing_and_infinite_limits_are_refused():
    p = make(VelocityController(shear_gain=1e-4))
    assert p.config["v_limit"] == p.config["u_limit"] == 15.0
    for bad in (np.inf, np.nan, -1.0):
        with pytest.raises(ValueError, match="v_limit"):
            make(v_limit=bad)
    cfg = make().config
    cfg["v_limit"] = np.inf
    with pytest.raises(ValueError, match="v_limit"):
        CPipeline(cfg)  # checked in Python first
    with pytest.raises(CAPIError) as e:
        CPipeline(cfg, check=False)  # and by the C ABI itself
    assert e.value.code == -3 and "v_limit" in str(e.value)


@pytest.mark.parametrize("backend", ["pybind", "capi"])
@pytest.mark.parametrize("limit", [None, DBL_MAX], ids=["default", "dbl_max"])
@pytest.mark.parametrize("net", ["jordan", "jordan_bank"])
def test_one_huge_sample_does_not_poison_the_loop(backend, limit, net):
    """The issue's case: one sample of 1.7e308 V. With the default limits it is out
    of range; with no limit (DBL_MAX) the update overflows and the tick is rejected
    as such (for the filter-bank net, its bank's states too). Either way every later
    output is finite and equals the run without it."""
    kw = {} if limit is None else {"v_limit": limit, "u_limit": limit}
    if net == "jordan_bank":
        kw["detector"] = SlipDetector.bank()
    p = make(VelocityController(shear_gain=1e-4), **kw)
    clean = make(VelocityController(shear_gain=1e-4), **kw)
    if backend == "capi":
        p = CPipeline(p.config)
        clean = CPipeline(clean.config)
    x = signals(600, p.n_inputs)
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


def test_reference_pipeline_rejects_the_same_overflow():
    p = make(VelocityController(shear_gain=1e-4), activation="exact", v_limit=DBL_MAX, u_limit=DBL_MAX)
    ref = ReferencePipeline(p.config)
    x = signals(200, p.n_inputs)
    x[50, :12:2], x[50, 1:12:2] = DBL_MAX, -DBL_MAX
    x[51, :12:2], x[51, 1:12:2] = DBL_MAX, -DBL_MAX
    out = p.process_block(x)[0]
    r = ref.process_block(x)
    assert np.all(np.isfinite(r))
    assert ref.rejected["overflow"] == p.status["overflow"] >= 1
    np.testing.assert_allclose(r, out, rtol=1e-9, atol=1e-12)


def test_sos_filter_rejects_an_overflowing_sample():
    f = SosFilter([[1.0, 0.0, 0.0, 1.0, -0.5, 0.0]], channels=2)  # y = x + 0.5 y(t-1)
    f.step([1.0, 2.0])
    y0 = f.step([DBL_MAX, -DBL_MAX])      # y still finite: accepted
    assert np.all(np.isfinite(y0)) and f.rejected == 0
    z0 = f.zi
    y = f.step([DBL_MAX, -DBL_MAX])       # y = max + max / 2 overflows: rejected
    np.testing.assert_array_equal(y, y0)  # the previous output is held
    np.testing.assert_array_equal(f.zi, z0)
    assert f.rejected == 1
    y = f.step([np.nan, 0.0])             # a later NaN holds the last accepted output too
    np.testing.assert_array_equal(y, y0)
    assert f.rejected == 2
    g = SosFilter([[1.0, 0.0, 0.0, 1.0, -0.5, 0.0]], channels=1)
    g.process(np.ones(3))
    zg = g.zi
    with pytest.raises(ValueError, match="overflow"):
        g.process(np.array([1.0, DBL_MAX, DBL_MAX, 1.0]))
    np.testing.assert_array_equal(g.zi, zg)


# -- non-finite positions -------------------------------------------------------------

@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_positions_are_refused_on_both_paths(value):
    p = make(VelocityController())
    p.process_block(signals(50, p.n_inputs))
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


# -- wrong output buffers ---------------------------------------------------------------

def test_capi_step_checks_its_buffers():
    c = CPipeline(make().config)
    x = np.zeros(c.n_inputs)
    good = np.zeros(c.n_outputs)
    c.step(x, good)
    for out, err in [(np.zeros(c.n_outputs, np.float32), TypeError), (np.zeros(c.n_outputs, np.int64), TypeError),
                     (np.zeros(c.n_outputs - 1), ValueError), (np.zeros(2 * c.n_outputs)[::2], ValueError),
                     (np.zeros((1, c.n_outputs)), ValueError), ([0.0] * c.n_outputs, TypeError)]:
        with pytest.raises(err, match="out"):
            c.step(x, out)
    ro = np.zeros(c.n_outputs)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="writeable"):
        c.step(x, ro)
    for bad, err in [(np.zeros(c.n_inputs, np.float32), TypeError), (np.zeros(c.n_inputs + 1), ValueError),
                     (np.zeros(2 * c.n_inputs)[::2], ValueError)]:
        with pytest.raises(err, match="x"):
            c.step(bad, good)
    assert c.status["ticks"] == 1


# -- non-finite detector features ------------------------------------------------------------

def _detector(backend, dtype=np.float64):
    w = DetectorWeights(init_params(4, 6, seed=0), input_mean=np.zeros(4), input_scale=np.ones(4), fs=FS)
    return SlipDetector(w, dtype=dtype, backend=backend)


@pytest.mark.parametrize("backend,dtype", [("cpp", np.float64), ("cpp", np.float32), ("numpy", np.float64)])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_features_are_refused_naming_the_sample(backend, dtype, value):
    det = _detector(backend, dtype)
    x = np.random.default_rng(1).normal(size=(3, 4, 20))
    first = x[:, :, :10].copy()
    det.run(first)
    x[1, 2, 5] = value
    x[2, 0, 7] = value
    with pytest.raises(ValueError, match=r"ridge 1, channel 2, sample 5"):
        det.run(x)
    with pytest.raises(ValueError, match=r"ridge 1, channel 2, sample 5"):
        det.run(x, reset=False)
    # the state is what the last good call left
    ref = _detector(backend, dtype)
    ref.run(first)
    good = np.random.default_rng(2).normal(size=(3, 4, 5))
    np.testing.assert_array_equal(det.run(good, reset=False)[2], ref.run(good, reset=False)[2])
    if backend == "cpp":
        with pytest.raises(ValueError, match="ridge 0, channel 3, sample 0"):
            det.step(np.array([[0, 0, 0, value], [0, 0, 0, 0], [0, 0, 0, 0]], dtype=float))


# -- one definition of the controller parameters --------------------------------------------

def test_controller_dataclasses_take_fields_and_defaults_from_cpp():
    fields = [f[0] for f in _core.controller_fields()]
    assert list(controller_fields()) == fields
    for cls, kind in [(NoController, "none"), (PaperController, "paper"), (VelocityController, "velocity")]:
        d = _core.controller_defaults(kind)
        obj = cls()
        for k, v in obj.params().items():
            assert d[k] == v, (kind, k)
        law_fields = set(controller_fields(kind))
        assert law_fields <= set(obj.params()) - {"kind"}
    p = MirrorPipeline(weights(), FS, 6, estimator=StressRateEstimator(PVDFCircuit(), FS, 12),
                       controller=VelocityController())
    assert {k: v for k, v in p._core.controller.items()} == {**_core.controller_defaults("velocity")}


def _c_default_velocity_config(w, est, keep):
    """A configuration filled the way a C program would: tm_config_init (the header's macro:
    tm_config_init_sized with the struct's size), the sections and weights,
    tm_controller_defaults(TM_CONTROLLER_VELOCITY, ...); arrays it points to go to ``keep``."""
    ffi, lib = load()
    cfg = new_config(ffi, lib)

    def ptr(a):
        a = np.ascontiguousarray(a, dtype=np.float64)
        keep.append(a)
        return ffi.cast("const double*", ffi.from_buffer(a))

    cfg.n_ridges = 6
    cfg.sos_v, cfg.n_sos_v = ptr(est.sos_rate), est.sos_rate.shape[0]
    cfg.sos_u, cfg.n_sos_u = ptr(est.sos_rate2), est.sos_rate2.shape[0]
    cfg.n_hidden = w["w1"].shape[0]
    cfg.w1, cfg.b1, cfg.w2, cfg.b2 = ptr(w["w1"]), ptr(w["b1"]), ptr(w["w2"]), ptr(w["b2"])
    cfg.input_mean, cfg.input_gain = ptr(w["input_mean"]), ptr(w["input_gain"])
    cfg.weights_fs = FS
    cfg.activation = 1
    assert lib.tm_controller_defaults(2, ffi.addressof(cfg.controller)) == 0
    return ffi, lib, cfg


def _c_default_velocity_pipeline(w, est):
    """A pipeline built from :func:`_c_default_velocity_config`."""
    keep = []
    ffi, lib, cfg = _c_default_velocity_config(w, est, keep)
    h = ffi.new("tm_pipeline*")
    assert lib.tm_pipeline_create(cfg, h) == 0, ffi.string(lib.tm_last_error())
    return ffi, lib, h[0], cfg


def test_config_init_writes_exactly_the_callers_struct():
    """tm_config_init_sized fills the given size and no byte beyond; the exported
    tm_config_init (what programs built against ABI <= 6 headers call) fills an ABI-6
    struct; sizes outside the accepted range write nothing."""
    ffi, lib = load()
    full = ffi.sizeof("tm_config")
    abi9 = ffi.offsetof("tm_config", "force_limit")
    abi8 = ffi.offsetof("tm_config", "bank_pad_mean")
    abi7 = ffi.offsetof("tm_config", "bank_knee")
    abi6 = ffi.offsetof("tm_config", "planner_decel")
    abi4 = ffi.offsetof("tm_config", "controller") + ffi.offsetof("tm_controller_params", "slip_confirm")
    abi3 = ffi.offsetof("tm_config", "controller") + ffi.offsetof("tm_controller_params", "shear_integral")

    def fresh():
        buf = ffi.new("char[]", full + 16)
        ffi.memmove(buf, b"\xab" * (full + 16), full + 16)
        return buf, ffi.cast("tm_config*", buf)

    for size, abi, call in [(full, 10, lambda c: lib.tm_config_init_sized(c, full)),
                            (abi9, 9, lambda c: lib.tm_config_init_sized(c, abi9)),
                            (abi8, 8, lambda c: lib.tm_config_init_sized(c, abi8)),
                            (abi7, 7, lambda c: lib.tm_config_init_sized(c, abi7)),
                            (abi6, 6, lambda c: lib.tm_config_init(c)),
                            (abi4, 4, lambda c: lib.tm_config_init_sized(c, abi4)),
                            (abi3, 3, lambda c: lib.tm_config_init_sized(c, abi3))]:
        buf, c = fresh()
        assert call(c) == 0
        assert c.struct_size == size and c.abi_version == abi and c.v_limit == 15.0 and c.n_ridges == 6
        assert bytes(ffi.buffer(buf)[size:]) == b"\xab" * (full + 16 - size), size
    for size in (abi3 - 8, full + 8, 0):
        buf, c = fresh()
        assert lib.tm_config_init_sized(c, size) == lib.TM_ERR_VERSION
        assert bytes(ffi.buffer(buf)) == b"\xab" * (full + 16)
        assert b"size" in ffi.string(lib.tm_last_error())
    assert lib.tm_config_init_sized(ffi.NULL, full) == lib.TM_ERR_NULL


def test_abi6_struct_runs_without_the_planner_lead():
    """A program of ABI 6 (tm_config ends before planner_decel) gets no lead, whatever lies
    beyond its struct: the same outputs, bit for bit, as planner_decel = 0 in a full struct;
    the same bytes at full size are refused, naming the field."""
    w = weights()
    est = StressRateEstimator(PVDFCircuit(), FS, 12, use_u=True)
    keep = []
    ffi, lib, cfg = _c_default_velocity_config(w, est, keep)
    cfg.controller.arm_delay = 0.0
    x = np.random.default_rng(5).normal(scale=0.05, size=(300, 24))
    h = ffi.new("tm_pipeline*")

    def run(c):
        assert lib.tm_pipeline_create(c, h) == 0, ffi.string(lib.tm_last_error())
        out = np.empty((x.shape[0], 2 + 3 * 6))  # n_outputs = 2 + 3 n_ridges
        xb = np.ascontiguousarray(x)
        for k in range(x.shape[0]):
            assert lib.tm_pipeline_step(h[0], ffi.cast("const double*", ffi.from_buffer(xb[k])), 24,
                                        ffi.cast("double*", ffi.from_buffer(out[k])), out.shape[1]) == 0
        assert lib.tm_pipeline_destroy(h[0]) == 0
        return out

    ref = run(cfg)  # full struct, planner_decel = 0
    assert np.ptp(ref[:, 0]) > 0  # the stage moves: a lead would show
    cfg.planner_decel = -5.0
    assert lib.tm_pipeline_create(cfg, h) == lib.TM_ERR_ARGUMENT and h[0] == 0
    assert b"planner_decel" in ffi.string(lib.tm_last_error())
    cfg.struct_size = ffi.offsetof("tm_config", "planner_decel")
    cfg.abi_version = 6
    assert np.array_equal(run(cfg).view(np.uint64), ref.view(np.uint64))


def test_default_velocity_law_is_bit_identical_from_c_and_python():
    w = weights()
    est = StressRateEstimator(PVDFCircuit(), FS, 12, use_u=True)
    ffi, lib, h, cfg = _c_default_velocity_pipeline(w, est)
    py = MirrorPipeline(w, FS, 6, estimator=est, controller=VelocityController(), activation="fast")
    for name in controller_fields():
        # (ABI 7 keeps the controller parameters added since in tm_config's tail)
        src = cfg.controller if hasattr(cfg.controller, name) else cfg
        assert getattr(src, name) == py._core.controller[name], name
    assert cfg.controller.gain == PaperController().gain
    assert cfg.v_limit == py.config["v_limit"] and cfg.u_limit == py.config["u_limit"]
    x = 40 * signals(3000, py.n_inputs, seed=5)  # drives y_pred through the ramp
    x = np.clip(x, -14.0, 14.0)
    out_c = np.zeros((len(x), py.n_outputs))
    try:
        for t in range(len(x)):
            row = np.ascontiguousarray(x[t])
            lib.tm_pipeline_step(h, ffi.from_buffer("double[]", row), row.size,
                                 ffi.from_buffer("double[]", out_c[t]), py.n_outputs)
    finally:
        lib.tm_pipeline_destroy(h)
    out_py = py.process_block(x)[0]
    assert np.any(out_py[:, 1] != 0.0)          # the law moved the stage
    np.testing.assert_array_equal(out_c, out_py)  # bit for bit
    ref = ReferencePipeline(py.config).process_block(x)
    np.testing.assert_allclose(ref[:, :2], out_py[:, :2], rtol=1e-6, atol=1e-9)  # fast sigmoid: 5e-10


# -- the header's contract -----------------------------------------------------------------------

def test_version_string_and_struct_sizes():
    ffi, lib = load()
    assert ffi.string(lib.tm_version_string()).decode() == f"tactile-mirror C ABI {lib.tm_abi_version()} " \
        "(pipeline 0.1.0)"
    p = CPipeline(make().config)
    # an older status struct (ABI 2: without overflow / last_reason) gets its prefix only
    old = ffi.offsetof("tm_pipeline_status", "overflow")
    buf = ffi.new("char[]", ffi.sizeof("tm_pipeline_status"))
    for i in range(len(buf)):
        buf[i] = b"\xab"
    s = ffi.cast("tm_pipeline_status*", buf)
    s.struct_size = old
    assert lib.tm_pipeline_get_status(p.handle, s) == 0
    assert s.struct_size == old and s.ticks == 0
    assert bytes(ffi.buffer(buf)[old:]) == b"\xab" * (len(buf) - old)
    # tm_config: sizes beyond this header's are refused; abi_version 2 is accepted
    cfg = new_config(ffi, lib)
    h = ffi.new("tm_pipeline*")
    cfg.struct_size = ffi.sizeof("tm_config") + 8
    assert lib.tm_pipeline_create(cfg, h) == -6
    # shorter than ABI 2/3's (which ended at the controller's slip_hold) is refused
    abi3 = ffi.offsetof("tm_config", "controller") + ffi.offsetof("tm_controller_params", "shear_integral")
    cfg.struct_size = abi3 - 8
    assert lib.tm_pipeline_create(cfg, h) == -6
    assert b"accepts" in ffi.string(lib.tm_last_error())
    assert lib.tm_config_init_sized(cfg, ffi.sizeof("tm_config")) == 0 and cfg.abi_version == 10 and cfg.v_limit == 15.0


# -- one wording for numeric arguments ---------------------------------------------------

def _numeric_constructors():
    from tactile_mirror.estimator import notch_sos
    from tactile_mirror.loop import SimulatedStage, StageLimits
    from tactile_mirror.loop.design import design_loop
    from tactile_mirror.noise import SensorNoise

    limits = StageLimits(-0.02, 0.02, 0.03, 1.0)
    return [
        ("Cf", 2.2e-12, lambda v: PVDFCircuit(Cf=v)),
        ("fs", FS, lambda v: StressRateEstimator(PVDFCircuit(), v, 2)),
        ("notch_q", 30.0, lambda v: notch_sos(FS, 50.0, notch_q=v)),
        ("temperature", 300.0, lambda v: SensorNoise(temperature=v)),
        ("v_max", 0.03, lambda v: StageLimits(-0.02, 0.02, v, 1.0)),
        ("lag", 0.002, lambda v: SimulatedStage(limits, lag=v)),
        ("fs", FS, lambda v: design_loop(limits, (1.0, 1e7), v, stage_delay=0.001, stage_lag=0.002)),
        ("slip_threshold", 0.8, lambda v: make(slip_threshold=v)),
        ("gain", 1.0, lambda v: PaperController(gain=v)),
    ]


@pytest.mark.parametrize("case", range(9))
def test_numeric_arguments_are_checked_alike(case):
    # Every constructor takes its numbers through one check (tactile_mirror.checks): a
    # non-number is a TypeError, a NaN / Inf or out-of-range number a ValueError, and both
    # name the argument; the same arguments pass with a good value.
    name, good, build = _numeric_constructors()[case]
    build(good)
    for bad in ("1.0", None, True, [1.0]):
        with pytest.raises(TypeError, match=f"^{name} must be a real number"):
            build(bad)
    for bad in (float("nan"), float("inf"), -float("inf")):
        with pytest.raises(ValueError, match=f"^{name} must be .*finite"):
            build(bad)


# -- the closed loop's simulation pieces -------------------------------------------------

def test_loop_simulation_pieces_refuse_what_they_cannot_mean():
    # Each of these ran and gave numbers (NaN positions, a clock stuck at inf, a mirrored
    # or NaN finger path, negative friction or stiffness, a drop rate over 1).
    from tactile_mirror.contact.brush import BrushRidges
    from tactile_mirror.loop import ArraySource, LoopRunner, SimulatedStage
    from tactile_mirror.loop.finger import finger_trajectory
    from tactile_mirror.loop.scene import LoopScene

    stage = SimulatedStage()
    stage.advance(0.001)
    for bad, error in ((float("nan"), ValueError), (float("inf"), ValueError), (1.0, ValueError), ("0", TypeError)):
        with pytest.raises(error, match="x0"):
            stage.reset(bad)
    for bad, error in ((float("inf"), ValueError), (0.0, ValueError), (True, TypeError)):
        with pytest.raises(error, match="dt"):
            stage.advance(bad)
    assert stage.t == 0.001 and np.isfinite(stage.position())
    runner = LoopRunner(make(), stage, ArraySource(np.zeros((5, make().n_inputs))))
    for bad, match in ((float("inf"), "duration"), (1e-9, "at least one tick")):
        with pytest.raises(ValueError, match=match):
            runner.run(duration=bad)
    for kw in ({"amplitude": -1e-3}, {"v_max": -0.01}, {"ramp": 0.0}, {"amplitude": float("nan")}):
        with pytest.raises(ValueError, match=next(iter(kw))):
            finger_trajectory(0, 1.0, 1000.0, **kw)
    for kw, match in (({"drop_rate": 1.5}, "drop_rate"), ({"mount_stiffness": -1.0}, "mount_stiffness"),
                      ({"mu_change": (0.1, -5.0)}, "mu_change mu"), ({"mu_change": (0.1,)}, "mu_change"),
                      ({"plant": "glass"}, "plant"), ({"seed": -1}, "seed")):
        with pytest.raises(ValueError, match=match):
            LoopScene(**kw)
    assert LoopScene(mu_change=[1.75, 0.45]).mu_change == (1.75, 0.45)
    with pytest.raises(ValueError, match="mu"):
        BrushRidges(6, mu=float("nan"))
    brush = BrushRidges(6)
    with pytest.raises(ValueError, match="mu"):
        brush.set_mu(-5.0)
    assert np.all(brush.mu == 1.0)


@pytest.mark.parametrize("make, exc, match", [
    # a string was iterated character by character; a complex load lost its imaginary part
    (lambda tm: tm.PVDFCircuit(load="123"), TypeError, "load must be a sequence of real numbers"),
    (lambda tm: tm.PVDFCircuit(load=np.array([0.0, 0.0, 1 + 1j])), TypeError, "load"),
    (lambda tm: tm.SensorNoise(harmonics="10"), TypeError, "harmonics"),
    (lambda tm: tm.SensorNoise().apply(np.zeros(8) + 0j, np.zeros(8), 1e3), TypeError, "v_out"),
    (lambda tm: tm.SensorNoise().apply(np.zeros(8), np.zeros(8, dtype=bool), 1e3), TypeError, "u_out"),
])
def test_strings_complex_and_bools_are_not_real_sequences(make, exc, match):
    import tactile_mirror as tm

    with pytest.raises(exc, match=match):
        make(tm)


def test_process_block_refuses_bool_samples_as_step_does():
    import tactile_mirror as tm

    est = tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 4)
    pipe = tm.MirrorPipeline(tm.SlipDetector.default(), 1000.0, 2, estimator=est)
    x = np.zeros((5, pipe.n_inputs), dtype=bool)
    with pytest.raises(TypeError, match="x must hold real numbers"):
        pipe.process_block(x)
    with pytest.raises(TypeError):
        pipe.step(x[0])
    assert pipe.status["ticks"] == 0


def test_signal_paths_refuse_bools_and_name_the_argument():
    """SosFilter.process and the estimator took True/False samples while SosFilter.step
    refused them; an axis of True was taken as axis 1. sosfilt, the drop-in for
    scipy.signal.sosfilt, casts them as scipy does."""
    import tactile_mirror as tm
    from scipy import signal

    sos = signal.butter(2, 0.1, output="sos")
    flags = np.array([True, False, True, True])
    assert np.allclose(tm.sosfilt(sos, flags), signal.sosfilt(sos, flags))
    filt = SosFilter(sos)
    with pytest.raises(TypeError, match="block"):
        filt.process(flags)
    assert np.all(filt.zi == 0)
    est = StressRateEstimator(PVDFCircuit(), 1000.0, 2)
    with pytest.raises(TypeError, match="^v must"):
        est.process(np.ones((2, 5), bool), np.ones((2, 5)))
    with pytest.raises(TypeError, match="^u must"):
        est.process(np.ones((2, 5)), np.ones((2, 5), bool))
    z = np.zeros((2, 50))
    with pytest.raises(TypeError, match="v_out"):
        tm.estimate_stress_rate(z.astype(bool), None, PVDFCircuit(), 1000.0)
    with pytest.raises(TypeError, match="axis"):
        tm.estimate_stress_rate(z, z, PVDFCircuit(), 1000.0, axis=True)
    with pytest.raises(TypeError, match="channels"):
        StressRateEstimator(PVDFCircuit(), 1000.0, 2.0)
    with pytest.raises(ValueError, match="channels"):
        StressRateEstimator(PVDFCircuit(), 1000.0, 0)
    # ints are numbers, as in scipy
    assert np.allclose(tm.sosfilt(sos, np.arange(4)), signal.sosfilt(sos, np.arange(4.0)))


def test_reference_helpers_name_bad_arguments():
    from tactile_mirror.lab import measure

    with pytest.raises(ValueError, match="max_shift"):
        measure.rel_rms_aligned(np.ones(10), np.ones(10), max_shift=10)
    with pytest.raises(TypeError, match="max_shift"):
        measure.rel_rms_aligned(np.ones(10), np.ones(10), max_shift=2.0)
    assert measure.rel_rms_aligned(np.ones(10), np.ones(10), max_shift=9) == 0.0
    with pytest.raises(ValueError, match="a0"):
        measure.extended_sosfilt(np.array([[1.0, 0, 0, 0, 0.1, 0]]), np.ones(4))


def test_c_abi_refuses_bank_fields_out_of_range_or_for_the_papers_net():
    """bank_pad_mean = 5, or a bank field on the paper's net, were ignored silently; and an
    ABI-9 struct (ending before force_input) runs without a force input."""
    w = weights()
    est = StressRateEstimator(PVDFCircuit(), FS, 12, use_u=True)
    keep = []
    ffi, lib, cfg = _c_default_velocity_config(w, est, keep)
    h = ffi.new("tm_pipeline*")
    for field, value in (("bank_pad_mean", 5), ("bank_pad_mean", 1)):
        setattr(cfg, field, value)
        assert lib.tm_pipeline_create(cfg, h) == lib.TM_ERR_ARGUMENT and h[0] == 0
        assert b"bank_pad_mean" in ffi.string(lib.tm_last_error())
    cfg.bank_pad_mean = 0
    cfg.force_input = 1  # 25 inputs
    assert lib.tm_pipeline_create(cfg, h) == 0
    ni, no = ffi.new("size_t*"), ffi.new("size_t*")
    assert lib.tm_pipeline_sizes(h[0], ni, no) == 0 and ni[0] == 25
    assert lib.tm_pipeline_destroy(h[0]) == 0
    # an ABI-9 program's struct: its size is the whole ABI-9 struct, with the 4 bytes of padding
    # after bank_pad_mean; whatever those hold (1 here), its force_input is the default, 0
    abi9 = ffi.offsetof("tm_config", "force_limit")
    assert abi9 % 8 == 0 and abi9 - ffi.offsetof("tm_config", "bank_pad_mean") == 8
    buf = ffi.buffer(cfg)
    buf[abi9 - 4:abi9] = (1).to_bytes(4, "little")
    cfg.struct_size = abi9
    cfg.abi_version = 9
    assert lib.tm_pipeline_create(cfg, h) == 0
    assert lib.tm_pipeline_sizes(h[0], ni, no) == 0 and ni[0] == 24
    assert lib.tm_pipeline_destroy(h[0]) == 0


@pytest.mark.parametrize("kw, match", [
    ({"Rf": 1e-300}, r"Rf \* Cf"), ({"Rs": 1e-300}, r"Rs \* Cd"), ({"Cd": 1e20}, r"Rd \* Cd"),
    ({"d33": -1e300}, "charge per pascal"), ({"load": (0.0, 0.0, 1e-300)}, "charge per pascal"),
])
def test_circuit_values_the_filters_cannot_represent_are_refused_at_construction(kw, match):
    # (they passed, then failed inside scipy's filter design: a bare AssertionError or
    # non-finite sections that named no field)
    import tactile_mirror as tm

    with pytest.raises(ValueError, match=match):
        tm.PVDFCircuit(**kw)


@pytest.mark.parametrize("kw", [{"e_n": 1e200}, {"i_n": 1e160}, {"cable_capacitance": 1e300}, {"hum": 1e200}])
def test_noise_densities_beyond_any_part_are_refused(kw):
    import tactile_mirror as tm

    with pytest.raises(ValueError, match=f"{next(iter(kw))} must be at most"):
        tm.SensorNoise(**kw)


def test_seeds_iterations_and_save_folders_are_named_in_their_errors(tmp_path, capsys):
    import tactile_mirror as tm
    from tactile_mirror.cli import main
    from tactile_mirror.lab.detector.synthetic import synthetic_scene
    from tactile_mirror.lab.detector.training import make_training_set, train_detector

    with pytest.raises(SystemExit):
        main(["evaluate", "--seed", "-5"])
    assert "argument --seed: must be non-negative" in capsys.readouterr().err
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        tm.SensorNoise().draw(1000.0, 10, seed=-1)
    ts = make_training_set([synthetic_scene(seed=0, n_ridges=1, duration=0.5)])
    for kw, match in (({"seed": -1}, "seed"), ({"maxiter": "3"}, "maxiter"), ({"maxiter": float("nan")}, "maxiter")):
        with pytest.raises(ValueError, match=match):
            train_detector(ts, n_hidden=2, progress=False, **kw)
    # the save's message names the file asked for, not the hidden temporary beside it
    with pytest.raises(FileNotFoundError, match=r"cannot save .*w\.npz.*does not exist") as exc:
        tm.SlipDetector.default().save(tmp_path / "no" / "sub" / "w.npz")
    assert ".tmp" not in str(exc.value)


def test_pipeline_rates_beyond_10_mhz_are_refused_in_python_and_c():
    import tactile_mirror as tm

    w = dict(weights(), fs=2e7)
    with pytest.raises(ValueError, match=r"fs must lie in \[1, 1e7\] Hz"):
        tm.MirrorPipeline(w, 2e7, 6, sos_v=np.array([[1.0, 0, 0, 1, 0, 0]]), sos_u=np.array([[1.0, 0, 0, 1, 0, 0]]))
    keep = []
    ffi, lib, cfg = _c_default_velocity_config(weights(), StressRateEstimator(PVDFCircuit(), FS, 12, use_u=True), keep)
    cfg.fs = cfg.weights_fs = 1e300
    h = ffi.new("tm_pipeline*")
    assert lib.tm_pipeline_create(cfg, h) == lib.TM_ERR_ARGUMENT and h[0] == 0
    assert b"fs must lie in [1, 1e7] Hz" in ffi.string(lib.tm_last_error())


def test_random_scenes_from_the_cli_and_their_ranges():
    """`simulate --scene random` always failed (its scalar --noise reached a (low, high) range)."""
    from tactile_mirror import scenes
    from tactile_mirror.cli import build_parser, scene_from_args

    args = build_parser().parse_args(["simulate", "--scene", "random", "--friction", "0.5", "--seed", "3"])
    sc = scene_from_args(args)
    assert sc.friction == 0.5 and sc.noise == args.noise  # the options given are fixed values
    assert repr(scenes.random(2, seed=7)) == repr(scenes.random(2, seed=7, friction=(0.45, 0.85)))  # as before
    for kw, exc, match in (({"friction": (0.9, 0.4)}, ValueError, "friction"), ({"noise": "ab"}, TypeError, "noise"),
                           ({"duration": 0.5}, ValueError, "duration must be at least 0.9 s"),
                           ({"seed": 1.7}, ValueError, "seed"), ({"n": True}, ValueError, "n must be")):
        n = kw.pop("n", 1)
        with pytest.raises(exc, match=match):
            scenes.random(n, **kw)


@pytest.mark.parametrize("kw, exc, match", [
    ({"stops": ("12",)}, TypeError, r"stops\[0\]"), ({"stops": "12"}, TypeError, "stops"),
    ({"stops": ((True, 2.0),)}, TypeError, r"stops\[0\]"), ({"n_ridges": True}, TypeError, "n_ridges"),
    ({"n_ridges": float("inf")}, TypeError, "n_ridges"), ({"n_ridges": None}, TypeError, "n_ridges"),
    ({"seed": True}, TypeError, "seed"), ({"duration": 1e300, "fs": 1e300}, ValueError, "at most 1e"),
    ({"circuit": None}, TypeError, "circuit"), ({"geometry": None}, TypeError, "geometry"),
    ({"duration": 0.2, "outputs": {"fields"}, "field_times": (0.1, 0.2)}, ValueError, r"field_times\[1\]"),
])
def test_scene_fields_are_checked_at_construction(kw, exc, match):
    import tactile_mirror as tm

    with pytest.raises(exc, match=match):
        tm.Scene(**kw)


def test_a_field_time_after_the_last_sample_is_the_last_sample():
    import tactile_mirror as tm

    r = tm.simulate(tm.Scene(duration=0.2, outputs={"fields", "forces"}, field_times=(0.0, 0.1, 0.1999)))
    assert sorted(r.fields) == [0.0, 0.1, 0.1999]  # (0.1999 rounded past the end and was dropped)


def test_brush_ridges_refuse_what_they_cannot_mean_and_keep_their_state():
    from tactile_mirror.contact.brush import BrushRidges

    b, ref = BrushRidges(), BrushRidges()
    for m in (b, ref):
        m.advance(1e-4)
        m.advance(2e-4)
    for bad, exc in ((float("nan"), ValueError), (float("inf"), ValueError), (2.0, ValueError), ("0", TypeError)):
        with pytest.raises(exc, match="dy"):
            b.advance(bad)
    assert b.advance(2e-4).force_y == ref.advance(2e-4).force_y  # (an inf was kept in the slid offsets)
    for kw, exc in (({"normal_load": float("nan")}, ValueError), ({"normal_load": -1.0}, ValueError),
                    ({"n_points": 0}, ValueError), ({"n_ridges": 2.7}, ValueError), ({"mu": "0.5"}, TypeError),
                    ({"mu": True}, TypeError)):
        with pytest.raises(exc, match=next(iter(kw))):
            BrushRidges(**kw)


def test_roundoff_bound_refuses_signals_it_cannot_bound():
    import tactile_mirror as tm

    sos = np.array([[1.0, 0, 0, 1, -0.9, 0]])
    for x, kw, exc in (([1.0, np.nan], {}, ValueError), ([1.0, np.inf], {}, ValueError),
                       (np.ones(3) + 1j, {}, TypeError), ("abc", {}, TypeError),
                       (np.ones(3), {"impulse_length": 0}, ValueError), (np.ones(3), {"impulse_length": 1.5}, ValueError),
                       (np.ones(3), {"impulse_length": True}, ValueError)):
        with pytest.raises(exc, match="impulse_length" if kw else "x must"):
            tm.roundoff_bound(sos, x, **kw)


def test_commands_with_a_file_as_their_out_folder_fail_before_the_work(tmp_path, capsys):
    from tactile_mirror.cli import main

    f = tmp_path / "afile"
    f.write_text("keep")
    for argv in (["figure", "6"], ["demo"], ["bench", "--quick"]):
        assert main([*argv, "--out", str(f)]) != 0
        assert "exists and is not a folder" in capsys.readouterr().err
    assert f.read_text() == "keep"


def test_more_arguments_that_were_taken_silently():
    import tactile_mirror as tm
    from tactile_mirror.contact.model import ridge_model
    from tactile_mirror.contact.pad import Pad
    from tactile_mirror.lab.measure import rel_max

    with pytest.raises(TypeError, match="use_u must be True or False"):
        tm.StressRateEstimator(PVDFCircuit(), FS, 2, use_u="False")  # (the string was truthy)
    with pytest.raises(ValueError, match=r"fs must lie in \[1, 1e7\] Hz"):
        tm.StressRateEstimator(PVDFCircuit(), 1e300, 2)
    with pytest.raises(ValueError, match="max_workers"):
        tm.simulate_many([tm.Scene(duration=0.01)] * 2, max_workers=0)  # (0 meant every core)
    with pytest.raises(TypeError, match="y must hold real numbers"):
        rel_max(np.ones(2) + 1j, np.ones(2))
    model = ridge_model(tm.Scene().geometry)
    for kw in ({"pitch": float("nan")}, {"pitch": float("inf")}, {"ridge_length": float("inf")}):
        with pytest.raises(ValueError, match=next(iter(kw))):
            Pad(model, 0.8, n_ridges=3, **kw)
    with pytest.raises(TypeError, match="plate_y"):
        Pad(model, 0.8).advance("0", 1e-5)
