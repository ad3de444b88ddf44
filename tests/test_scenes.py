"""Scenes: the paper's Figure 5(b) plate profiles, explicit trajectories, random sets."""
import numpy as np
import pytest
import tactile_mirror as tm


def test_paper_profiles_follow_figure_5b():
    y6, z6 = tm.scenes.paper("fig6").plate_motion()
    t = tm.scenes.paper("fig6").t
    assert t.size == 2000 and t[1] - t[0] == pytest.approx(1e-3)
    # down at 0.06 mm/s for 0.5 s (30 um), then sideways at 0.2 mm/s
    np.testing.assert_allclose(z6[t <= 0.5], 0.06e-3 * t[t <= 0.5], atol=1e-15)
    np.testing.assert_allclose(z6[t >= 0.5], 30e-6, atol=1e-15)
    assert np.all(y6[t <= 0.5] == 0)
    np.testing.assert_allclose(np.diff(y6[t > 0.5]), 0.2e-3 * 1e-3, rtol=1e-9)
    for name, (a, b) in (("fig7", (1.00, 1.05)), ("fig8", (1.40, 1.45))):
        y, z = tm.scenes.paper(name).plate_motion()
        np.testing.assert_array_equal(z, z6)
        still = (t >= a) & (t <= b)
        assert np.ptp(y[still]) < 1e-15  # the plate stands still during the stop
        np.testing.assert_allclose(y[t < a], y6[t < a])
        # after the stop the plate lags fig6 by the stop length
        late = t > b + 0.01
        np.testing.assert_allclose(y[late], y6[late] - 0.2e-3 * (b - a), atol=1e-12)


def test_explicit_trajectory_overrides_the_profile():
    y = np.linspace(0, 1e-4, 50)
    z = np.full(50, 20e-6)
    s = tm.Scene(trajectory=(y, z), fs=500.0)
    assert s.n_samples == 50 and s.t[-1] == pytest.approx(49 / 500)
    py, pz = s.plate_motion()
    np.testing.assert_array_equal(py, y)
    np.testing.assert_array_equal(pz, z)
    with pytest.raises(ValueError, match="trajectory"):
        tm.Scene(trajectory=(y, z[:-1]))
    with pytest.raises(ValueError, match="trajectory"):
        tm.Scene(trajectory=(y, np.full(50, np.nan)))


@pytest.mark.parametrize("kw, name", [({"fs": 0}, "fs"), ({"duration": -1}, "duration"),
                                      ({"slide_speed": -1e-3}, "slide_speed"), ({"n_ridges": 0}, "n_ridges"),
                                      ({"noise": np.inf}, "noise"), ({"stop_after_slip": -1}, "stop_after_slip")])
def test_bad_arguments_are_named(kw, name):
    with pytest.raises(ValueError, match=name):
        tm.Scene(**kw)


@pytest.mark.parametrize("kw, error, name", [
    ({"finger_radius": 0.0, "n_ridges": 6}, ValueError, "finger_radius"),
    ({"finger_radius": np.nan}, ValueError, "finger_radius"),
    ({"field_times": (0.5, np.nan)}, ValueError, r"field_times\[1\]"),
    ({"trajectory": (np.ones(5) * 1j, np.zeros(5))}, TypeError, "trajectory"),
    ({"friction": "0.5"}, TypeError, "friction"),
    ({"kinetic_ratio": None}, TypeError, "kinetic_ratio"),
    ({"fs": True}, TypeError, "fs"),
    ({"stop_after_slip": np.nan}, ValueError, "stop_after_slip"),
])
def test_what_simulate_would_fail_on_is_refused_at_construction(kw, error, name):
    # (these reached simulate() and failed there, or a complex trajectory lost its
    # imaginary part with only a warning)
    with pytest.raises(error, match=f"^{name}"):
        tm.Scene(**kw)
    # a flat finger (infinite radius) is a scene
    assert tm.Scene(finger_radius=np.inf, n_ridges=6).finger_radius == np.inf


@pytest.mark.parametrize("kw, exc, match", [
    ({"stops": ("12",)}, TypeError, r"stops\[0\]"), ({"stops": "12"}, TypeError, "stops"),
    ({"stops": ((True, 2.0),)}, TypeError, r"stops\[0\]"), ({"n_ridges": True}, TypeError, "n_ridges"),
    ({"n_ridges": float("inf")}, TypeError, "n_ridges"), ({"n_ridges": None}, TypeError, "n_ridges"),
    ({"seed": True}, TypeError, "seed"), ({"duration": 1e300, "fs": 1e300}, ValueError, "at most 1e"),
    ({"circuit": None}, TypeError, "circuit"), ({"geometry": None}, TypeError, "geometry"),
    ({"duration": 0.2, "outputs": {"fields"}, "field_times": (0.1, 0.2)}, ValueError, r"field_times\[1\]"),
])
def test_scene_fields_are_checked_at_construction(kw, exc, match):
    with pytest.raises(exc, match=match):
        tm.Scene(**kw)


