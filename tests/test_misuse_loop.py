"""Misbehaving stage drivers, outputs that cannot be written, damaged result and cache files:
a clear error naming the culprit, raised before the long work, and nothing recorded is lost."""
from __future__ import annotations

import hashlib
import json
import math
import os
import pickle

import numpy as np
import pytest
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.cli import main
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.loop import ArraySource, LoopRunner, SimulatedStage, StageError
from tactile_mirror.pipeline import MirrorPipeline, PaperController

FS = 1000.0


def make_pipeline():
    rng = np.random.default_rng(5)
    h = 6
    w = {"w1": rng.normal(size=(h, 5)), "b1": rng.normal(size=h), "w2": 3 * rng.normal(size=(2, h)),
         "b2": rng.normal(size=2), "input_mean": np.zeros(4), "input_gain": np.array([3e-3, 3e-3, 3e-5, 3e-5]),
         "fs": FS}
    est = StressRateEstimator(PVDFCircuit(), FS, 4, bandwidth=100.0)
    return MirrorPipeline(w, FS, 2, estimator=est, controller=PaperController(threshold=0.0, gain=1.0),
                          v_limit=5.0, u_limit=5.0)


def samples(n, ni):
    rng = np.random.default_rng(0)
    return 0.05 * np.sin(np.arange(n)[:, None] * 0.02 * np.arange(1, ni + 1)) + 0.01 * rng.normal(size=(n, ni))


class FaultyStage(SimulatedStage):
    """A simulated stage whose driver fails on demand: ``move_to`` raises at tick
    ``fail_move``, ``position`` returns ``bad_position`` from tick ``bad_at`` on."""

    def __init__(self, fail_move=None, bad_position=None, bad_at=None, fail_advance=None, fail_stop=False):
        super().__init__()
        self.fail_move, self.bad_position, self.bad_at = fail_move, bad_position, bad_at
        self.fail_advance, self.fail_stop = fail_advance, fail_stop
        self.ticks = self.stops = 0

    def position(self):
        if self.bad_at is not None and self.ticks >= self.bad_at:
            return self.bad_position
        return super().position()

    def move_to(self, x):
        if self.ticks == self.fail_move:
            raise OSError("driver timeout")
        super().move_to(x)

    def advance(self, dt):
        if self.ticks == self.fail_advance:
            raise ConnectionError("link lost")
        self.ticks += 1
        return super().advance(dt)

    def stop(self):
        self.stops += 1
        if self.fail_stop:
            raise OSError("stop not acknowledged")
        super().stop()


def reference(n):
    """The first ``n`` ticks of an undisturbed run."""
    pipe = make_pipeline()
    return LoopRunner(pipe, SimulatedStage(), ArraySource(samples(n, pipe.n_inputs))).run(n_ticks=n)


# ---------------------------------------------------------------- A: LoopRunner and the stage driver
def test_a_failing_move_to_stops_the_stage_and_keeps_the_ticks_run():
    pipe = make_pipeline()
    x = samples(50, pipe.n_inputs)
    stage = FaultyStage(fail_move=12)
    with pytest.raises(StageError, match=r"stage\.move_to\(.*\) raised at tick 12: OSError: driver timeout") as exc:
        LoopRunner(pipe, stage, ArraySource(x)).run(n_ticks=50)
    err = exc.value
    assert isinstance(err, RuntimeError) and isinstance(err.__cause__, OSError)  # the driver's error, chained
    assert stage.stops == 1
    part, ref = err.partial, reference(12)
    assert len(part.t) == part.samples.shape[0] == part.latency_ns.size == part.tick_ns.size == 12
    np.testing.assert_array_equal(part.samples, x[:12])
    np.testing.assert_array_equal(part.outputs, ref.outputs)  # the ticks run, exactly as without the fault
    np.testing.assert_array_equal(part.stage_position, ref.stage_position)
    rec = part.to_recording(pipe.config)  # the partial run is a valid recording
    assert rec.samples.shape == (12, pipe.n_inputs)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, None, "0.1", np.zeros(2), np.array(0.001), True,
                                 np.float64("nan"), 1j], ids=repr)
def test_a_position_that_is_not_a_finite_real_number_is_refused(bad):
    pipe = make_pipeline()
    stage = FaultyStage(bad_position=bad, bad_at=5)
    with pytest.raises(StageError, match=r"stage\.position\(\) returned .* at tick 5: a position must be a finite real"
                       ) as exc:
        LoopRunner(pipe, stage, ArraySource(samples(30, pipe.n_inputs))).run(n_ticks=30)
    assert stage.stops == 1
    part = exc.value.partial
    assert len(part.t) == 5 and np.all(np.isfinite(part.stage_position))
    np.testing.assert_array_equal(part.outputs, reference(5).outputs)


