"""The header-only C++ kernels, built stand-alone with AddressSanitizer and UBSan
and checked against references computed here with scipy."""
import os
import subprocess

import _native_build as nb
import numpy as np
import pytest
import scipy.signal as ss

CXX = nb.cxx_compiler()
pytestmark = pytest.mark.skipif(CXX is None, reason="no C++ compiler on PATH")


# The programs, built once per run by whichever test process needs one first (the other
# waits for it), started ahead of the tests (the native_build marks; costliest first,
# cost: seconds of the longest compile, roughly) and kept under build/native-tests/ for later
# runs while the sources, headers and flags stay the same (tests/_native_build.py).
# Unoptimised: the sanitizers check the same accesses, and it compiles in 5 s instead of 37 s.
SOS = nb.kernel_program("test_sos.cpp", opt="-O0", cost=6)
BPTT = nb.kernel_program("test_bptt.cpp", cost=4)
# -O2 as the extension is built: the float exp of the AVX2 variant relies on the fused
# multiply-adds that -O2 forms.
SIMD = nb.kernel_program("test_simd.cpp", opt="-O2", cost=4)
# AddressSanitizer only, without debug info, unoptimised: the many kernel instantiations
# take minutes of one core to compile with optimisation (4-6 min with UBSan and -g); at
# -O0 the three translation units (main, the float checks, the double checks), compiled
# side by side, take about a minute, and the checks run in about 10 s.
JORDAN = nb.kernel_program(["test_jordan.cpp", "test_jordan_float.cpp", "test_jordan_double.cpp"],
                           sanitizers="address", debug=False, opt="-O0", cost=65)
SHARED_LIST = {s: nb.kernel_program("test_shared_list.cpp", sanitizers=s, cost=5)
               for s in ("thread", "address,undefined")}
CONTACT = nb.kernel_program("test_contact.cpp", cost=17)


def build(spec):
    """The program's path, built (or waited for) now."""
    return spec.build()


