"""Contact model: analytic checks (Hertz, Cattaneo-Mindlin), the reduction, force
balance, mesh convergence and the paper's Figs. 6-8 properties."""
import dataclasses

import numpy as np
import pytest
import tactile_mirror as tm
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.contact import (
    OPEN,
    SLIP,
    STICK,
    ContactConvergenceError,
    ContactSolver,
    Pad,
    ridge_model,
    simulate,
)
from tactile_mirror.contact.solver import BACKENDS
from tactile_mirror.estimator import estimate_stress_rate
from tactile_mirror.geometry import RidgeGeometry, wide_block

FS = 1000.0


@pytest.fixture(scope="module")
def block():
    return ridge_model(wide_block(contact_halfwidth=1.2e-3))


@pytest.fixture(scope="module")
def ridge():
    return ridge_model(RidgeGeometry())


def hertz(P, geom):
    E = geom.material.plane_strain_modulus
    a = np.sqrt(4 * P * geom.top_radius / (np.pi * E))
    return a, 2 * P / (np.pi * a)


# ------------------------------------------------------------------ analytic checks
@pytest.mark.parametrize("backend", BACKENDS)
def test_hertz_line_contact_on_wide_block(block, backend):
    # indented to 5 um, then on to 10 um from there (frictionless: the path does not
    # matter, and the reference follows the second press from the first's contact
    # instead of from the free block again)
    m = block
    n = m.n_nodes
    solver = ContactSolver(m, 1e-8, backend=backend)  # frictionless
    for delta in (5e-6, 10e-6):
        st = solver.step(0.0, m.geometry.height - delta)
        p = -st.forces[n:] / m.weights
        P = -st.forces[n:].sum()
        a_h, p0_h = hertz(P, m.geometry)
        ys = m.node_y[p > 0]
        a = 0.5 * (ys.max() - ys.min())
        assert abs(a / a_h - 1) < 0.03, f"delta {delta}: contact half-width {a / a_h:.3f} of Hertz's"
        assert abs(p.max() / p0_h - 1) < 0.03, f"delta {delta}: peak pressure {p.max() / p0_h:.3f} of Hertz's"
        # the pressure profile is elliptical: compare at |y| < 0.9 a
        inner = np.abs(m.node_y) < 0.9 * a_h
        shape = p0_h * np.sqrt(1 - (m.node_y[inner] / a_h) ** 2)
        assert np.max(np.abs(p[inner] - shape)) < 0.05 * p0_h, f"delta {delta}: not elliptical"


@pytest.mark.parametrize("backend", BACKENDS)
def test_cattaneo_mindlin_stick_zone(block, backend):
    # one monotone tangential loading, checked as it passes Q = 0.2, 0.5 and 0.8 mu P
    m = block
    n = m.n_nodes
    mu = 0.5
    solver = ContactSolver(m, mu, backend=backend)
    z = m.geometry.height - 10e-6
    st = solver.step(0.0, z)
    P = -st.forces[n:].sum()
    a, _ = hertz(P, m.geometry)
    spacing = np.max(np.diff(m.node_y[np.abs(m.node_y) < a]))
    s, Q = 0.0, 0.0
    for ratio in (0.2, 0.5, 0.8):
        # load tangentially in small increments until Q = ratio * mu * P
        ds = 2e-8
        while Q < ratio * mu * P:
            s += ds
            st = solver.step(s, z)
            Q = st.forces[:n].sum()
            if Q > 0.9 * ratio * mu * P:
                ds = 2e-9
        stick = m.node_y[st.state == STICK]
        c = 0.5 * (stick.max() - stick.min())
        c_theory = a * np.sqrt(1 - Q / (mu * P))
        # one node spacing (+1 % of a for the finite block)
        assert abs(c - c_theory) <= spacing + 0.01 * a, f"Q = {ratio} mu P: stick half-width {c} vs {c_theory}"
        # about the stick zone's own centre (Dundurs beta = 0.0099 shifts it slightly)
        y = m.node_y - 0.5 * (stick.max() + stick.min())
        assert np.all(st.state[np.abs(y) < 0.9 * c_theory] == STICK), f"Q = {ratio} mu P"
        assert np.all(st.state[(np.abs(y) > 1.1 * c_theory) & (np.abs(m.node_y) < 0.9 * a)] == SLIP), \
            f"Q = {ratio} mu P"


