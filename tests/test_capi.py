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
from tactile_mirror.loop import PaperController, VelocityController, header_path, library_path
from tactile_mirror.pipeline import MirrorPipeline

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
