"""The compiled contact solver against the Python reference: same forces (1e-10
relative), same node states, same errors, and an unchanged history after an error."""
import dataclasses

import numpy as np
import pytest
import tactile_mirror as tm
from tactile_mirror import _core
from tactile_mirror.contact import ContactConvergenceError, ContactSolver, Pad, ridge_model

RTOL = 1e-10


@pytest.fixture(scope="module")
def ridge():
    return ridge_model()


def run_both(scene, n_steps=None, mu_change=None):
    """Step a pad of each backend over the scene's plate motion; yields both states."""
    pads = {b: Pad.from_scene(scene, backend=b) for b in ("python", "cpp")}
    assert pads["cpp"].backend == "cpp" and pads["python"].backend == "python"
    y, z = scene.plate_motion()
    n = y.size if n_steps is None else n_steps
    for i in range(n):
        if mu_change is not None and i == mu_change[0]:
            for p in pads.values():
                p.mu = mu_change[1]
        yield i, pads["python"].advance(y[i], z[i]), pads["cpp"].advance(y[i], z[i])


def assert_same_run(scene, **kw):
    worst, contact_steps, slip_steps = 0.0, 0, 0
    for i, a, b in run_both(scene, **kw):
        np.testing.assert_array_equal(a.node_state, b.node_state, err_msg=f"node states differ at step {i}")
        scale = np.max(np.abs(a.forces))
        if scale > 0:
            worst = max(worst, np.max(np.abs(a.forces - b.forces)) / scale)
            contact_steps += 1
        else:
            assert not np.any(b.forces)
        slip_steps += bool(np.any(a.node_state == 2))
        np.testing.assert_allclose(b.slip_fraction, a.slip_fraction, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(a.gross_slip, b.gross_slip)
    assert worst <= RTOL, f"max relative force difference {worst:.2e}"
    return contact_steps, slip_steps


@pytest.mark.parametrize("name", ["fig6", "fig7", "fig8"])
def test_cpp_equals_python_on_paper_scenes(name):
    contact, slip = assert_same_run(tm.scenes.paper(name))
    assert contact > 1500 and slip > 100  # the scene does load, stick and slip


def test_cpp_equals_python_on_random_scenes():
    # 50 scenes at 50 Hz: coarse steps make the active set jump by many nodes per
    # step, the harder case for the piece iteration (and a short test).
    scenes = tm.scenes.random(50, seed=13, fs=50.0)
    slipped = 0
    for s in scenes:
        _, slip = assert_same_run(s)
        slipped += slip > 0
    assert slipped >= 40


def test_parameters_changed_mid_run_reach_the_kernel():
    s = tm.scenes.paper("fig6", duration=1.2)
    assert_same_run(s, mu_change=(800, 0.45))


def test_history_moves_between_backends(ridge):
    H = ridge.geometry.height
    path = [(0.0, 10e-6), (0.0, 30e-6)] + [(k * 2e-6, 30e-6) for k in range(1, 60)]
    a = ContactSolver(ridge, 0.6, mu_kinetic=0.5, backend="cpp")
    for y, d in path[:40]:
        a.step(y, H - d)
    b = ContactSolver(ridge, 0.6, mu_kinetic=0.5, backend="python")
    b.set_state(a.get_state())
    for y, d in path[40:]:
        x, w = a.step(y, H - d), b.step(y, H - d)
        np.testing.assert_array_equal(x.state, w.state)
        assert np.max(np.abs(x.forces - w.forces)) <= RTOL * np.max(np.abs(w.forces))
    with pytest.raises(ValueError, match="lam"):
        a.set_state({**a.get_state(), "lam": np.zeros(3)})


def same_history(a, b):
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)