# ------------------------------------------------------------------ the reduction
def test_reduced_equals_unreduced(ridge):
    """Every piece the path meets, solved on the condensed surface and with the full
    stiffness (sparse, no condensed quantity), from the same history: same surface
    displacements, and forces to the accuracy of the full KKT solve (it meets the
    constraints to ~4e-12 m on the fully stuck 10 um piece, whose force response has a
    condition number ~2e4)."""
    H = ridge.geometry.height
    red, full = ContactSolver(ridge, 0.5, backend="python"), ContactSolver(ridge, 0.5, reduced=False)
    path = [(0.0, 10e-6), (0.0, 30e-6), (20e-6, 30e-6), (80e-6, 30e-6), (150e-6, 30e-6)]
    seen = set()
    for y, d in path:
        before = red.get_state()
        st = red.step(y, H - d)
        after = red.get_state()
        full.set_state(before)
        for s in (red, full):
            s._uy_prev = before["uy_prev"]
            s._mu_node = np.where(st.state == SLIP, s.mu_kinetic, s.mu)
        ds = y - before["s_prev"]
        a, ua = red._solve_piece(st.state, red._sign, H - d, ds)
        b, ub = full._solve_piece(st.state, red._sign, H - d, ds)
        assert np.max(np.abs(a - b)) <= 2e-3 * np.max(np.abs(b))
        assert np.max(np.abs(ua - ub)) <= 1e-5 * np.max(np.abs(ub))
        red.set_state(after)
        seen |= set(st.state.tolist())
    assert seen == {OPEN, STICK, SLIP}  # pieces with every kind of node


def test_force_balance_and_sensor_operator(ridge):
    H = ridge.geometry.height
    n = ridge.n_nodes
    s = ContactSolver(ridge, 0.6)
    s.step(0.0, H - 30e-6)
    st = s.step(60e-6, H - 30e-6)
    f = st.forces
    reaction = ridge.reaction @ f
    np.testing.assert_allclose(reaction, [-f[:n].sum(), -f[n:].sum()], rtol=1e-8, atol=1e-9 * np.abs(f).max())
    # the precomputed sensor operator equals stresses probed from the full field
    u = ridge.displacement_field(f)
    d = ridge._full
    from tactile_mirror.contact.model import _strip_operator

    lam, mu = d["lame"]
    S = _strip_operator(ridge.geometry, d["mesh"], d["basis"], lam, mu)
    np.testing.assert_allclose(ridge.strip_stress(f).ravel(), S @ u, rtol=1e-9, atol=1e-6)


def test_strip_stress_converges_with_mesh():
    """Strip stress for one load state on three meshes: the differences shrink."""
    vals = []
    for h in (0.4e-3, 0.2e-3, 0.1e-3):
        g = RidgeGeometry(mesh_size=h, contact_mesh_size=h / 4)
        m = ridge_model(g)
        s = ContactSolver(m, 0.6)
        s.step(0.0, g.height - 30e-6)
        st = s.step(40e-6, g.height - 30e-6)
        vals.append(m.strip_stress(st.forces).ravel())
    d1 = np.max(np.abs(vals[1] - vals[0]))
    d2 = np.max(np.abs(vals[2] - vals[1]))
    assert d2 < 0.6 * d1
    assert d2 < 0.05 * np.max(np.abs(vals[2]))


def test_damped_newton_fallback_agrees_with_active_set(ridge):
    H = ridge.geometry.height
    a, b = ContactSolver(ridge, 0.6), ContactSolver(ridge, 0.6)
    b.max_active_set_iter = 0  # every step through the damped semismooth Newton method
    for y, d in [(0.0, 10e-6), (0.0, 30e-6), (30e-6, 30e-6), (90e-6, 30e-6), (150e-6, 30e-6)]:
        x, z = a.step(y, H - d), b.step(y, H - d)
        assert np.max(np.abs(x.forces - z.forces)) <= 1e-8 * np.max(np.abs(x.forces))
        np.testing.assert_array_equal(x.state, z.state)