def test_random_scenes_stay_in_their_ranges_and_take_overrides():
    scenes = tm.scenes.random(20, seed=1, friction=(0.5, 0.6), n_ridges=6, stop_probability=1.0)
    assert len(scenes) == 20
    for s in scenes:
        assert 0.5 <= s.friction <= 0.6 and s.n_ridges == 6 and len(s.stops) == 1
        a, b = s.stops[0]
        assert 0.02 <= b - a <= 0.1
    assert tm.scenes.random(0) == []
    with pytest.raises(ValueError, match="stop_probability"):
        tm.scenes.random(2, stop_probability=2.0)
    with pytest.raises(ValueError, match="n must"):
        tm.scenes.random(-1)


def test_random_scenes_from_the_cli_and_their_ranges():
    """`simulate --scene random` always failed (its scalar --noise reached a (low, high) range)."""
    from tactile_mirror import scenes
    from tactile_mirror.cli import build_parser, scene_from_args

    args = build_parser().parse_args(["simulate", "--scene", "random", "--friction", "0.5", "--seed", "3"])
    sc = scene_from_args(args)
    assert sc.friction == 0.5 and sc.noise == args.noise  # the options given are fixed values
    assert repr(scenes.random(2, seed=7)) == repr(scenes.random(2, seed=7, friction=(0.45, 0.85)))  # as before
    for kw, exc, match in (({"friction": (0.9, 0.4)}, ValueError, "friction"), ({"noise": "ab"}, TypeError, "noise"),
                           ({"duration": 0.5}, ValueError, "duration must be at least 0.9 s"),
                           ({"seed": 1.7}, ValueError, "seed"), ({"n": True}, ValueError, "n must be")):
        n = kw.pop("n", 1)
        with pytest.raises(exc, match=match):
            scenes.random(n, **kw)


# ---------------------------------------------------------------- validity of the model
def test_an_indent_beyond_the_small_strain_range_is_refused_naming_the_limit():
    with pytest.raises(ValueError, match=r"indent_speed.*small-strain limit of 200 um.*MAX_INDENT_STRAIN = 0\.1"):
        tm.Scene(indent_speed=1.0)  # 0.5 m on a 2 mm ridge
    limit = tm.scenes.MAX_INDENT_STRAIN * tm.Scene().geometry.height
    # the indent reached is what counts: speed x the indent phase, or x the run if shorter
    tm.Scene(indent_speed=limit / 0.5 * 0.999)
    with pytest.raises(ValueError, match="small-strain"):
        tm.Scene(indent_speed=limit / 0.5 * 1.001)
    tm.Scene(indent_speed=limit / 0.2, duration=0.19)  # stops short of the limit
    # the limit scales with the ridge
    from tactile_mirror.geometry import RidgeGeometry

    tall = RidgeGeometry(height=4e-3)
    tm.Scene(indent_speed=limit / 0.5 * 1.5, geometry=tall)
    # explicit trajectories are held to the same limit
    y = np.zeros(10)
    with pytest.raises(ValueError, match="trajectory.*small-strain"):
        tm.Scene(trajectory=(y, np.linspace(0, 1.01 * limit, 10)))
    tm.Scene(trajectory=(y, np.linspace(-1e-3, limit, 10)))  # above the ridge is fine


@pytest.mark.parametrize("kw, match", [
    ({"noise": 1e308}, "noise must be below 1 V rms"),
    ({"noise": 1.0}, "noise must be below"),
    ({"seed": -1}, "seed must be a non-negative integer"),
    ({"seed": 1.5}, "seed"),
    ({"duration": 1e-4}, "at least 2 samples, got 0"),
    ({"duration": 1e-3}, "at least 2 samples, got 1"),
    ({"fs": 1.0, "duration": 1.0}, "at least 2 samples"),
])
def test_scenes_the_model_cannot_mean_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        tm.Scene(**kw)


@pytest.mark.parametrize("seed", [True, "1", None])
def test_a_seed_that_is_not_a_number_is_a_type_error(seed):
    with pytest.raises(TypeError, match="seed must be a non-negative integer"):
        tm.Scene(seed=seed)


def test_the_edges_of_validity_are_accepted():
    assert tm.Scene(duration=2e-3).n_samples == 2
    assert tm.Scene(noise=0.5, seed=2**70).noise == 0.5
    assert tm.Scene(seed=np.int64(3)).seed == 3


def test_every_scene_the_library_builds_is_valid():
    from tactile_mirror.lab.detector.build_options import TEST_KWARGS, TRAIN_KWARGS

    for name in ("fig6", "fig7", "fig8"):
        tm.scenes.paper(name)
    for kw in ({}, TRAIN_KWARGS, TEST_KWARGS):
        assert len(tm.scenes.random(300, seed=11, **kw)) == 300