@pytest.mark.parametrize("backend", ["cpp", "python"])
def test_errors_leave_the_solver_unchanged(ridge, backend):
    H = ridge.geometry.height
    s = ContactSolver(ridge, 0.6, mu_kinetic=0.5, backend=backend)
    ref = ContactSolver(ridge, 0.6, mu_kinetic=0.5, backend=backend)
    path = [(0.0, 10e-6), (0.0, 30e-6), (20e-6, 30e-6), (60e-6, 30e-6)]
    for y, d in path:
        s.step(y, H - d)
        ref.step(y, H - d)
    before = s.get_state()
    with pytest.raises(ValueError, match="finite"):
        s.step(np.nan, H - 30e-6)
    same_history(before, s.get_state())
    s.max_iter, s.max_active_set_iter = 0, 0
    with pytest.raises(ContactConvergenceError, match="did not converge in 0 iterations"):
        s.step(100e-6, H - 30e-6)
    same_history(before, s.get_state())
    s.max_iter, s.max_active_set_iter = 60, 25
    x, w = s.step(100e-6, H - 30e-6), ref.step(100e-6, H - 30e-6)
    np.testing.assert_array_equal(x.forces, w.forces)  # as if the failed steps never happened
    np.testing.assert_array_equal(x.state, w.state)


@pytest.mark.parametrize("backend", ["cpp", "python"])
def test_singular_system_is_reported(ridge, backend):
    # A rank-one compliance: every piece with two or more active nodes is singular.
    n = ridge.n_nodes
    bad = dataclasses.replace(ridge, compliance=np.full((2 * n, 2 * n), 1e-9))
    s = ContactSolver(bad, 0.6, backend=backend)
    before = s.get_state()
    with pytest.raises(ContactConvergenceError, match="singular contact system"):
        s.step(0.0, ridge.geometry.height - 30e-6)
    same_history(before, s.get_state())


def test_pad_commits_all_ridges_or_none():
    scene = tm.scenes.paper("fig6", n_ridges=6)
    pad = Pad.from_scene(scene)
    y, z = scene.plate_motion()
    for i in range(520):
        pad.advance(y[i], z[i])
    before = [s.get_state() for s in pad.solvers]
    pad.solvers[4].max_iter, pad.solvers[4].max_active_set_iter = 0, 0
    with pytest.raises(ContactConvergenceError, match="did not converge"):
        pad.advance(y[520], z[520])
    for s, b in zip(pad.solvers, before):  # ridges 0-3 converged but were not committed
        same_history(b, s.get_state())
    with pytest.raises(ValueError, match="finite"):
        pad.advance(y[520], np.inf)


def test_backend_argument_is_checked(ridge):
    with pytest.raises(ValueError, match="backend"):
        ContactSolver(ridge, 0.5, backend="fortran")
    assert ContactSolver(ridge, 0.5).backend == "cpp"
    assert ContactSolver(ridge, 0.5, reduced=False).backend == "python"  # the unreduced reference


def test_kernel_rejects_malformed_arrays(ridge):
    n = ridge.n_nodes
    with pytest.raises(ValueError, match="compliance"):
        _core._ContactSolver(np.zeros((3, 3)), ridge.node_z, ridge.weights, 1.0, 0.0)
    with pytest.raises(ValueError, match="weights"):
        _core._ContactSolver(ridge.compliance, ridge.node_z, np.ones(n + 1), 1.0, 0.0)
    with pytest.raises(TypeError, match="_ContactSolver"):
        _core._ContactPad([object()])


def assert_same_result(a, b, rtol=RTOL):
    """Two SimulationResults of one scene: same states and slip times, forces and
    stresses within rtol of their scale."""
    assert a.t.size == b.t.size
    assert a.slip_time == b.slip_time
    np.testing.assert_array_equal(a.ridge_slip_time, b.ridge_slip_time)
    for k in ("stress", "force_y", "force_z", "slip_fraction", "node_position"):
        x, y = getattr(a, k), getattr(b, k)
        if x is None:
            assert y is None
            continue
        np.testing.assert_allclose(y, x, rtol=0, atol=rtol * np.max(np.abs(x)), err_msg=k)
    if a.node_state is not None:
        np.testing.assert_array_equal(a.node_state, b.node_state)
    assert a.fields.keys() == b.fields.keys()