@pytest.mark.native_build(SOS)
def test_sos_kernel_under_sanitizers(tmp_path):
    # One test over the cases, so that one worker builds the program once (as separate
    # parametrized tests, pytest-xdist ran them on both workers and each built it).
    try:
        exe = build(SOS)
    except subprocess.CalledProcessError as exc:
        raise AssertionError(f"building tests/cpp/test_sos.cpp with sanitizers failed:\n{exc.stderr}") from exc
    sos = ss.ellip(6, 0.5, 50, [0.02, 0.3], "bandpass", output="sos")
    for channels, n in [(1, 37), (5, 500), (12, 1000), (70, 129)]:
        x = np.random.default_rng(channels).standard_normal((channels, n))
        ref = ss.sosfilt(sos, x)
        data = tmp_path / f"ref-{channels}-{n}.bin"
        with open(data, "wb") as f:
            np.array([sos.shape[0], channels, n], dtype=np.uint64).tofile(f)
            sos.astype(np.float64).tofile(f)
            x.tofile(f)
            ref.tofile(f)
        out = subprocess.run([str(exe), str(data)], check=False, capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, f"{channels} channels x {n}: " + out.stdout + out.stderr
        assert "ok: 0 failures" in out.stdout


@pytest.mark.native_build(BPTT)
def test_bptt_kernel_under_sanitizers(tmp_path):
    from tactile_mirror.detector.network import loss_and_grad

    try:
        exe = build(BPTT)
    except subprocess.CalledProcessError as exc:
        raise AssertionError(f"building tests/cpp/test_bptt.cpp with sanitizers failed:\n{exc.stderr}") from exc
    rng = np.random.default_rng(4)
    nin, h, s, n = 4, 7, 19, 150  # 19 sequences: three blocks of 8, the last one short
    theta = 1.5 * rng.standard_normal(h * (nin + 1) + 3 * h + 2)
    length = rng.integers(0, n + 1, s)
    real = np.arange(n)[None, :] < length[:, None]
    x = rng.standard_normal((s, nin, n)) * real[:, None, :]
    ts = (rng.uniform(size=(s, n)) > 0.5) * 1.0
    tp = rng.uniform(size=(s, n))
    ws, wp = (rng.uniform(size=(s, n)) * real / (s * n) for _ in range(2))
    loss, grad = loss_and_grad(theta, x, ts, tp, ws, wp, nin, h)
    data = tmp_path / "bptt.bin"
    with open(data, "wb") as f:
        np.array([nin, h, s, n], dtype=np.uint64).tofile(f)
        for a in (theta, x, ts, tp, ws, wp):
            np.ascontiguousarray(a, dtype=np.float64).tofile(f)
        length.astype(np.int64).tofile(f)
        np.array([loss], dtype=np.float64).tofile(f)
        grad.astype(np.float64).tofile(f)
    out = subprocess.run([str(exe), str(data)], check=False, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "ok: 0 failures" in out.stdout


@pytest.mark.native_build(SIMD)
def test_simd_layer_under_sanitizers():
    try:
        exe = build(SIMD)
    except subprocess.CalledProcessError as exc:
        raise AssertionError(f"building tests/cpp/test_simd.cpp with sanitizers failed:\n{exc.stderr}") from exc
    out = subprocess.run([str(exe)], check=False, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "ok: 0 failures" in out.stdout


@pytest.mark.native_build(JORDAN)
def test_jordan_kernels_under_address_sanitizer():
    # Block runs (projections, staging, ghost instances) against step() bit for bit and
    # against the scalar step_one(), every code variant, both activations, 4/5/8/17
    # inputs, 1-13 instances, and the filter-bank front end. AddressSanitizer only,
    # without debug info (JORDAN).
    try:
        exe = build(JORDAN)
    except subprocess.CalledProcessError as exc:
        raise AssertionError(f"building tests/cpp/test_jordan.cpp with AddressSanitizer failed:\n{exc.stderr}") from exc
    out = subprocess.run([str(exe)], check=False, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "ok: 0 failures" in out.stdout


def _thread_sanitizer_runs(tmp_path) -> bool:
    probe = tmp_path / "probe.cpp"
    probe.write_text("int main() { return 0; }\n")
    p = subprocess.run([CXX, "-fsanitize=thread", str(probe), "-o", str(tmp_path / "probe")], check=False,
                       capture_output=True)
    return p.returncode == 0 and subprocess.run([str(tmp_path / "probe")], check=False).returncode == 0


@pytest.mark.parametrize("sanitizers", [pytest.param(s, marks=pytest.mark.native_build(spec))
                                        for s, spec in SHARED_LIST.items()])
def test_shared_list_under_sanitizers(tmp_path, sanitizers):
    # the work sharing behind a pad's two threads (Pad.threads = 2), on synthetic items:
    # 20000 lists of random cost, failing items, pauses that put the second thread to
    # sleep; every item runs once, every item before the first failure runs (so the
    # failure reported does not depend on timing), the second thread wakes up after every
    # pause, the per-item data is ordered between the threads (ThreadSanitizer), and no
    # stack object is read late (AddressSanitizer)
    if sanitizers == "thread" and not _thread_sanitizer_runs(tmp_path):
        pytest.skip("the compiler cannot build or run ThreadSanitizer programs here")
    try:
        exe = build(SHARED_LIST[sanitizers])
    except subprocess.CalledProcessError as exc:
        raise AssertionError(f"building tests/cpp/test_shared_list.cpp with {sanitizers} failed:\n{exc.stderr}") from exc
    env = {**os.environ, "TSAN_OPTIONS": "halt_on_error=1", "ASAN_OPTIONS": "detect_stack_use_after_return=1"}
    out = subprocess.run([str(exe)], check=False, capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stdout + out.stderr[-5000:]
    assert "ok: 0 failures" in out.stdout
    assert "ThreadSanitizer" not in out.stderr


@pytest.mark.native_build(CONTACT)
def test_contact_kernel_under_sanitizers(tmp_path):
    # The contact kernel (contact_solver.hpp) on fig6 with a coarse contact mesh (41
    # nodes) up to 0.125 s after gross slip: the press, partial slip (the first
    # breakaway at sample 554), the breakaway cascades and the gross slip at 1475,
    # sliding. Against the compiled module's follow (every and auto) and per-sample
    # step (auto), with the same configuration ContactSolver gives the module; the
    # rejected non-finite positions, cascades failing without iterations and restore()
    # leave the history unchanged (tests/cpp/test_contact.cpp).
    from tactile_mirror import scenes
    from tactile_mirror.contact import ContactSolver, ridge_model
    from tactile_mirror.geometry import RidgeGeometry

    try:
        exe = build(CONTACT)
    except subprocess.CalledProcessError as exc:
        raise AssertionError(f"building tests/cpp/test_contact.cpp with sanitizers failed:\n{exc.stderr}") from exc
    scene = scenes.paper("fig6", geometry=RidgeGeometry(contact_mesh_size=0.2e-3))
    model = ridge_model(scene.geometry)
    y, indent = scene.plate_motion()
    N, n = 1600, model.n_nodes
    y = np.ascontiguousarray(y[:N])
    z = np.ascontiguousarray(model.geometry.height - indent[:N])

    def solver():
        return ContactSolver(model, scene.friction, mu_kinetic=scene.friction * scene.kinetic_ratio, backend="cpp")

    s = solver()
    p = s._params
    runs = []
    for every in (True, False):
        k = solver()._kernel
        lam, state = np.empty((N, 2 * n)), np.empty((N, n), dtype=np.int8)
        assert k.follow(y, z, every, lam, None, state)[0] == 0
        runs.append((lam, state, k))
    k = solver()._kernel
    lam, state = np.empty((N, 2 * n)), np.empty((N, n), dtype=np.int8)
    for t in range(N):
        status, f, _, st, _, _ = k.step(y[t], z[t], False)
        assert status == 0
        lam[t] = np.concatenate([f[:n], -f[n:]])
        state[t] = st
    runs.append((lam, state, k))
    # the path holds what the test is about: bordered updates, breakaways, gross slip
    st = runs[0][1]
    assert runs[0][2].updates > 0 and np.any((st[:-1] == 1) & (st[1:] == 2))
    assert np.any(np.any(st != 0, axis=1) & ~np.any(st == 1, axis=1))
    data = tmp_path / "contact.bin"
    with open(data, "wb") as fh:
        np.array([n, N, p["max_iter"], p["max_active_set_iter"]], dtype=np.uint64).tofile(fh)
        np.array([s._r, s._w_tol, p["mu"], p["mu_kinetic"], p["tol"], s._g_tol, s._f_tol, s._evt_tol[0, 0],
                  s._evt_tol[1, 0]], dtype=np.float64).tofile(fh)
        for a in (model.compliance, model.node_z, model.weights, y, z):
            np.ascontiguousarray(a, dtype=np.float64).tofile(fh)
        for lam, state, k in runs:
            lam.tofile(fh)
            state.tofile(fh)
            np.array([k.solves, k.events, k.factorizations, k.updates], dtype=np.int64).tofile(fh)
    out = subprocess.run([str(exe), str(data)], check=False, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "ok: 0 failures" in out.stdout
