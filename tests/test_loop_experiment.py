"""The closed-loop experiment's pieces: contact plants, finger paths, slip counting, short
runs, the experiment's options, and the names that moved out of the experiment module."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tactile_mirror.contact.brush import BrushRidges
from tactile_mirror.lab.loop.experiment import ExperimentOptions, calibrate_direction, run_experiment
from tactile_mirror.loop.finger import finger_trajectory, pressed_finger_path
from tactile_mirror.loop.scene import LoopScene as Scene
from tactile_mirror.loop.scene import gross_slip_events, gross_slip_starts, run_scene
from tactile_mirror.pipeline import VelocityController

FS = 1000.0


def weights(h=4):
    rng = np.random.default_rng(0)
    return {"w1": rng.normal(size=(h, 5)), "b1": rng.normal(size=h), "w2": rng.normal(size=(2, h)),
            "b2": rng.normal(size=2), "input_mean": np.zeros(4), "input_gain": np.array([1e-5, 1e-5, 1e-7, 1e-7]),
            "fs": FS}


def test_brush_ridges_partial_then_gross_slip():
    plant = BrushRidges(n_ridges=1, mu=1.0, normal_load=0.1, k_finger=100.0, n_points=20)
    frac = []
    fy = []
    for dy in np.linspace(0, 2e-3, 400):
        st = plant.advance(dy)
        frac.append(st.slip_fraction[0])
        fy.append(st.force_y)
    frac = np.array(frac)
    first = np.argmax(frac > 0)
    gross = np.argmax(frac >= 1)
    assert 0 < first < gross  # local slip before gross slip
    assert fy[-1] == pytest.approx(0.1, rel=1e-9)  # the Coulomb limit mu P
    assert np.all(np.diff(frac) >= 0)
    # slip starts at the edges
    plant.reset()
    lim = plant.mu[0] * plant.p
    plant.advance(np.linspace(0, 2e-3, 400)[first])
    q = plant.k * (np.linspace(0, 2e-3, 400)[first] - plant.s[0])
    at = np.abs(q) >= lim * (1 - 1e-9)
    assert at[0] and at[-1] and not at[len(at) // 2]
    # reversing re-sticks
    plant.advance(2e-3)
    st = plant.advance(1.9e-3)
    assert st.slip_fraction[0] == 0.0
    # strips see opposite bending
    assert np.sign(st.stress[0, 0] - st.stress[0, 1]) != 0


def test_finger_trajectory_within_limits_and_seeded():
    y = finger_trajectory(3, 2.0, FS, v_max=0.01, a_max=0.2)
    v = np.gradient(y, 1 / FS)
    assert y[0] == 0.0 and np.abs(v).max() <= 0.01 + 1e-9
    assert np.abs(np.gradient(v, 1 / FS)).max() <= 0.2 + 1e-6
    np.testing.assert_array_equal(y, finger_trajectory(3, 2.0, FS, v_max=0.01, a_max=0.2))
    assert not np.array_equal(y, finger_trajectory(4, 2.0, FS, v_max=0.01, a_max=0.2))


def test_finger_paths_too_short_are_refused_by_name():
    # a path of fewer than two samples, or one that ends before the press does, has no
    # movement to scale: a clear error instead of an IndexError deep inside
    for duration, fs in ((0.0, FS), (0.5 / FS, FS), (np.nan, FS), (1.0, 0.0)):
        with pytest.raises(ValueError, match="duration|fs"):
            finger_trajectory(0, duration, fs)
    with pytest.raises(ValueError, match="longer than the press"):
        pressed_finger_path(0, 0.2, FS, press=0.5)
    assert pressed_finger_path(0, 0.6, FS, press=0.5).size == round(0.6 * FS)


def test_gross_slip_events():
    sf = np.zeros((2, 100))
    sf[:, 10:20] = 1.0
    sf[:, 25:30] = 1.0   # merged with the first (gap < 20)
    sf[:, 60:70] = 1.0
    sf[1, 90:98] = 1.0   # one ridge only: not a contact gross slip
    assert gross_slip_events(sf) == 2
    assert gross_slip_events(sf[1:]) == 3
    assert gross_slip_events(np.zeros((2, 10))) == 0
    assert gross_slip_starts(sf).tolist() == [10, 60] and gross_slip_starts(sf[1:]).tolist() == [10, 60, 90]
    sf[:, :5] = 1.0  # slipping from the first tick
    assert gross_slip_starts(sf).tolist() == [0, 60]  # 10 starts 5 ticks after: merged


def test_short_open_and_closed_runs():
    w = weights()
    sign = calibrate_direction(w, FS)
    assert sign in (1.0, -1.0)
    sc = Scene(seed=1, duration=0.6, noise=1e-4, drop_rate=0.02)
    r_open = run_scene(sc, w, None)
    assert np.all(r_open.stage == 0.0) and r_open.tracking_max > 0
    law = VelocityController(threshold=0.15, y_full=0.5, v_max=0.03, a_max=1.0, direction_sign=sign,
                             asym_tau=2.0, shear_gain=4e-7)
    r = run_scene(sc, w, law)
    assert r.status["rejected"] > 0
    assert r.tracking_rms < r_open.tracking_rms  # the stage follows the finger
    assert set(r.summary()) >= {"gross_slips", "tracking_rms_mm", "controller"}


def test_fem_pad_plant_short_closed_loop():
    pytest.importorskip("skfem")
    from tactile_mirror.lab.loop.experiment import PLANTS, calibrate_shear

    w = weights()
    sign, a_per_m = calibrate_shear(w, FS, n_ridges=2, plant="fem")
    assert sign in (1.0, -1.0) and a_per_m > 0
    sc = Scene(seed=2, duration=0.8, plant="fem", trajectory=PLANTS["fem"]["trajectory"])
    law = VelocityController(threshold=0.99, y_full=1.0, v_max=4e-3, a_max=1.0, direction_sign=sign,
                             asym_tau=2.0, shear_gain=50.0 / a_per_m, arm_delay=0.5)
    r = run_scene(sc, w, law, n_ridges=2)
    assert np.all(r.finger[:500] == 0.0)  # the press phase
    assert np.all(r.outputs[:500, 0] == 0.0)  # armed after it
    assert r.log["force_z"][499] > r.log["force_z"][10] > 0
    assert np.ptp(r.stage) > 0


def test_experiment_options_are_frozen_and_normalised():
    o = ExperimentOptions(seeds=range(3), duration=1, plant="fem")
    assert o.seeds == (0, 1, 2) and isinstance(o.duration, float)
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.plant = "brush"  # type: ignore[misc]


def test_run_experiment_takes_options():
    w = weights()
    opts = ExperimentOptions(seeds=(1,), duration=0.3, robustness=False)
    new = run_experiment(opts, weights=w)
    assert new["rows"][0]["controller"] == "open loop" and len(new["rows"]) == 5
    with pytest.raises(TypeError, match="ExperimentOptions"):
        run_experiment([1])
    with pytest.raises(TypeError):
        run_experiment(nope=1)  # type: ignore[call-arg]