def test_compiled_trajectory_equals_python_simulate():
    # simulate() with the compiled pad steps whole blocks of samples in one call
    scene = tm.scenes.paper("fig8", outputs={"stress", "forces", "slip", "state"}, stop_after_slip=0.05)
    a = tm.simulate(scene, backend="python")
    b = tm.simulate(scene)
    assert a.slip_time is not None and a.t.size < scene.plate_motion()[0].size  # it did stop after slip
    assert_same_result(a, b)


@pytest.mark.parametrize("block", [7, 1024])
def test_compiled_blocks_equal_per_step_stepping(monkeypatch, block):
    # block boundaries anywhere (also inside the steps after gross slip) change nothing;
    # progress=True steps the compiled pad one sample at a time from Python
    import importlib

    sim = importlib.import_module("tactile_mirror.contact.simulate")

    monkeypatch.setattr(sim, "_BLOCK", block)
    scene = tm.scenes.paper("fig6", n_ridges=2, field_times=(0.2, 1.0),
                           outputs={"stress", "forces", "slip", "state", "fields"}, stop_after_slip=0.013)
    a = sim.simulate(scene, progress=True)
    b = sim.simulate(scene)
    assert a.slip_time is not None
    assert_same_result(a, b, rtol=0.0)
    assert a.newton_iterations == b.newton_iterations
    for tf in a.fields:
        np.testing.assert_array_equal(a.fields[tf][0], b.fields[tf][0])


def test_run_stops_at_a_failing_step_with_the_last_good_history():
    scene = tm.scenes.paper("fig6", n_ridges=2)
    pad = Pad.from_scene(scene)
    ref = Pad.from_scene(scene)
    y, z = scene.plate_motion()
    T = 600
    plate_z = ref.model.geometry.height - (z[:T, None] - pad.indent_offset[None, :])
    for i in range(520):
        last = ref.advance(y[i], z[i])
    n = pad.model.n_nodes
    f = np.empty((T, 2, 2 * n))
    st = np.empty((T, 2, n), dtype=np.int8)
    fr = np.empty((T, 2))
    its = np.empty(T, dtype=np.int32)
    plate_z[520, 1] = np.nan
    status, ridge, done = pad._stepper.run(y[:T], plate_z, f, None, st, fr, its)
    assert (status, ridge, done) == (1, 1, 520)  # non-finite position of ridge 1 at step 520
    np.testing.assert_array_equal(f[519], last.forces)  # same kernel, same steps: same bits
    np.testing.assert_array_equal(st[519], last.node_state)
    for s, r in zip(pad.solvers, ref.solvers):
        same_history(r.get_state(), s.get_state())
    with pytest.raises(ValueError, match="plate_z"):
        pad._stepper.run(y[:T], plate_z[:, :1], f, None, st, fr, its)
    with pytest.raises(ValueError, match="forces"):
        pad._stepper.run(y[:T], plate_z, f[:, :, :n], None, st, fr, its)
    with pytest.raises(TypeError, match="state"):
        pad._stepper.run(y[:T], plate_z, f, None, st.astype(np.int32), fr, its)


def test_baseline_kernels_equal_python():
    # the AVX2+FMA and the baseline variants of the dense kernels both stay within
    # round-off of the reference
    # one name per variant, shared with the filters and the detector
    assert _core._contact_simd_path() in ("avx2+fma", "sse2", "generic", "native")
    detected = _core._contact_simd_path()
    _core._contact_set_baseline(True)
    try:
        assert _core._contact_simd_path() in ("sse2", "generic", "native")
        assert detected != "avx2+fma" or _core._contact_simd_path() != detected
        assert_same_run(tm.scenes.paper("fig6", duration=1.2))
    finally:
        _core._contact_set_baseline(False)
