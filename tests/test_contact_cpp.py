"""The compiled contact solver against the Python reference: the same event-driven
path (same node states at every sample, same solves and events), forces within 1e-10
of their peak, the same errors, and an unchanged history after an error."""
import dataclasses

import numpy as np
import pytest
import tactile_mirror as tm
from tactile_mirror import _core
from tactile_mirror.contact import ContactConvergenceError, ContactSolver, Pad, ridge_model

# Forces agree within RTOL of their peak. 1e-10 for the solve at every sample; the
# whole-trajectory event stepping and the per-sample stepping with parameter changes
# or the baseline (non-FMA) kernels carry round-off along the path from event to event
# (the reference's own two stepping modes agree to 1.5e-10 on fig6): 1e-9 there, the
# bound issue 17 sets between the two modes.
RTOL = 1e-10
RTOL_PATH = 1e-9


@pytest.fixture(scope="module")
def ridge():
    return ridge_model()


def run_both(scene, n_steps=None, mu_change=None):
    """Step a pad of each backend sample by sample (Pad.advance, stepping "every": a
    solve per sample) over the scene's plate motion; yields both states."""
    pads = {b: Pad.from_scene(scene, backend=b, stepping="every") for b in ("python", "cpp")}
    assert pads["cpp"].backend == "cpp" and pads["python"].backend == "python"
    y, z = scene.plate_motion()
    n = y.size if n_steps is None else n_steps
    for i in range(n):
        if mu_change is not None and i == mu_change[0]:
            for p in pads.values():
                p.mu = mu_change[1]
        yield i, pads["python"].advance(y[i], z[i]), pads["cpp"].advance(y[i], z[i])