@pytest.mark.parametrize("backend", ["cpp", "python"])
def test_nonconvergence_is_reported(ridge, backend):
    # the Alart-Curnier solve runs at a breakaway cascade (mu_kinetic < mu): with no
    # iterations allowed, the first cascade of the slide fails
    H = ridge.geometry.height
    s = ContactSolver(ridge, 0.6, max_iter=0, mu_kinetic=0.5, backend=backend)
    s.max_active_set_iter = 0
    before = s.get_state()
    with pytest.raises(ContactConvergenceError, match="did not converge"):
        for k in range(40):
            s.step(k * 5e-6, H - 30e-6)
    assert k == 0  # the indent already breaks nodes away at its edges
    for key, v in before.items():
        np.testing.assert_array_equal(np.asarray(s.get_state()[key]), np.asarray(v))


def test_friction_arguments_are_checked(ridge):
    with pytest.raises(ValueError, match="mu_kinetic"):
        ContactSolver(ridge, 0.5, mu_kinetic=0.6)
    with pytest.raises(ValueError, match="mu must"):
        ContactSolver(ridge, -0.1)
    with pytest.raises(ValueError, match="kinetic_ratio"):
        tm.Scene(kinetic_ratio=1.2)


@pytest.mark.parametrize("backend", ["cpp", "python"])
def test_contact_setters_check_and_keep_every_parameter_on_a_refusal(ridge, backend):
    s = ContactSolver(ridge, 1.0, mu_kinetic=0.8, backend=backend)
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
    ref = ContactSolver(ridge, 0.1, backend=backend)
    s.set_friction(0.1)
    for solver in (s, ref):
        solver.reset()
    np.testing.assert_allclose(s.step(0.0, 20e-6).forces, ref.step(0.0, 20e-6).forces, rtol=0, atol=1e-9)


def test_pad_friction_changes_every_ridge_up_and_down(ridge):
    pad = Pad(ridge, 0.5, n_ridges=3, mu_kinetic=0.4)
    pad.mu = 1.0  # up: the kinetic coefficient passes the old static one on the way
    assert [(s.mu, s.mu_kinetic) for s in pad.solvers] == [(1.0, 0.8)] * 3
    pad.mu = 0.25
    assert [(s.mu, s.mu_kinetic) for s in pad.solvers] == [(0.25, 0.2)] * 3
    with pytest.raises(ValueError, match="mu"):
        pad.mu = float("inf")
    with pytest.raises(TypeError, match="mu"):
        pad.mu = "0.5"
    assert [(s.mu, s.mu_kinetic) for s in pad.solvers] == [(0.25, 0.2)] * 3


def test_model_is_cached():
    g = RidgeGeometry()
    assert ridge_model(g) is ridge_model(RidgeGeometry())


# ------------------------------------------------------------------ the paper's scenes
@pytest.fixture(scope="module")
def paper_runs():
    return {name: simulate(tm.scenes.paper(name)) for name in ("fig6", "fig7", "fig8")}


def rates(res):
    r1, r2 = estimate_stress_rate(res.v_out[0], res.u_out[0], res.scene.circuit, res.fs)
    return res.t, r1[0] - r1[1], r2[0] - r2[1]


def test_fig6_slips_in_the_papers_window(paper_runs):
    r = paper_runs["fig6"]
    assert 1.4 <= r.slip_time <= 1.5
    assert r.slip_fraction[0, -1] == 1.0
    # incipient slip: under the growing tangential load the stuck length shrinks
    # steadily (the ridge tilts, its trailing part lifts off, slip spreads from the
    # contact edge) until nothing is stuck
    mid = simulate(dataclasses.replace(r.scene, duration=1.45, outputs=frozenset({"state"})))
    w = ridge_model().weights
    stuck = [w[mid.node_state[0, :, round(tt * 1000)] == STICK].sum() for tt in (1.0, 1.1, 1.2, 1.3, 1.4)]
    assert all(b < a for a, b in zip(stuck, stuck[1:]))
    assert stuck[-1] < 0.1 * stuck[0]