def test_a_bad_position_before_the_first_tick():
    pipe = make_pipeline()
    stage = FaultyStage(bad_position=math.nan, bad_at=0)
    with pytest.raises(StageError, match="before the first tick") as exc:
        LoopRunner(pipe, stage, ArraySource(samples(10, pipe.n_inputs))).run(n_ticks=10)
    assert stage.stops == 1 and len(exc.value.partial.t) == 0
    with pytest.raises(TypeError, match="x0"):
        LoopRunner(pipe, SimulatedStage(), ArraySource(samples(10, pipe.n_inputs))).run(n_ticks=10, x0="0.1")


@pytest.mark.parametrize("value", [0, np.float32(0.0), np.int64(0), 0.0])
def test_real_scalar_positions_are_accepted(value):
    pipe = make_pipeline()
    stage = FaultyStage(bad_position=value, bad_at=0)
    res = LoopRunner(pipe, stage, ArraySource(samples(10, pipe.n_inputs)), command=False).run(n_ticks=10)
    assert len(res.t) == 10 and res.stage_position.dtype == np.float64 and stage.stops == 0


def test_a_failing_advance_keeps_the_tick_it_commanded():
    pipe = make_pipeline()
    stage = FaultyStage(fail_advance=7)
    with pytest.raises(StageError, match=r"stage\.advance\(.*\) raised at tick 7") as exc:
        LoopRunner(pipe, stage, ArraySource(samples(20, pipe.n_inputs))).run(n_ticks=20)
    assert isinstance(exc.value.__cause__, ConnectionError) and stage.stops == 1
    np.testing.assert_array_equal(exc.value.partial.outputs, reference(8).outputs)


def test_a_failing_stop_is_reported_with_the_driver_error():
    pipe = make_pipeline()
    stage = FaultyStage(fail_move=3, fail_stop=True)
    with pytest.raises(StageError, match="stage.stop\\(\\) failed too: OSError: stop not acknowledged") as exc:
        LoopRunner(pipe, stage, ArraySource(samples(20, pipe.n_inputs))).run(n_ticks=20)
    assert len(exc.value.partial.t) == 3


@pytest.mark.parametrize("error", [ValueError("bad sample"), KeyboardInterrupt()], ids=lambda e: type(e).__name__)
def test_any_other_error_stops_the_stage_and_propagates_unchanged(error):
    class Source(ArraySource):
        def read(self, stage_position, t):
            if self.i == 4:
                raise error
            return super().read(stage_position, t)

    pipe = make_pipeline()
    stage = FaultyStage()
    with pytest.raises(type(error)) as exc:
        LoopRunner(pipe, stage, Source(samples(20, pipe.n_inputs))).run(n_ticks=20)
    assert exc.value is error and stage.stops == 1


def test_a_normal_run_leaves_the_stage_on_its_target():
    pipe = make_pipeline()
    stage = FaultyStage()
    res = LoopRunner(pipe, stage, ArraySource(samples(20, pipe.n_inputs))).run(n_ticks=20)
    assert len(res.t) == 20 and stage.stops == 0


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


# ---------------------------------------------------------------- B: the loop commands' --out
def _must_not_run(*args, **kwargs):
    raise AssertionError("the work ran before --out was checked")


@pytest.fixture
def no_loop_work(monkeypatch):
    from tactile_mirror.contact import plants
    from tactile_mirror.lab.loop import envelope, experiment
    from tactile_mirror.loop import scene

    for module, name in ((envelope, "design_law"), (envelope, "law_controllers"), (envelope, "run_envelope"),
                         (experiment, "calibrate_shear_weights"), (experiment, "calibrate_shear"),
                         (scene, "run_scene"), (plants, "FemPad")):
        monkeypatch.setattr(module, name, _must_not_run)