def assert_same_run(scene, rtol=RTOL, **kw):
    """Identical node states at every step, forces within rtol of the run's peak force."""
    diff, peak, contact_steps, slip_steps = 0.0, 0.0, 0, 0
    for i, a, b in run_both(scene, **kw):
        np.testing.assert_array_equal(a.node_state, b.node_state, err_msg=f"node states differ at step {i}")
        scale = np.max(np.abs(a.forces))
        if scale > 0:
            diff = max(diff, np.max(np.abs(a.forces - b.forces)))
            peak = max(peak, scale)
            contact_steps += 1
        else:
            assert not np.any(b.forces)
        slip_steps += bool(np.any(a.node_state == 2))
        np.testing.assert_allclose(b.slip_fraction, a.slip_fraction, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(a.gross_slip, b.gross_slip)
    if rtol is not None:
        assert diff <= rtol * peak, f"max force difference {diff / peak:.2e} of the peak"
    return contact_steps, slip_steps


@pytest.mark.parametrize("name", ["fig6", "fig7", "fig8"])
def test_cpp_equals_python_on_paper_scenes(name):
    contact, slip = assert_same_run(tm.scenes.paper(name), rtol=RTOL_PATH)
    assert contact > 1500 and slip > 100  # the scene does load, stick and slip


def random_scenes_50hz():
    # 50 scenes at 50 Hz: coarse steps make the active set jump by many nodes per
    # step, the harder case for the piece iteration (and a short test). Friction from
    # 0.5, as in random_scenes_100hz.
    return tm.scenes.random(50, seed=13, fs=50.0, friction=(0.5, 1.2))


@pytest.mark.xfail(strict=True, reason="known: stepped one 50 Hz sample at a time (Pad.advance, 'every'), one of "
                   "the 50 scenes parts in the statuses of mirror-image nodes at its first contact steps; to be traced")
def test_cpp_equals_python_on_random_scenes():
    slipped = 0
    for s in random_scenes_50hz():
        _, slip = assert_same_run(s, rtol=None)  # statuses at every step; forces below
        slipped += slip > 0
    assert slipped >= 40


def test_parameters_changed_mid_run_reach_the_kernel():
    s = tm.scenes.paper("fig6", duration=1.2)
    assert_same_run(s, rtol=RTOL_PATH, mu_change=(800, 0.45))


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
    # A rank-one compliance: every piece is singular (entries a power of two, so the
    # elimination cancels exactly and the zero pivot is exact, as LAPACK reports it).
    n = ridge.n_nodes
    bad = dataclasses.replace(ridge, compliance=np.full((2 * n, 2 * n), 2.0 ** -30))
    s = ContactSolver(bad, 0.6, backend=backend)
    before = s.get_state()
    with pytest.raises(ContactConvergenceError, match="singular contact system"):
        s.step(0.0, ridge.geometry.height - 30e-6)
    same_history(before, s.get_state())


@pytest.mark.parametrize("stepping", ["auto", "every"])
def test_pad_commits_all_ridges_or_none(stepping):
    # ridge 4 cannot solve a breakaway cascade (no iterations allowed): the step where
    # its first cascade comes fails, and every ridge keeps the history it had before
    scene = tm.scenes.paper("fig6", n_ridges=6)
    pad = Pad.from_scene(scene, stepping=stepping)
    y, z = scene.plate_motion()
    pad.solvers[4].max_iter, pad.solvers[4].max_active_set_iter = 0, 0
    for i in range(y.size):
        before = [s.get_state() for s in pad.solvers]
        try:
            pad.advance(y[i], z[i])
        except ContactConvergenceError as exc:
            assert "did not converge" in str(exc)
            break
    else:
        pytest.fail("no cascade met")
    assert i > 100
    for s, b in zip(pad.solvers, before):  # ridges 0-3 succeeded but were undone
        same_history(b, s.get_state())
    with pytest.raises(ValueError, match="finite"):
        pad.advance(y[i], np.inf)


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


@pytest.mark.parametrize("stepping", ["every", "auto"])
def test_compiled_blocks_equal_per_step_stepping(monkeypatch, stepping):
    # block boundaries anywhere (also inside the steps after gross slip) change only
    # round-off (an "auto" segment is cut there), and stepping the compiled pad one
    # sample at a time from Python (Pad.advance) meets the same path
    import importlib

    sim = importlib.import_module("tactile_mirror.contact.simulate")

    scene = tm.scenes.paper("fig6", n_ridges=2, field_times=(0.2, 1.0),
                           outputs={"stress", "forces", "slip", "state", "fields"}, stop_after_slip=0.013)
    a = sim.simulate(scene, stepping=stepping)
    monkeypatch.setattr(sim, "_EVENT_BLOCK", 7)
    b = sim.simulate(scene, stepping=stepping)
    assert a.slip_time is not None
    assert_same_result(a, b, rtol=0.0 if stepping == "every" else RTOL_PATH)
    # (solves and events differ: a run stopping after the slip follows its last block
    # to the block's end)
    pad = Pad.from_scene(scene, stepping=stepping)
    y, z = scene.plate_motion()
    for i in range(a.t.size):
        st = pad.advance(y[i], z[i])
        np.testing.assert_array_equal(st.node_state, a.node_state[..., i])
        assert np.max(np.abs(st.strip_stress - a.stress[..., i])) <= RTOL_PATH * np.max(np.abs(a.stress))


def test_run_stops_at_a_failing_step_with_the_last_good_history():
    scene = tm.scenes.paper("fig6", n_ridges=2)
    pad = Pad.from_scene(scene)
    ref = Pad.from_scene(scene, stepping="every")
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
        assert_same_run(tm.scenes.paper("fig6", duration=1.2), rtol=RTOL_PATH)
    finally:
        _core._contact_set_baseline(False)


# ---- the event-driven path following, whole trajectories


def follow_both(scene, stepping, threads=1):
    """Pad.follow of each backend over the scene's plate motion."""
    out = {}
    for backend in ("python", "cpp"):
        pad = Pad.from_scene(scene, backend=backend, stepping=stepping)
        pad.threads = threads
        y, ind = scene.plate_motion()
        lam, disp, state = pad.follow(y, ind, want_displacement=True)
        out[backend] = (pad, lam, disp, state)
    return out


def assert_same_follow(scene, stepping, rtol=RTOL_PATH):
    out = follow_both(scene, stepping)
    (pp, lp, dp, sp), (pc, lc, dc, sc) = out["python"], out["cpp"]
    np.testing.assert_array_equal(sp, sc)  # identical statuses at every sample
    assert (pc.solves, pc.events) == (pp.solves, pp.events)
    scale = np.max(np.abs(lp))
    if rtol is None:
        pass
    elif scale > 0:
        assert np.max(np.abs(lc - lp)) <= rtol * scale
        assert np.max(np.abs(dc - dp)) <= rtol * np.max(np.abs(dp))
    else:
        assert not np.any(lc)
    return pp.events, int(np.count_nonzero(sp == 2))


@pytest.mark.parametrize("stepping", ["auto", "every"])
@pytest.mark.parametrize("name", ["fig6", "fig7", "fig8"])
def test_follow_cpp_equals_python_on_paper_scenes(name, stepping):
    events, slipping = assert_same_follow(tm.scenes.paper(name), stepping)
    assert events > 300 and slipping > 1000  # contact, breakaways, gross slip


def random_scenes_100hz():
    # 16 scenes (friction 0.5-1.2, stops, 1 or 2 ridges) at 100 Hz. Below friction
    # ~0.45 the reference's own two stepping modes part on the statuses of mirror-image
    # nodes (a round-off tie the path does not settle), and so do the backends; that
    # range is left to the reference's tests.
    scenes = tm.scenes.random(16, seed=4177, friction=(0.5, 1.2), indent=(15e-6, 40e-6),
                              slide_speed=(0.1e-3, 0.6e-3), stop_probability=0.6, duration=1.5, fs=100.0)
    return [dataclasses.replace(s, n_ridges=2, finger_radius=0.05) if k % 5 == 0 else s
            for k, s in enumerate(scenes)]


def test_follow_cpp_equals_python_on_random_scenes():
    # identical statuses at every sample, the same solves and events; forces below
    slipped = 0
    for s in random_scenes_100hz():
        _, slipping = assert_same_follow(s, "auto", rtol=None)
        slipped += slipping > 0
    assert slipped >= 12


@pytest.mark.xfail(strict=True, reason="known: on a few random scenes the backends meet the same statuses, "
                   "solves and events but their forces part by up to 5e-4 of the peak (100 Hz) and 1.3e-7 "
                   "(50 Hz, per sample); not round-off, to be traced")
def test_random_scene_forces_agree_to_round_off():
    for s in random_scenes_100hz():
        assert_same_follow(s, "auto", rtol=RTOL_PATH)
    for s in random_scenes_50hz():
        assert_same_run(s, rtol=RTOL_PATH)


def test_follow_on_two_threads_equals_one():
    scene = tm.scenes.paper("fig8", n_ridges=6)
    y, ind = scene.plate_motion()
    runs = []
    for threads in (1, 2):
        pad = Pad.from_scene(scene)
        pad.threads = threads
        runs.append((pad.follow(y, ind, want_displacement=True), pad.solves, pad.events))
    (a, sa, ea), (b, sb, eb) = runs
    for x, w in zip(a, b):
        np.testing.assert_array_equal(x, w)  # the ridges are independent: the same bits
    assert (sa, ea) == (sb, eb)
    with pytest.raises(ValueError, match="threads"):
        Pad(pad.model, 0.5, threads=0)


@pytest.mark.parametrize("backend", ["cpp", "python"])
def test_follow_errors_leave_the_history_unchanged(backend):
    scene = tm.scenes.paper("fig6", n_ridges=2)
    y, ind = scene.plate_motion()
    pad = Pad.from_scene(scene, backend=backend)
    pad.follow(y[:400], ind[:400])
    before = [s.get_state() for s in pad.solvers]
    counts = (pad.solves, pad.events)
    bad = ind[400:].copy()
    bad[300] = np.nan
    with pytest.raises(ValueError, match="finite"):
        pad.follow(y[400:], bad)
    for s, b in zip(pad.solvers, before):
        same_history(b, s.get_state())
    # a breakaway cascade that cannot converge, on ridge 1 only
    pad.solvers[1].max_iter, pad.solvers[1].max_active_set_iter = 0, 0
    with pytest.raises(ContactConvergenceError, match="did not converge"):
        pad.follow(y[400:], ind[400:])
    for s, b in zip(pad.solvers, before):
        same_history(b, s.get_state())
    assert (pad.solves, pad.events) == counts
    pad.solvers[1].max_iter, pad.solvers[1].max_active_set_iter = 60, 25
    ref = Pad.from_scene(scene, backend=backend)
    a = pad.follow(y[400:], ind[400:])
    ref.follow(y[:400], ind[:400])
    b = ref.follow(y[400:], ind[400:])
    # as if the failed calls never happened (to round-off: the compiled kernel may
    # factor a piece afresh that the uninterrupted run solved by bordering)
    np.testing.assert_array_equal(a[2], b[2])
    assert np.max(np.abs(a[0] - b[0])) <= RTOL * np.max(np.abs(b[0]))