def test_fig6_rate_grows_then_drops_at_slip(paper_runs):
    t, d1, d2 = rates(paper_runs["fig6"])
    ts = paper_runs["fig6"].slip_time
    before = (t > ts - 0.15) & (t < ts - 0.01)
    after = (t > ts + 0.05) & (t < ts + 0.3)
    growth = (t > 1.05) & (t < 1.3)
    assert np.ptp(d1[growth]) > 20e3  # the L-R stress rate swings by > 20 kPa/s from ~1.1 s
    assert np.mean(np.abs(d1[before])) > 20 * np.mean(np.abs(d1[after]))  # sharp drop at slip
    at_slip = np.abs(t - ts) < 0.02
    assert np.max(np.abs(d2[at_slip])) > 2 * np.max(np.abs(d2[(t > 0.55) & (t < ts - 0.05)]))


def test_fig7_stop_at_A(paper_runs):
    t, d1, d2 = rates(paper_runs["fig7"])
    during = (t > 1.015) & (t < 1.045)
    moving = (t > 0.9) & (t < 0.99)
    assert np.max(np.abs(d1[during])) < 0.05 * np.max(np.abs(d1[moving]))  # zero rate while stopped
    quiet = np.max(np.abs(d2[(t > 0.6) & (t < 0.98)]))
    for edge in (1.00, 1.05):  # impulses of the 2nd-order rate at stop and restart
        assert np.max(np.abs(d2[np.abs(t - edge) < 0.01])) > 2 * quiet
    assert abs(paper_runs["fig7"].slip_time - paper_runs["fig6"].slip_time - 0.05) <= 0.01


def test_fig8_stop_at_B_delays_slip(paper_runs):
    r6, r8 = paper_runs["fig6"], paper_runs["fig8"]
    assert abs(r8.slip_time - r6.slip_time - 0.05) <= 0.01
    t, d1, d2 = rates(r8)
    # a large 2nd-order impulse at the stop and restart, before slip
    impulse = np.max(np.abs(d2[(t > 1.39) & (t < r8.slip_time - 0.003)]))
    assert impulse > 2 * np.max(np.abs(d2[(t > 0.6) & (t < 1.35)]))
    # and the gross slip itself releases stored shear: a stress drop no stop produces
    at_slip = np.min(d1[np.abs(t - r8.slip_time) < 0.01])
    assert at_slip < -3 * np.max(np.abs(d1[(t > 0.6) & (t < 1.35)]))
    stopped = (t > 1.41) & (t < 1.44)
    assert np.all(r8.slip_fraction[0, stopped] == 0.0)  # nothing slides while the plate stands


# ------------------------------------------------------------------ scenes, outputs, stepping
def test_outputs_follow_the_request():
    s = tm.scenes.paper("fig6", duration=0.6, outputs=frozenset({"forces"}))
    r = simulate(s)
    assert r.force_z is not None and r.stress is None and r.v_out is None and r.node_state is None
    r2 = simulate(dataclasses.replace(s, outputs=frozenset({"signals", "state"})))
    assert r2.v_out.shape == (1, 2, 600) and r2.node_state.shape[0] == 1 and r2.force_z is None


def test_a_field_time_after_the_last_sample_is_the_last_sample():
    r = tm.simulate(tm.Scene(duration=0.2, outputs={"fields", "forces"}, field_times=(0.0, 0.1, 0.1999)))
    assert sorted(r.fields) == [0.0, 0.1, 0.1999]  # (0.1999 rounded past the end and was dropped)


@pytest.mark.parametrize("backend", BACKENDS)
def test_pad_advance_matches_simulate_and_inner_ridges_press_deeper(backend):
    s = tm.scenes.paper("fig6", duration=0.8, n_ridges=6)
    stepping = "every" if backend == "cpp" else "auto"  # the same law in simulate and the pad
    r = simulate(s, backend=backend, stepping=stepping)
    pad = Pad.from_scene(s, backend=backend, stepping=stepping)
    y, z = s.plate_motion()
    for i in range(y.size):
        st = pad.advance(y[i], z[i])
    np.testing.assert_allclose(st.strip_stress, r.stress[..., -1], rtol=1e-10, atol=1e-6)
    assert r.stress.shape == (6, 2, 3, 800) and r.v_out.shape == (6, 2, 800)
    fz = np.abs(st.forces[:, ridge_model().n_nodes:].sum(axis=1))
    assert fz[2] > fz[0] and fz[3] > fz[5]  # inner ridges carry more