@pytest.mark.parametrize("command", ["design", "envelope", "realtime"])
def test_loop_out_that_is_a_file_fails_before_the_work(command, tmp_path, capsys, no_loop_work):
    target = tmp_path / "taken"
    target.write_text("keep me")
    assert main(["loop", command, "--out", str(target)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: --out") and str(target) in err and "not a folder" in err
    assert "Traceback" not in err and "Errno" not in err
    assert target.read_text() == "keep me"


@pytest.mark.parametrize("command, name", [("design", "loop_design.json"), ("realtime", "realtime.json"),
                                           ("envelope", "loop_envelope.json")])
def test_loop_output_file_that_is_a_folder_fails_before_the_work(command, name, tmp_path, capsys, no_loop_work):
    (tmp_path / name).mkdir()
    assert main(["loop", command, "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error:") and name in err and "Traceback" not in err


# ---------------------------------------------------------------- C: the envelope's results file
@pytest.fixture
def fake_envelope(monkeypatch):
    """run_envelope with the design and every scene faked: counts the scenes run."""
    from types import SimpleNamespace

    from tactile_mirror.lab.loop import envelope
    from tactile_mirror.loop import scene

    calls = []
    design = SimpleNamespace(summary=lambda: {"fake": True}, shear_weights=None, controller=None)

    def laws(*args, **kwargs):
        calls.append("design")
        return {"open loop": None, "paper": None, "default": None}, design

    def run_scene(sc, *args, **kwargs):
        calls.append(sc.seed)
        n = round(sc.duration * sc.fs)
        t = np.arange(n) / sc.fs
        finger = 1e-3 * np.sin(t)
        log = {"slip_fraction": np.zeros((2, n)), "pad": np.zeros(n), "force_y": np.ones(n), "force_z": np.ones(n)}
        summary = {"gross_slips": 0, "gross_slip_time_s": 0.0, "tracking_rms_mm": 0.5, "tracking_max_mm": 1.0}
        return SimpleNamespace(t=t, finger=finger, log=log, summary=lambda: summary)

    monkeypatch.setattr(envelope, "law_controllers", laws)
    monkeypatch.setattr(scene, "run_scene", run_scene)
    return calls


def _envelope(path, **kw):
    from tactile_mirror.lab.loop.envelope import run_envelope

    return run_envelope(path, speeds=(0.005,), n_seeds=2, laws=("open loop",), duration=1.0, weights={},
                        progress=False, **kw)


GOOD_ROW = {"condition": "nominal", "law": "open loop", "speed": 0.005, "seed": 0, "paths": "report",
            "gross_slips": 0, "tracking_rms_mm": 0.5, "finger_peak_acceleration": 0.1}


@pytest.mark.parametrize("text, problem", [
    ('{"rows": [{"condition": "nominal", ', "not valid JSON"),
    ("", "not valid JSON"),
    ("[]", "JSON list, not an object"),
    ("{}", "has no 'rows'"),
    ('{"rows": {}}', "'rows' of type dict"),
    ('{"rows": [{"condition": "nominal", "law": "paper"}]}', "row 0 lacks 'speed'"),
    (json.dumps({"rows": [GOOD_ROW, {**GOOD_ROW, "speed": "fast"}]}), "row 1 has speed='fast', not a number"),
    (json.dumps({"rows": [GOOD_ROW, 3]}), "row 1 is a int"),
    (json.dumps({"rows": [{**GOOD_ROW, "seed": 1.5}]}), "row 0 has seed=1.5, not an integer"),
    (json.dumps({"rows": [GOOD_ROW], "path_sets": []}), "'path_sets' is a list"),
])
def test_a_damaged_results_file_is_named_before_the_design(text, problem, tmp_path, fake_envelope):
    path = tmp_path / "env.json"
    path.write_text(text)
    with pytest.raises(ValueError, match="envelope results file") as exc:
        _envelope(str(path))
    assert str(path) in str(exc.value) and problem in str(exc.value)
    assert fake_envelope == []  # neither the design nor a scene ran
    assert path.read_text() == text  # the file is as it was


def test_the_envelope_saves_atomically_and_resumes(tmp_path, fake_envelope):
    path = tmp_path / "env.json"
    (tmp_path / "env.json.tmp").mkdir()  # the old fixed temporary name: in the way, and not used any more
    data = _envelope(path)  # a pathlib.Path is fine too
    assert fake_envelope == ["design", 0, 1] and len(data["rows"]) == 2
    assert json.loads(path.read_text()) == data
    assert sorted(os.listdir(tmp_path)) == ["env.json", "env.json.tmp"]  # no temporary left behind
    fake_envelope.clear()
    again = _envelope(str(path))
    assert fake_envelope == ["design"] and again["rows"] == data["rows"]  # nothing rerun


def test_an_unwritable_results_file_is_found_before_the_design(tmp_path, fake_envelope):
    (tmp_path / "env.json").mkdir()
    with pytest.raises(IsADirectoryError, match="env.json"):
        _envelope(str(tmp_path / "env.json"))
    assert fake_envelope == []


# ---------------------------------------------------------------- D: simulate_cached's scene cache
@pytest.fixture
def fake_simulation(monkeypatch):
    """simulate_cached with the simulation faked (tiny real SimulationResults); counts the simulations."""
    from tactile_mirror.contact.simulation import SimulationResult
    from tactile_mirror.lab.detector import scene_cache

    calls = []

    def simulate_scenes(scenes, progress=True, executor=None):
        calls.append(len(scenes))
        return [SimulationResult(scene=None, t=np.arange(3) / FS, fs=FS, plate_y=np.zeros(3), indent=np.full(3, i))
                for i in range(len(scenes))]

    monkeypatch.setattr(scene_cache, "simulate_scenes", simulate_scenes)
    monkeypatch.setattr(scene_cache, "random_scenes", lambda n, seed, **kwargs: list(range(n)))
    return calls


def _only_file(folder):
    (name,) = os.listdir(folder)
    return folder / name


@pytest.mark.parametrize("damage", ["truncated", "empty", "dict", "short list", "foreign items"])
def test_a_damaged_cache_file_is_a_miss_that_is_replaced(damage, tmp_path, fake_simulation):
    from tactile_mirror.lab.detector.scene_cache import simulate_cached

    first = simulate_cached(3, 7, {"duration": 1.0}, tmp_path, progress=False)
    cache = _only_file(tmp_path)
    good = cache.read_bytes()
    cache.write_bytes({"truncated": good[: len(good) // 2], "empty": b"",
                       "dict": pickle.dumps({"rows": []}), "short list": pickle.dumps(first[:2]),
                       "foreign items": pickle.dumps([1, 2, 3])}[damage])
    with pytest.warns(RuntimeWarning, match=f"scene cache '{cache}'.*simulating the scenes again"):
        res = simulate_cached(3, 7, {"duration": 1.0}, tmp_path, progress=False)
    assert fake_simulation == [3, 3] and len(res) == 3
    assert [r.indent[0] for r in res] == [0, 1, 2]
    assert _only_file(tmp_path) == cache  # replaced in place, no temporary left behind
    again = simulate_cached(3, 7, {"duration": 1.0}, tmp_path, progress=False)  # a hit again
    assert fake_simulation == [3, 3] and [r.indent[0] for r in again] == [0, 1, 2]


def test_a_cache_dir_that_is_a_file_fails_before_simulating(tmp_path, fake_simulation):
    from tactile_mirror.lab.detector.scene_cache import simulate_cached

    target = tmp_path / "cache"
    target.write_text("not a folder")
    with pytest.raises(NotADirectoryError, match=f"cache_dir '{target}' is a file"):
        simulate_cached(2, 1, {}, target, progress=False)
    with pytest.raises(OSError, match="cache_dir"):
        simulate_cached(2, 1, {}, target / "sub", progress=False)  # its parent is a file
    with pytest.raises(TypeError, match="cache_dir"):
        simulate_cached(2, 1, {}, 3.5, progress=False)
    assert fake_simulation == []


def test_the_cache_key_covers_arrays_in_full_and_keeps_the_existing_keys():
    from tactile_mirror import __version__
    from tactile_mirror.lab.detector import build_options, scene_cache

    a, b = np.zeros(5000), np.zeros(5000)
    b[2500] = 1.0
    assert repr(a) == repr(b)  # what collided

    def key(kw):
        return scene_cache.cache_key(3, 1, kw, __version__)

    assert key({"x": a}) != key({"x": b})
    assert key({"x": a}) == key({"x": a.copy()})  # the content, not the object
    assert key({"x": a}) != key({"x": a.astype(np.float32)}) != key({"x": a.reshape(50, 100)})
    assert key({"x": (a,)}) != key({"x": (b,)})
    # plain options keep the key the existing caches were saved under
    for kw in (build_options.TRAIN_KWARGS, build_options.TEST_KWARGS, {**build_options.TEST_KWARGS, "n_ridges": 6},
               {}):
        old = hashlib.sha256(repr((3, 1, sorted(kw.items()), __version__)).encode()).hexdigest()[:16]
        assert key(kw) == old


# ---------------------------------------------------------------- E: the loop scene's mount
@pytest.mark.parametrize("stiffness", [1e-3, 1.0, 999.0])
def test_a_mount_too_soft_for_the_model_is_named_at_the_scene(stiffness):
    """mount_stiffness=1e-3 carried the pad metres off the stage and failed mid-run as the
    plant's "dy must lie within 1 m"."""
    from tactile_mirror.loop.scene import MIN_MOUNT_STIFFNESS, LoopScene

    with pytest.raises(ValueError, match=f"mount_stiffness must be at least {MIN_MOUNT_STIFFNESS:g} N/m"):
        LoopScene(mount_stiffness=stiffness)
    assert LoopScene(mount_stiffness=MIN_MOUNT_STIFFNESS).mount_stiffness == MIN_MOUNT_STIFFNESS


# ---------------------------------------------------------------- F: the loop experiment's plant names
@pytest.mark.parametrize("call", ["make_laws", "default_weights", "train_detector_on_brush", "open_and_closed"])
def test_an_unknown_plant_is_a_value_error_listing_the_plants(call):
    """An unknown plant name was a bare KeyError."""
    from tactile_mirror.lab.loop import experiment

    kwargs = {"make_laws": {"weights": {}}, "open_and_closed": {"weights": {}}}.get(call, {})
    with pytest.raises(ValueError, match=r"plant must be one of \['brush', 'fem'\], got 'rubber'"):
        getattr(experiment, call)(plant="rubber", **kwargs)


# ---------------------------------------------------------------- G: the envelope's classes, laws and plant
def test_repeated_speeds_laws_and_conditions_run_once_with_a_warning(tmp_path, fake_envelope):
    """A repeated --speeds or --laws value ran its class twice (and the table counted its rows
    twice)."""
    from tactile_mirror.lab.loop.envelope import run_envelope

    with pytest.warns(UserWarning, match="given more than once") as record:
        data = run_envelope(str(tmp_path / "env.json"), speeds=(0.005, 0.005, 0.0050000001), n_seeds=2,
                            laws=("open loop", "open loop"), conditions=("nominal", "nominal"), duration=1.0,
                            weights={}, progress=False)
    assert fake_envelope == ["design", 0, 1] and len(data["rows"]) == 2
    (t,) = data["table"]
    assert t["runs"] == 2
    assert {str(w.message).split(":")[0] for w in record} == {"speeds (m/s)", "laws", "conditions"}


def test_the_envelope_reports_the_speed_its_paths_ran_and_warns_when_capped(tmp_path, fake_envelope):
    """Where the path set's acceleration limit binds, the paths peak below the class's speed;
    the rows and table named only the class's (asked) speed."""
    import warnings

    from tactile_mirror.lab.loop.envelope import PATH_SETS, envelope_table, run_envelope

    fast = PATH_SETS["tuning-fast2"]
    with pytest.warns(UserWarning, match=r"acceleration limit \(0.5 m/s\^2\).*20 mm/s: 2 of 2 paths peak at 1"):
        run_envelope(str(tmp_path / "fast.json"), speeds=(0.005, 0.02), n_seeds=2, laws=("open loop",),
                     paths=fast, duration=3.0, weights={}, progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a class its paths reach: no warning
        run_envelope(str(tmp_path / "slow.json"), speeds=(0.005,), n_seeds=2, laws=("open loop",),
                     paths=fast, duration=3.0, weights={}, progress=False)
    row = {"paths": "tuning-fast2", "condition": "nominal", "law": "open loop", "speed": 0.02, "gross_slips": 0,
           "tracking_rms_mm": 0.01, "finger_peak_acceleration": 0.5, "seed": 0}
    (t,) = envelope_table([dict(row, finger_peak_speed=0.016), dict(row, seed=1, finger_peak_speed=0.018)])
    assert t["speed_mm_s"] == pytest.approx(20.0) and t["capped_runs"] == 2
    assert (t["peak_speed_run_mm_s_min"], t["peak_speed_run_mm_s_max"]) == pytest.approx((16.0, 18.0))
    (t,) = envelope_table([dict(row, finger_peak_speed=0.02)])
    assert t["capped_runs"] == 0 and t["peak_speed_run_mm_s_max"] == pytest.approx(20.0)


def test_the_envelope_command_prints_the_speed_run_and_its_notes(tmp_path, fake_envelope, capsys):
    assert main(["loop", "envelope", "--out", str(tmp_path), "--speeds", "5,20,20", "--seeds", "1",
                 "--laws", "open loop,open loop", "--paths", "tuning-fast2", "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert "| peak speed mm/s | peak speed run mm/s |" in out
    assert len([line for line in out.splitlines() if line.startswith("| nominal | open loop |")]) == 2
    notes = err.splitlines()
    assert len(notes) == 3 and all(line.startswith("warning: ") for line in notes)
    assert "[0.02] given more than once" in notes[0] and "['open loop'] given more than once" in notes[1]
    assert "acceleration limit" in notes[2] and "20 mm/s: 1 of 1 paths" in notes[2]


def test_an_unknown_plant_is_named_before_the_design(tmp_path, fake_envelope):
    with pytest.raises(ValueError, match=r"plant must be one of \['brush', 'fem'\], got 'rubber'"):
        _envelope(str(tmp_path / "env.json"), plant="rubber")
    assert fake_envelope == []
