"""The closed-loop experiment's pieces: contact plants, finger paths, slip counting, short
runs, the experiment's options, and the names that moved out of the experiment module."""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
import tactile_mirror
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.contact.brush import BrushRidges
from tactile_mirror.contact.plants import ContactPlant
from tactile_mirror.loop import VelocityController, experiment
from tactile_mirror.loop.experiment import ExperimentOptions, calibrate_direction, run_experiment
from tactile_mirror.loop.finger import finger_trajectory, pressed_finger_path
from tactile_mirror.loop.scene import LoopScene as Scene
from tactile_mirror.loop.scene import gross_slip_events, gross_slip_starts, make_plant, run_scene, scene_finger

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
    from tactile_mirror.loop.experiment import PLANTS, calibrate_shear

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


def test_moved_names_warn_and_resolve_to_their_new_home():
    import importlib

    for name, (module, new) in experiment._MOVED.items():
        with pytest.warns(DeprecationWarning, match=f"{module}.{new}"):
            old = getattr(experiment, name)
        assert old is getattr(importlib.import_module(module), new), name
    with pytest.warns(DeprecationWarning, match="LoopScene"):
        from tactile_mirror.loop.experiment import Scene as OldScene
    assert OldScene is Scene and OldScene is not tactile_mirror.Scene
    with pytest.raises(AttributeError, match="no_such_name"):
        experiment.no_such_name  # noqa: B018
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the names that stay do not warn
        for name in experiment.__all__:
            getattr(experiment, name)


def test_brush_plant_has_the_plant_interface():
    plant = BrushRidges(n_ridges=3)
    assert isinstance(plant, ContactPlant)
    st = plant.advance(1e-4)
    assert st.stress.shape == (3, 2) and st.slip_fraction.shape == (3,)
    plant.set_mu(0.5)
    assert np.all(plant.mu == 0.5)


def test_fem_plant_has_the_plant_interface():
    pytest.importorskip("skfem")
    from tactile_mirror.contact.plants import FemPad

    plant = FemPad(n_ridges=1, fs=FS)
    assert isinstance(plant, ContactPlant)
    plant.set_mu([0.4, 0.6])
    assert plant.mu == pytest.approx(0.5)
    st = plant.advance(0.0)
    assert st.stress.shape == (1, 2) and st.force_z > 0


def test_run_scene_takes_a_given_finger_path():
    """A recorded (here: generated elsewhere) finger path replaces the scene's own, tick for
    tick; the run lasts as long as it; a bad one is refused by name."""
    sc = Scene(seed=3, duration=0.6)
    own = run_scene(sc, weights(), None)
    path = scene_finger(Scene(seed=9, duration=0.3))
    r = run_scene(sc, weights(), None, finger=path)
    np.testing.assert_array_equal(r.finger, path)
    assert r.t.size == path.size and r.tracking_max == pytest.approx(np.abs(path).max())
    assert not np.array_equal(r.finger, own.finger[: path.size])
    for bad in (np.zeros((2, 5)), np.array([]), np.array([0.0, np.nan])):
        with pytest.raises(ValueError, match="finger"):
            run_scene(sc, weights(), None, finger=bad)
    # a plant of its own replaces the scene's; one with another ridge count is refused
    from tactile_mirror.contact.brush import BrushRidges

    slippery = [run_scene(sc, weights(), None, finger=path, plant=BrushRidges(6, mu=0.3)) for _ in range(2)]
    np.testing.assert_array_equal(slippery[0].log["force_y"], slippery[1].log["force_y"])
    assert not np.array_equal(slippery[0].log["force_y"], run_scene(sc, weights(), None, finger=path).log["force_y"])
    with pytest.raises(ValueError, match="n_ridges"):
        run_scene(sc, weights(), None, finger=path, plant=make_plant(sc, 3))


def test_pressed_finger_path_rests_then_follows_the_trajectory():
    y = pressed_finger_path(5, 1.5, FS, press=0.5, amplitude=1e-3)
    assert np.all(y[:500] == 0.0)
    np.testing.assert_array_equal(y[500:], finger_trajectory(5, 1.0, FS, amplitude=1e-3))
    np.testing.assert_array_equal(pressed_finger_path(5, 1.0, FS), finger_trajectory(5, 1.0, FS))


def test_loop_signals_are_the_circuit_stream_of_the_plant_loads():
    """Open loop, no noise: the source's v_out/u_out are the circuit's streaming form run
    offline over the plant's change of load, bit for bit."""
    sc = Scene(seed=4, duration=0.4)
    r = run_scene(sc, weights(), None)
    plant = make_plant(sc)
    loads = np.stack([plant.advance(y).stress.reshape(-1) for y in scene_finger(sc)], axis=-1)  # (12, n)
    loads = loads - loads[:, :1]
    v, u = PVDFCircuit().stream(FS, 12).process_load(loads)
    np.testing.assert_array_equal(r.log["v_out"], v.reshape(6, 2, -1))
    np.testing.assert_array_equal(r.log["u_out"], u.reshape(6, 2, -1))


@pytest.mark.parametrize("field,value,exc,match", [
    ("plant", "rubber", ValueError, "plant"),
    ("duration", -1.0, ValueError, "duration"),
    ("fs", float("nan"), ValueError, "fs"),
    ("seeds", [0, True], TypeError, "seeds"),
    ("seeds", 3, TypeError, "seeds"),
    ("seeds", [], ValueError, "seeds must hold at least one seed"),  # (ran, and wrote empty tables)
    ("seeds", [0, -1], ValueError, "seeds must be non-negative"),  # (refused only by the first scene)
    ("seeds", [np.True_], TypeError, "seeds"),
    ("robustness_seeds", -1, ValueError, "robustness_seeds"),
    ("robustness", "yes", TypeError, "robustness"),
])
def test_experiment_options_name_the_bad_field(field, value, exc, match):
    with pytest.raises(exc, match=match):
        ExperimentOptions(**{field: value})


def test_experiment_options_are_frozen_and_normalised():
    o = ExperimentOptions(seeds=range(3), duration=1, plant="fem")
    assert o.seeds == (0, 1, 2) and isinstance(o.duration, float)
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.plant = "brush"  # type: ignore[misc]


def test_run_experiment_old_keywords_warn_and_give_the_same_result():
    w = weights()
    opts = ExperimentOptions(seeds=(1,), duration=0.3, robustness=False)
    new = run_experiment(opts, weights=w)
    with pytest.warns(DeprecationWarning, match="ExperimentOptions"):
        old_kw = run_experiment(seeds=[1], duration=0.3, weights=w, robustness=False)
    with pytest.warns(DeprecationWarning, match="ExperimentOptions"):
        old_pos = run_experiment([1], 0.3, 1000.0, w, None, False)
    assert new["rows"] == old_kw["rows"] == old_pos["rows"]
    assert new["rows"][0]["controller"] == "open loop" and len(new["rows"]) == 5
    with pytest.raises(TypeError, match="not both"):
        run_experiment(opts, duration=1.0)
    with pytest.raises(TypeError, match="nope"):
        run_experiment(nope=1)
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match="plant"):
        run_experiment(plant="rubber")


def test_experiment_command_line_maps_onto_the_options():
    import argparse

    args = argparse.Namespace(seeds=3, duration=1.5, plant="fem", no_robustness=True, robustness_seeds=1)
    o = experiment.options_from_args(args)
    assert o == ExperimentOptions(seeds=(0, 1, 2), duration=1.5, plant="fem", robustness=False,
                                  robustness_seeds=1, progress=True)
    with pytest.raises(SystemExit):
        experiment.main(["--duration", "0", "--out", "unused"])
