"""Real-time safety: objects shared between threads, a handle closed while another
thread steps it, and a C program that counts allocations and locks on the tick path."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import _native_build as nb
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.detector.core import SlipDetector
from tactile_mirror.detector.network import init_params
from tactile_mirror.detector.weights import DetectorWeights
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.filters import SosFilter
from tactile_mirror.loop import header_path, library_path
from tactile_mirror.pipeline import MirrorPipeline, VelocityController

cffi = pytest.importorskip("cffi")
from tactile_mirror.loop.capi import CAPIError, CPipeline

FS = 1000.0
HERE = Path(__file__).resolve().parent
CAPI_TSAN = nb.capi_tsan()  # the sanitizer build run by tests/run_sanitizers.py --thread
BUSY = -9  # TM_ERR_BUSY
HANDLE = -2  # TM_ERR_HANDLE


def weights(h=8, seed=3):
    rng = np.random.default_rng(seed)
    return {"w1": rng.normal(size=(h, 5)), "b1": rng.normal(size=h), "w2": 2 * rng.normal(size=(2, h)),
            "b2": rng.normal(size=2), "input_mean": np.zeros(4),
            "input_gain": np.array([3e-3, 3e-3, 3e-5, 3e-5]), "fs": FS}


def make(n_ridges=6):
    est = StressRateEstimator(PVDFCircuit(), FS, 2 * n_ridges, use_u=True)
    return MirrorPipeline(weights(), FS, n_ridges, estimator=est, controller=VelocityController(shear_gain=1e-4),
                          activation="fast", v_limit=5.0, u_limit=5.0)


def signals(n, ni, seed=2):
    rng = np.random.default_rng(seed)
    x = 0.05 * np.sin(np.arange(n)[:, None] * 0.01 * np.arange(1, ni + 1)) + 0.02 * rng.normal(size=(n, ni))
    x[::97, 0] = np.nan
    return x


def _run_in_thread(fn):
    """Run ``fn`` in a new thread; its result or error lands in the returned box.

    Which thread claims a shared object first is up to the scheduler: when the main
    thread happens to be inside a call as this one starts, the refusal ("used by
    another thread" / TM_ERR_BUSY) is counted in ``box["refused"]`` and ``fn`` is
    tried again, so the thread's own call always runs whole."""
    box = {"refused": 0}

    def target():
        while True:
            try:
                box["value"] = fn()
                return
            except (RuntimeError, CAPIError) as e:
                if "another thread" in str(e) or getattr(e, "code", None) == BUSY:
                    box["refused"] += 1
                    continue
                box["error"] = e
                return
            except BaseException as e:  # noqa: BLE001 - handed to the caller
                box["error"] = e
                return

    t = threading.Thread(target=target)
    t.start()
    return t, box


# -- the pybind11 objects ------------------------------------------------------------

def test_pipeline_shared_between_threads_refuses_the_second_caller():
    """While one thread runs a long block (GIL released) every call that would touch
    the state from another thread raises at once; no tick is lost or doubled, and
    the status read meanwhile is never torn (it changes per call, not per tick)."""
    p, serial = make(), make()
    x = signals(40000, p.n_inputs)
    ref = serial.process_block(x)[0]
    t, box = _run_in_thread(lambda: p.process_block(x)[0])
    refused, ok_steps, seen = 0, 0, []
    row = np.zeros(p.n_inputs)
    while t.is_alive():
        s = p.status
        seen.append(s["ticks"])
        assert s["rejected"] == s["nonfinite"] + s["out_of_range"] + s["overflow"]
        for call in (lambda: p.step(row), lambda: p.process_block(row[None]), lambda: p.reset(0.0),
                     lambda: p.set_position(0.0), lambda: p.features, lambda: p.controller_state):
            try:
                call()
                ok_steps += 1
            except RuntimeError as e:
                assert "another thread" in str(e)
                refused += 1
    t.join()
    assert refused > 0
    if ok_steps == 0:  # nothing slipped in: the block is the serial run
        np.testing.assert_array_equal(box["value"], ref)
    # published per call: never a count from the middle of the block
    assert all(s <= ok_steps or s >= len(x) for s in seen)
    assert all(b >= a for a, b in zip(seen, seen[1:]))


def test_pipeline_ticks_from_two_threads_are_all_counted():
    """The issue's case: two threads stepping one pipeline. Each tick the library
    accepted to run is counted exactly once; the others were refused with an error."""
    p = make()
    x = signals(400, p.n_inputs)
    done = [0, 0]

    def worker(k):
        for _ in range(150):
            try:
                p.process_block(x)
                done[k] += len(x)
            except RuntimeError:
                pass

    ts = [threading.Thread(target=worker, args=(k,)) for k in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert p.status["ticks"] == sum(done)


def _detector(dtype=np.float64, backend="cpp"):
    w = DetectorWeights(init_params(4, 8, seed=1), input_mean=np.zeros(4), input_scale=np.ones(4), fs=FS)
    return SlipDetector(w, dtype=dtype, backend=backend)


@pytest.mark.parametrize("backend", ["cpp", "numpy"])
def test_slip_detector_shared_between_threads(backend):
    det, ref = _detector(backend=backend), _detector(backend=backend)
    x = np.random.default_rng(0).normal(size=(6, 4, 200000 if backend == "cpp" else 20000))
    want = ref.run(x)[2]
    t, box = _run_in_thread(lambda: det.run(x)[2])
    refused = 0
    while t.is_alive():
        try:
            det.run(x[:, :, :10])
        except RuntimeError as e:
            assert "another thread" in str(e)
            refused += 1
    t.join()
    assert refused > 0
    np.testing.assert_array_equal(box["value"], want)  # the other thread never mixed in
    k = det.kernel(6)
    t, box = _run_in_thread(lambda: k.run(np.ascontiguousarray(x[:, :, :100000]), reset=True))
    refused = 0
    while t.is_alive():
        for call in (k.reset, lambda: k.state):
            try:
                call()
            except RuntimeError:
                refused += 1
    t.join()
    assert refused > 0 or backend == "numpy"


def test_sos_filter_state_read_is_not_torn():
    f = SosFilter([[1.0, 0.0, 0.0, 1.0, -0.9, 0.0]] * 3, channels=64)
    x = np.ones((64, 400000))
    t, box = _run_in_thread(lambda: f.process(x))
    refused = 0
    while t.is_alive():
        try:
            assert f.zi.shape == (3, 64, 2)
        except RuntimeError as e:
            assert "another thread" in str(e)
            refused += 1
    t.join()
    assert "error" not in box
    assert refused > 0


@settings(max_examples=25, deadline=None)
@given(plan=st.lists(st.tuples(st.integers(0, 2), st.sampled_from(["step", "block", "status", "features"]),
                               st.integers(1, 300)), min_size=2, max_size=8),
       shared=st.booleans())
def test_random_interleavings_of_threads(plan, shared):
    """Random calls from three threads on one shared pipeline or on one pipeline
    each: every call either works or raises the 'another thread' error, outputs are
    finite, and the tick count is exactly the ticks of the calls that worked (and,
    for separate pipelines, nothing is ever refused)."""
    pipes = [make(2)] if shared else [make(2) for _ in range(3)]
    x = signals(300, pipes[0].n_inputs)
    taken = [0, 0, 0]
    refused = [0, 0, 0]
    errors = []

    def worker(k):
        p = pipes[0 if shared else k]
        out = np.zeros(p.n_outputs)
        for who, what, n in plan:
            if who != k:
                continue
            try:
                if what == "step":
                    for i in range(n):
                        p.step(np.ascontiguousarray(x[i]), out)
                        taken[k] += 1
                        assert np.all(np.isfinite(out))
                elif what == "block":
                    o = p.process_block(x[:n])[0]
                    taken[k] += n
                    assert np.all(np.isfinite(o))
                elif what == "status":
                    s = p.status
                    assert s["rejected"] <= s["ticks"]
                else:
                    assert np.all(np.isfinite(p.features))
            except RuntimeError as e:
                if "another thread" not in str(e):
                    errors.append(repr(e))
                refused[k] += 1
            except AssertionError as e:
                errors.append(repr(e))

    ts = [threading.Thread(target=worker, args=(k,)) for k in range(3)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors
    if shared:
        assert pipes[0].status["ticks"] == sum(taken)
    else:
        assert refused == [0, 0, 0]
        for k in range(3):
            assert pipes[k].status["ticks"] == taken[k]


# -- the published status and the unguarded windows ---------------------------------------

def _expected_status(seq, max_hold):
    """Counters after each tick of ``seq`` (kinds 'ok', 'nan', 'big'), as the status must publish them."""
    st = {"ticks": 0, "rejected": 0, "nonfinite": 0, "out_of_range": 0, "consecutive_rejected": 0,
          "last_bad_tick": -1, "fault": False}
    for kind in seq:
        if kind == "ok":
            st["consecutive_rejected"] = 0
            st["fault"] = False
        else:
            st["rejected"] += 1
            st["nonfinite" if kind == "nan" else "out_of_range"] += 1
            st["last_bad_tick"] = st["ticks"]
            st["consecutive_rejected"] += 1
            st["fault"] = st["consecutive_rejected"] > max_hold
        st["ticks"] += 1
        yield dict(st)


@pytest.mark.parametrize("backend", ["pybind", "capi"])
def test_published_status_follows_every_rejection_and_recovery(backend):
    # The counters are published only when a tick changed them: a rejection, and the
    # first accepted tick after rejections (consecutive_rejected back to 0, fault off).
    # After every single step the status another thread reads must be the exact one.
    p = MirrorPipeline(weights(), FS, 2, estimator=StressRateEstimator(PVDFCircuit(), FS, 4, use_u=True),
                       controller=VelocityController(shear_gain=1e-4), v_limit=5.0, u_limit=5.0, max_hold_ticks=2)
    if backend == "capi":
        p = CPipeline(p.config)
    rng = np.random.default_rng(11)
    seq = ["ok"] * 5 + ["nan", "ok", "ok", "big", "big", "big", "ok", "nan", "nan", "nan", "nan", "ok"] + ["ok"] * 3
    seq += list(rng.choice(["ok", "ok", "ok", "nan", "big"], size=200))
    row = np.zeros(p.n_inputs)
    for i, (kind, want) in enumerate(zip(seq, _expected_status(seq, 2))):
        row[:] = 0.01 * np.sin(0.1 * i + np.arange(p.n_inputs))
        if kind == "nan":
            row[i % p.n_inputs] = np.nan
        elif kind == "big":
            row[i % p.n_inputs] = 7.0
        p.step(row)
        got = p.status
        assert {k: got[k] for k in want} == want, (i, kind)
    if backend == "capi":
        p.close()


@pytest.mark.parametrize("net", ["jordan", "jordan_bank"])
def test_float32_windows_without_undo_never_let_an_overflow_through(net):
    # float32 with huge finite limits: samples of random magnitude up to the limit
    # and random sign. Ticks inside a window skip the undo and the finiteness check,
    # so a window longer than the bound allows would show up as a non-finite output
    # or feature; every overflowing tick must instead be rejected as 'overflow'. The
    # filter-bank net's window bounds include its bank's states.
    from tactile_mirror.detector import SlipDetector

    est = StressRateEstimator(PVDFCircuit(), FS, 4, use_u=True, dtype=np.float32)
    det = weights() if net == "jordan" else SlipDetector.bank()
    p = MirrorPipeline(det, FS, 2, estimator=est, controller=VelocityController(shear_gain=1e-4),
                       v_limit=1e30, u_limit=1e30, dtype=np.float32)
    rng = np.random.default_rng(4)
    n = 20000
    x = 0.01 * rng.standard_normal((n, p.n_inputs))
    burst = rng.random(n) < 0.05
    x[burst] = np.sign(rng.standard_normal((burst.sum(), p.n_inputs))) * 10.0 ** rng.uniform(
        0, 30, (burst.sum(), p.n_inputs))
    ramp = slice(5000, 5600)  # a slow climb: the states grow while windows are open
    x[ramp] = 10.0 ** np.linspace(0, 30, 600)[:, None] * np.sign(np.sin(np.arange(600)))[:, None]
    out, feat, ok = p.process_block(x, features=True, accepted=True)
    assert np.all(np.isfinite(out)) and np.all(np.isfinite(feat))
    s = p.status
    assert s["rejected"] == s["overflow"] == int(np.count_nonzero(~ok)) > 0
    # stepping tick by tick gives the same (the windows are the same in both calls)
    q = MirrorPipeline.from_config(p.config)
    for i, row in enumerate(x):
        q.step(row)
        assert q.last_accepted == ok[i], i
    np.testing.assert_array_equal(q.outputs, out[-1])


# -- the C ABI -------------------------------------------------------------------------

CLOSE_WHILE_STEPPING = textwrap.dedent("""
    import sys, threading, numpy as np
    sys.path.insert(0, {tests!r})
    from test_rt_safety import make
    from tactile_mirror.loop.capi import CAPIError, CPipeline
    for _ in range(8):
        c = CPipeline(make().config)
        x = np.zeros(c.n_inputs)
        codes = []
        def stepper():
            while True:
                try:
                    c.process_block(np.zeros((200, c.n_inputs)))
                    c.step(x)
                except CAPIError as e:
                    codes.append(e.code)
                    if e.code == -2:
                        return
        t = threading.Thread(target=stepper)
        h = c.handle
        t.start()
        while c.status["ticks"] < 400:
            pass
        c.close()    # tm_pipeline_destroy while the other thread is inside a call on h
        t.join()
        assert codes and codes[-1] == -2, codes
        assert c.lib.tm_pipeline_destroy(h) == -2
    print("ok")
""")


def test_close_while_stepping_does_not_crash():
    """The issue's case (heap corruption on today's main): run in a child process so
    that a crash fails this test instead of the test run."""
    r = subprocess.run([sys.executable, "-c", CLOSE_WHILE_STEPPING.format(tests=str(HERE))], capture_output=True,
                       text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split()[-1] == "ok"


def test_capi_handle_used_by_two_threads_is_busy():
    # Whichever thread comes second while the other is inside a call gets TM_ERR_BUSY
    # at once (never a wait, never a torn status); the block call retries until it
    # runs whole. Which thread claims the handle first is up to the scheduler, so the
    # race is run until a refusal was seen (bounded).
    c = CPipeline(make().config)
    x = np.zeros((20000, c.n_inputs))
    row = np.zeros(c.n_inputs)

    def block_until_done():
        refused = []
        while True:
            try:
                return c.process_block(x), refused
            except CAPIError as e:
                refused.append(e.code)

    codes = []
    for _attempt in range(20):
        t, box = _run_in_thread(block_until_done)
        while t.is_alive():
            try:
                c.step(row)
            except CAPIError as e:
                codes.append(e.code)
            assert c.status["rejected"] <= c.status["ticks"]  # any thread, any time
        t.join()
        assert "error" not in box
        codes += box["value"][1]
        if codes:
            break
    assert codes and set(codes) == {BUSY}
    c.close()
    with pytest.raises(CAPIError) as e:
        c.step(row)
    assert e.value.code == HANDLE


def test_stale_handle_never_claims_the_pipeline_that_reuses_its_slot():
    # A destroyed handle's slot is reused by the next pipeline with a new generation:
    # the stale handle gets TM_ERR_HANDLE (never TM_ERR_BUSY, never the new pipeline),
    # while a thread drives the new handle, and the new handle is never refused
    # because of the stale one.
    a = CPipeline(make().config)
    stale = a.handle
    a.close()
    b = CPipeline(make().config)
    assert (b.handle & 0xFFFFFFFF) == (stale & 0xFFFFFFFF) and b.handle != stale  # same slot, next generation
    lib, ffi = b.lib, b.ffi
    x = np.zeros(b.n_inputs)
    xp = ffi.cast("const double*", ffi.from_buffer(x))
    stop = threading.Event()
    codes = []

    def stale_caller():
        while not stop.is_set():
            codes.append(lib.tm_pipeline_step(stale, xp, b.n_inputs, ffi.NULL, 0))

    t = threading.Thread(target=stale_caller)
    t.start()
    try:
        for _ in range(3000):
            b.step(x)  # raises on TM_ERR_BUSY
    finally:
        stop.set()
        t.join()
    assert codes and set(codes) == {HANDLE}
    assert b.status["ticks"] == 3000
    b.close()


def _cc():
    for name in ("cc", "gcc", "clang"):
        p = shutil.which(name)
        if p:
            return p
    return None


@pytest.mark.skipif(_cc() is None or not sys.platform.startswith("linux"), reason="needs a C compiler on Linux")
@pytest.mark.parametrize("net", ["paper", "bank"])
def test_tick_path_allocates_nothing_and_takes_no_lock(tmp_path, net):
    """tests/c/rt_safety.c under the interposer tests/c/rt_counter.c: 2e5 ticks,
    5e4 block ticks, 1e3 status and feature reads, rejected ticks of every kind and
    the error paths make no allocation, take no lock and never yield; with the
    paper's net and with the filter-bank net."""
    lib = library_path()
    shim = tmp_path / "librt_counter.so"
    subprocess.run([_cc(), "-shared", "-fPIC", "-O1", str(HERE / "c" / "rt_counter.c"), "-o", str(shim), "-ldl"],
                   check=True, capture_output=True)
    exe = tmp_path / "rt_safety"
    subprocess.run([_cc(), "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", str(HERE / "c" / "rt_safety.c"), "-I",
                    os.path.dirname(header_path()), lib, "-Wl,-rpath," + os.path.dirname(lib), "-lm", "-ldl",
                    "-lpthread", "-o", str(exe)], check=True, capture_output=True)
    env = dict(os.environ, LD_PRELOAD=str(shim))
    r = subprocess.run([str(exe), net], capture_output=True, text=True, timeout=120, env=env, check=False)
    assert r.returncode == 0, r.stdout + r.stderr
    lines = dict(line.split(" ", 1) for line in r.stdout.strip().splitlines())
    calib = lines["calibration"].split()
    assert calib == ["alloc", "1", "lock", "1"]  # the interposer sees what it should
    counts = dict(zip(*[iter(("alloc " + lines["alloc"]).split())] * 2))
    assert counts["alloc"] == "0" and counts["lock"] == "0" and counts["yield"] == "0", r.stdout
    assert int(counts["ticks"]) == 250000
    assert int(counts["nonfinite"]) > 0 and int(counts["out_of_range"]) > 0 and int(counts["overflow"]) > 0


@pytest.mark.slow
@pytest.mark.skipif(_cc() is None or not sys.platform.startswith("linux"), reason="needs a C compiler on Linux")
@pytest.mark.native_build(CAPI_TSAN)
def test_threads_under_thread_sanitizer():
    # The build is shared with the other test process and later runs
    # (tests/_native_build.py): made or waited for here (where ThreadSanitizer
    # programs run at all), then reused by the script.
    cc, cxx = nb.cc_cxx()
    if cc and cxx and nb.thread_sanitizer_runs(cc, ".c"):
        CAPI_TSAN.build()
    r = subprocess.run([sys.executable, str(HERE / "run_sanitizers.py"), "--thread"], capture_output=True,
                       text=True, timeout=900, check=False)
    if r.returncode == 77:
        pytest.skip("ThreadSanitizer is not available: " + r.stderr.strip()[-200:])
    assert r.returncode == 0, r.stdout + r.stderr[-5000:]