def test_scene_validation():
    with pytest.raises(ValueError, match="friction"):
        tm.Scene(friction=0)
    with pytest.raises(ValueError, match="stops"):
        tm.Scene(stops=((1.0, 0.5),))
    with pytest.raises(ValueError, match="outputs"):
        tm.Scene(outputs=frozenset({"everything"}))
    with pytest.raises(ValueError, match="trajectory"):
        tm.Scene(trajectory=(np.zeros(5), np.zeros(4)))
    with pytest.raises(ValueError, match="name"):
        tm.scenes.paper("fig9")
    with pytest.raises(TypeError, match="scene"):
        simulate("fig6")


def test_a_pad_or_scene_of_more_ridges_than_a_finger_covers_is_refused_by_name(ridge):
    """Scene(n_ridges=100000) ran out of memory in simulate, with no message."""
    from tactile_mirror.contact import FemPad
    from tactile_mirror.contact.pad import MAX_RIDGES

    for n in (MAX_RIDGES + 1, 100_000):
        with pytest.raises(ValueError, match=f"n_ridges must be at most {MAX_RIDGES}"):
            tm.Scene(n_ridges=n)
        with pytest.raises(ValueError, match="n_ridges"):
            Pad(ridge, 0.5, n_ridges=n)
        with pytest.raises(ValueError, match="n_ridges"):
            FemPad(n)
    with pytest.raises(TypeError, match="n_ridges"):
        FemPad(6.7)  # (was 6 ridges)
    assert tm.Scene(n_ridges=MAX_RIDGES).n_ridges == MAX_RIDGES


def test_random_scenes_are_deterministic_and_varied():
    a, b = tm.scenes.random(6, seed=3), tm.scenes.random(6, seed=3)
    assert [s.friction for s in a] == [s.friction for s in b]
    assert len({round(s.friction, 6) for s in a}) == 6
    assert any(s.stops for s in a)


def test_simulate_many_with_a_dask_executor():
    distributed = pytest.importorskip("distributed")
    scenes = [tm.scenes.paper("fig6", duration=0.3, outputs=frozenset({"forces"}), friction=f)
              for f in (0.5, 0.7)]
    with distributed.LocalCluster(n_workers=1, processes=False, threads_per_worker=1,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        res = tm.simulate_many(scenes, executor=client.get_executor(), progress=False)
    direct = [simulate(s) for s in scenes]
    for r, d in zip(res, direct):
        np.testing.assert_array_equal(r.force_z, d.force_z)
    with pytest.raises(TypeError, match="executor must be"):  # (was an AttributeError on 'submit')
        tm.simulate_many(scenes, executor=object(), progress=False)


def test_own_worker_pool_gives_the_bits_of_this_process_whatever_its_thread_settings(monkeypatch):
    import os

    from threadpoolctl import threadpool_limits

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    scenes = [tm.scenes.paper("fig6", duration=0.2, outputs=frozenset({"forces"}), friction=f) for f in (0.5, 0.7)]
    with threadpool_limits(limits=2):  # the parent's BLAS threaded: every task pins its own to 1
        pool = tm.simulate_many(scenes, progress=False, max_workers=2)
        here = tm.simulate_many(scenes, progress=False, max_workers=1)  # in this process
    assert "OMP_NUM_THREADS" not in os.environ and os.environ["OPENBLAS_NUM_THREADS"] == "3"  # restored
    for p, h, s in zip(pool, here, scenes):
        assert p.scene == s and h.scene is s
        np.testing.assert_array_equal(p.force_z, h.force_z)
        assert (p.slip_time, p.events) == (h.slip_time, h.events)


# ------------------------------------------------------------------ arguments taken silently
def test_more_arguments_that_were_taken_silently():
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
