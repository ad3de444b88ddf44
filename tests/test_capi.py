"""The C ABI (tm.h): through cffi (ABI mode) against the pybind11 results, and from C."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import _native_build as nb
import numpy as np
import pytest
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.loop import header_path, library_path
from tactile_mirror.pipeline import MirrorPipeline, PaperController, ReferencePipeline, VelocityController
from tactile_mirror.pipeline.controller import controller_fields

cffi = pytest.importorskip("cffi")
from tactile_mirror.loop.capi import CAPIError, CPipeline, load, new_config

FS = 1000.0
HERE = Path(__file__).resolve().parent
CAPI_ASAN = nb.capi_asan()  # the sanitizer build run by tests/run_sanitizers.py


def weights(h=8, seed=3, fs=FS):
    rng = np.random.default_rng(seed)
    return {"w1": rng.normal(size=(h, 5)), "b1": rng.normal(size=h), "w2": 2 * rng.normal(size=(2, h)),
            "b2": rng.normal(size=2), "input_mean": np.zeros(4),
            "input_gain": np.array([3e-3, 3e-3, 3e-5, 3e-5]), "fs": fs}


def make(use_u=True, dtype=np.float64, controller=None, n_ridges=6):
    est = StressRateEstimator(PVDFCircuit(), FS, 2 * n_ridges, use_u=use_u)
    dtype, ddtype = dtype if isinstance(dtype, tuple) else (dtype, dtype)
    return MirrorPipeline(weights(), FS, n_ridges, estimator=est, controller=controller, dtype=dtype,
                          detector_dtype=ddtype,
                          v_limit=5.0, u_limit=5.0, activation="fast", max_hold_ticks=20)


def signals(n, ni, seed=2):
    rng = np.random.default_rng(seed)
    x = 0.05 * np.sin(np.arange(n)[:, None] * 0.01 * np.arange(1, ni + 1)) + 0.02 * rng.normal(size=(n, ni))
    x[77, 3] = np.nan
    x[150, 0] = -np.inf
    x[151, ni - 1] = 7.0
    x[400:430] = np.nan  # beyond max_hold_ticks: fault
    return x


def test_library_and_header_are_installed():
    lib = library_path()
    assert os.path.isfile(lib) and os.path.isabs(lib)
    assert os.path.isfile(header_path())
    ffi, c = load()
    assert c.tm_abi_version() == 10
    assert ffi.string(c.tm_version_string()).decode().startswith("tactile-mirror C ABI 10 ")


@pytest.mark.parametrize("use_u", [True, False])
@pytest.mark.parametrize("dtype", [np.float64, np.float32, (np.float64, np.float32)], ids=["f64", "f32", "mixed"])
@pytest.mark.parametrize("controller", [None, PaperController(threshold=0.3),
                                        VelocityController(v_max=0.01, a_max=0.5)], ids=["none", "paper", "vel"])
def test_c_abi_matches_pybind11_bit_for_bit(use_u, dtype, controller):
    pipe = make(use_u, dtype, controller)
    x = signals(600, pipe.n_inputs)
    ref, acc_ref = pipe.process_block(x, accepted=True)
    with CPipeline(pipe.config) as c:
        assert (c.n_inputs, c.n_outputs) == (pipe.n_inputs, pipe.n_outputs)
        out, acc = c.process_block(x, accepted=True)
        assert np.array_equal(out.view(np.uint64), ref.view(np.uint64))
        np.testing.assert_array_equal(acc, acc_ref)
        st = c.status
        for k, v in pipe.status.items():
            assert st[k] == v, k
        np.testing.assert_array_equal(c.features, pipe.features)
        c.reset()
        o = np.zeros(c.n_outputs)
        steps = np.array([(c.step(row, o), o.copy())[1] for row in x])
        assert np.array_equal(steps.view(np.uint64), ref.view(np.uint64))
        assert c.last_accepted
        c.step(x[77])
        assert not c.last_accepted


def test_error_codes():
    pipe = make()
    ffi, lib = load()
    with CPipeline(pipe.config) as c:
        h = c.handle
        x = np.zeros(c.n_inputs)
        out = np.zeros(c.n_outputs)
        xb = ffi.from_buffer("double[]", x)
        ob = ffi.from_buffer("double[]", out)
        assert lib.tm_pipeline_step(h, xb, c.n_inputs - 1, ob, c.n_outputs) == lib.TM_ERR_SIZE
        assert b"inputs" in ffi.string(lib.tm_last_error())
        assert lib.tm_pipeline_step(h, ffi.NULL, c.n_inputs, ob, c.n_outputs) == lib.TM_ERR_NULL
        assert lib.tm_pipeline_step(h, xb, c.n_inputs, ffi.NULL, 0) == lib.TM_OK  # out is optional
        for bad in (0, h + 1, h + (1 << 32), 2**64 - 1, 12345):
            assert lib.tm_pipeline_step(bad, xb, c.n_inputs, ob, c.n_outputs) == lib.TM_ERR_HANDLE
        st = ffi.new("tm_pipeline_status*")
        st.struct_size = 3
        assert lib.tm_pipeline_get_status(h, st) == lib.TM_ERR_VERSION
        assert lib.tm_pipeline_get_status(h, ffi.NULL) == lib.TM_ERR_NULL
        assert lib.tm_pipeline_reset(h, float("nan")) == lib.TM_ERR_ARGUMENT
        assert lib.tm_pipeline_time_step_ns(h, 0, ffi.new("double*")) == lib.TM_ERR_ARGUMENT
    # destroyed: refused, never dereferenced
    assert lib.tm_pipeline_destroy(h) == lib.TM_ERR_HANDLE
    assert lib.tm_pipeline_step(h, xb, c.n_inputs, ob, c.n_outputs) == lib.TM_ERR_HANDLE
    assert lib.tm_config_init(ffi.NULL) == lib.TM_ERR_NULL
    assert ffi.string(lib.tm_status_name(lib.TM_ERR_FS)) == b"TM_ERR_FS"


@pytest.mark.parametrize("key, value, match", [("b1", np.zeros(2), "b1"), ("w2", np.zeros((1, 8)), "w2"),
                                                ("input_mean", np.zeros(1), "input_mean"),
                                                ("shear_weights", np.zeros(3), "shear_weights"),
                                                ("n_ridges", 2**31, "n_ridges")])
def test_short_config_arrays_are_refused_before_the_c_abi_reads_them(key, value, match):
    # tm_pipeline_create takes bare pointers and reads as many values as the sizes say: a
    # short b1 was read past its end (finite garbage out). CPipeline checks the config as
    # MirrorPipeline.from_config does before handing it over.
    with pytest.raises(ValueError, match=match):
        CPipeline(dict(make().config, **{key: value}))


def test_create_errors_name_the_field():
    cfg = make().config
    bad_fs = dict(cfg, weights_fs=2000.0)
    with pytest.raises(CAPIError, match="TM_ERR_FS.*another sample rate") as e:
        CPipeline(bad_fs, check=False)
    assert e.value.code == -5
    with pytest.raises(CAPIError, match="TM_ERR_ARGUMENT.*v_max"):
        CPipeline(dict(cfg, controller=dict(cfg["controller"], kind="velocity", v_max=0.0)), check=False)
    with pytest.raises(CAPIError, match="n_ridges"):
        CPipeline(dict(cfg, n_ridges=0), check=False)
    with pytest.raises(CAPIError, match="sos_u must be empty"):
        CPipeline(dict(cfg, use_u=False), check=False)
    ffi, lib = load()
    c = new_config(ffi, lib)
    c.abi_version = 99
    h = ffi.new("tm_pipeline*")
    assert lib.tm_pipeline_create(c, h) == lib.TM_ERR_VERSION and h[0] == 0
    c = new_config(ffi, lib)
    c.precision = 32
    c.detector_precision = 64
    assert lib.tm_pipeline_create(c, h) == lib.TM_ERR_ARGUMENT
    assert b"detector_precision" in ffi.string(lib.tm_last_error())


def test_timing_inside_library():
    with CPipeline(make().config) as c:
        assert c.time_step_ns(1000) > 0


# -- wrong output buffers ---------------------------------------------------------------

def test_capi_step_checks_its_buffers(fast_pipeline):
    c = CPipeline(fast_pipeline().config)
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


# -- the header's contract -----------------------------------------------------------------------

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


def test_default_velocity_law_is_bit_identical_from_c_and_python(wave_signals):
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
    x = 40 * wave_signals(3000, py.n_inputs, seed=5)  # drives y_pred through the ramp
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


def test_version_string_and_struct_sizes(fast_pipeline):
    ffi, lib = load()
    assert ffi.string(lib.tm_version_string()).decode() == f"tactile-mirror C ABI {lib.tm_abi_version()} " \
        "(pipeline 0.1.0)"
    p = CPipeline(fast_pipeline().config)
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


def _cc():
    for name in ("cc", "gcc", "clang"):
        p = shutil.which(name)
        if p:
            return p
    return None


@pytest.mark.skipif(_cc() is None, reason="no C compiler")
def test_c_program(tmp_path):
    lib = library_path()
    exe = tmp_path / "example"
    cmd = [_cc(), "-std=c99", "-Wall", "-Wextra", "-Werror", "-O1", "-D_POSIX_C_SOURCE=199309L",
           str(HERE / "c" / "example.c"), "-I", os.path.dirname(header_path()), lib,
           "-Wl,-rpath," + os.path.dirname(lib), "-lm", "-o", str(exe)]
    subprocess.run(cmd, check=True, capture_output=True)
    r = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "ok"


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("cmake") is None or _cc() is None, reason="needs cmake and a C compiler")
@pytest.mark.native_build(CAPI_ASAN)
def test_sanitizers():
    # The build is shared with the other test process and later runs
    # (tests/_native_build.py): made or waited for here, then reused by the script.
    CAPI_ASAN.build()
    r = subprocess.run([sys.executable, str(HERE / "run_sanitizers.py")], capture_output=True, text=True,
                       timeout=300, check=False)
    assert r.returncode == 0, r.stdout + r.stderr


def test_every_declaration_is_resolved_when_the_library_is_loaded():
    # cffi resolves a name on first use under a lock that all libraries of one FFI
    # share. A CPipeline freed by the cycle collector during such a look-up (inside a
    # new CPipeline's construction) would look up tm_pipeline_destroy on its own
    # library under the same lock from __del__: a deadlock, seen in a test run.
    # With every name resolved by load(), calls are plain attribute reads.
    lib = load()[1]
    names = dir(lib)
    assert "tm_pipeline_destroy" in names and "tm_pipeline_step" in names
    assert all(n in vars(lib) for n in names)
