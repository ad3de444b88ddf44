"""The closed-loop experiment's pieces: contact plants, finger paths, slip counting, short
runs, the experiment's options, and the names that moved out of the experiment module."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.contact.brush import BrushRidges
from tactile_mirror.lab.loop import experiment
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


def test_brush_ridges_refuse_what_they_cannot_mean_and_keep_their_state():
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


def test_loop_simulation_pieces_refuse_what_they_cannot_mean(fast_pipeline):
    # Each of these ran and gave numbers (NaN positions, a clock stuck at inf, a mirrored
    # or NaN finger path, negative friction or stiffness, a drop rate over 1).
    from tactile_mirror.loop import ArraySource, LoopRunner, SimulatedStage
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
    runner = LoopRunner(fast_pipeline(), stage, ArraySource(np.zeros((5, fast_pipeline().n_inputs))))
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


@pytest.mark.parametrize("bad", [math.nan, None, "0.1"], ids=repr)
def test_plant_source_names_the_stage_position(bad):
    from tactile_mirror.loop.scene import LoopScene, PlantSource, make_plant, scene_finger

    sc = LoopScene(seed=1, duration=0.05, plant="brush")
    source = PlantSource(sc, make_plant(sc, 2), PVDFCircuit(), scene_finger(sc))
    source.read(0.0, 0.0)
    with pytest.raises((TypeError, ValueError), match=r"stage_position \(the stage's position\)"):
        source.read(bad, 0.001)
    assert source.k == 1  # nothing was stepped
    assert source.read(0.0, 0.001).shape == (8,)


@pytest.mark.parametrize("stiffness", [1e-3, 1.0, 999.0])
def test_a_mount_too_soft_for_the_model_is_named_at_the_scene(stiffness):
    """mount_stiffness=1e-3 carried the pad metres off the stage and failed mid-run as the
    plant's "dy must lie within 1 m"."""
    from tactile_mirror.loop.scene import MIN_MOUNT_STIFFNESS, LoopScene

    with pytest.raises(ValueError, match=f"mount_stiffness must be at least {MIN_MOUNT_STIFFNESS:g} N/m"):
        LoopScene(mount_stiffness=stiffness)
    assert LoopScene(mount_stiffness=MIN_MOUNT_STIFFNESS).mount_stiffness == MIN_MOUNT_STIFFNESS


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


@pytest.mark.parametrize("call", ["make_laws", "default_weights", "train_detector_on_brush", "open_and_closed"])
def test_an_unknown_plant_is_a_value_error_listing_the_plants(call):
    """An unknown plant name was a bare KeyError."""
    kwargs = {"make_laws": {"weights": {}}, "open_and_closed": {"weights": {}}}.get(call, {})
    with pytest.raises(ValueError, match=r"plant must be one of \['brush', 'fem'\], got 'rubber'"):
        getattr(experiment, call)(plant="rubber", **kwargs)
