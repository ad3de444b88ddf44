"""Loop glue: controllers' validation, the simulated stage, the loop runner, recordings."""
from __future__ import annotations

import math

import numpy as np
import pytest
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.loop import (
    ArraySource,
    LoopRunner,
    Recording,
    RecordingError,
    SimulatedStage,
    Stage,
    StageError,
    StageLimits,
)
from tactile_mirror.pipeline import MirrorPipeline, PaperController, VelocityController, controller_from_dict

FS = 1000.0


def make(controller=None, fs=FS, n_ridges=2):
    rng = np.random.default_rng(5)
    h = 6
    w = {"w1": rng.normal(size=(h, 5)), "b1": rng.normal(size=h), "w2": 3 * rng.normal(size=(2, h)),
         "b2": rng.normal(size=2), "input_mean": np.zeros(4), "input_gain": np.array([3e-3, 3e-3, 3e-5, 3e-5]),
         "fs": fs}
    est = StressRateEstimator(PVDFCircuit(), fs, 2 * n_ridges, bandwidth=min(100.0, fs / 4))
    return MirrorPipeline(w, fs, n_ridges, estimator=est, controller=controller, v_limit=5.0, u_limit=5.0)


def samples(n, ni, seed=0):
    rng = np.random.default_rng(seed)
    return 0.05 * np.sin(np.arange(n)[:, None] * 0.02 * np.arange(1, ni + 1)) + 0.01 * rng.normal(size=(n, ni))


@pytest.mark.parametrize("cls, kwargs, match", [
    (PaperController, {"gain": -1}, "gain"),
    (PaperController, {"threshold": 1.0}, "threshold"),
    (PaperController, {"threshold": float("nan")}, "threshold"),
    (PaperController, {"x_min": 0.1, "x_max": 0.2}, "bracket"),
    (PaperController, {"x_min": 0.0, "x_max": 0.0}, "x_max"),
    (PaperController, {"direction_sign": 0}, "direction_sign"),
    (PaperController, {"asym_tau": 0}, "asym_tau"),
    (PaperController, {"asym_deadband": -1}, "asym_deadband"),
    (VelocityController, {"v_max": 0}, "v_max"),
    (VelocityController, {"a_max": -2}, "a_max"),
    (VelocityController, {"threshold": 0.6, "y_full": 0.5}, "y_full"),
    (VelocityController, {"y_full": 1.5}, "y_full"),
    (VelocityController, {"ramp_gain": -1}, "ramp_gain"),
    (VelocityController, {"pred_boost": -0.1}, "pred_boost"),
    (PaperController, {"slip_hold": -1.0}, "slip_hold"),
])
def test_controller_validation(cls, kwargs, match):
    with pytest.raises(ValueError, match=match):
        cls(**kwargs)


def test_controller_types_and_round_trip():
    with pytest.raises(TypeError, match="gain"):
        PaperController(gain="fast")
    with pytest.raises(TypeError, match="v_max"):
        VelocityController(v_max=True)
    c = VelocityController(v_max=0.03)
    assert controller_from_dict(c.params()) == c
    boosted = VelocityController(ramp_gain=0.0, pred_boost=1.5, shear_gain=1e-3)
    assert controller_from_dict(boosted.params()) == boosted
    assert controller_from_dict(None).kind == "none"
    with pytest.raises(ValueError, match="kind"):
        controller_from_dict({"kind": "pid"})
    with pytest.raises(ValueError, match="no parameter"):
        controller_from_dict({"kind": "paper", "kp": 1.0})
    with pytest.raises(ValueError, match="y_pred and asym"):
        c.run(np.zeros(3), np.zeros(4), FS)


def test_simulated_stage_limits_delay_and_lag():
    lim = StageLimits(-0.01, 0.01, 0.02, 1.0)
    st = SimulatedStage(lim, delay=0.005)
    assert isinstance(st, Stage)
    st.move_to(0.05)  # clipped to the travel
    assert st.status()["clipped"] == 1
    dt = 1e-3
    xs = np.array([st.advance(dt) for _ in range(2000)])
    v = np.diff(np.concatenate([[0.0], xs])) / dt
    assert xs[:4].max() == 0.0  # dead time: nothing for 5 ms
    assert np.abs(v).max() <= 0.02 + 1e-9
    assert np.abs(np.diff(v)).max() <= 1.0 * dt * 1.5 + 1e-9
    assert xs[-1] == pytest.approx(0.01, abs=1e-9)
    lagged = SimulatedStage(lim, lag=0.02)
    lagged.move_to(0.001)
    x = [lagged.advance(dt) for _ in range(300)]
    assert x[-1] == pytest.approx(0.001, rel=1e-3)
    assert lagged.position() == x[-1]
    lagged.stop()
    assert lagged.status()["fault"] is False
    for bad in ({"delay": -1}, {"lag": float("nan")}, {"x0": 1.0}):
        with pytest.raises(ValueError):
            SimulatedStage(lim, **bad)
    with pytest.raises(ValueError, match="v_max"):
        StageLimits(-1, 1, 0, 1)
    with pytest.raises(ValueError, match="dt"):
        st.advance(0.0)


def test_runner_equals_block_and_measures_latency():
    pipe = make(VelocityController(threshold=0.2, y_full=0.6, v_max=0.01, a_max=0.5))
    x = samples(1500, pipe.n_inputs)
    x[700, 1] = np.nan
    stage = SimulatedStage(StageLimits(-0.05, 0.05, 0.05, 2.0))
    res = LoopRunner(pipe, stage, ArraySource(x)).run(n_ticks=2000)
    assert len(res.t) == 1500  # the source ended first
    ref = make(VelocityController(threshold=0.2, y_full=0.6, v_max=0.01, a_max=0.5))
    out, acc = ref.process_block(x, accepted=True)
    assert np.array_equal(res.outputs, out)
    np.testing.assert_array_equal(res.accepted, acc)
    assert res.latency_ns.shape == (1500,) and np.all(res.latency_ns > 0)
    p = res.latency_percentiles()
    assert p["p50"] <= p["p99"] <= p["p99.9"] <= p["max"]
    assert res.status["rejected"] == 1
    assert np.ptp(res.stage_position) > 0  # the stage followed the commands


def test_runner_realtime_pacing():
    pipe = make(PaperController(), fs=10000.0)
    x = samples(1000, pipe.n_inputs)
    stage = SimulatedStage()
    res = LoopRunner(pipe, stage, ArraySource(x), realtime=True).run(duration=0.1)
    assert len(res.t) == 1000 and res.realtime
    assert res.overruns >= 0 and res.late_starts >= 0
    with pytest.raises(ValueError, match="exactly one"):
        LoopRunner(pipe, stage, ArraySource(x)).run()
    with pytest.raises(TypeError, match="read"):
        LoopRunner(pipe, stage, object())
    with pytest.raises(TypeError, match="move_to"):
        LoopRunner(pipe, object(), ArraySource(x))


def test_open_loop_never_commands_the_stage():
    pipe = make(PaperController(threshold=0.0, gain=1.0))
    stage = SimulatedStage()
    res = LoopRunner(pipe, stage, ArraySource(samples(300, pipe.n_inputs)), command=False).run(n_ticks=300)
    assert np.all(res.stage_position == 0.0) and stage.status()["moves"] == 0


# -- a misbehaving stage driver: stopped, its error named, the ticks run kept -------------------

def make_pipeline():
    """The pipeline the stage-driver tests run: the paper's law at threshold 0, gain 1."""
    return make(PaperController(threshold=0.0, gain=1.0))


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


def test_recording_round_trip_and_bit_identical_replay(tmp_path):
    pipe = make(VelocityController(v_max=0.01, a_max=0.5, threshold=0.1, y_full=0.5))
    x = samples(800, pipe.n_inputs)
    x[100:103, 2] = np.inf
    stage = SimulatedStage(lag=0.005)
    res = LoopRunner(pipe, stage, ArraySource(x)).run(n_ticks=800, x0=0.001)
    rec = res.to_recording(pipe.config, {"scene": "synthetic"})
    path = tmp_path / "run.npz"
    rec.save(path)
    back = Recording.load(path)
    assert back.metadata["scene"] == "synthetic" and back.x0 == 0.001
    assert np.array_equal(back.samples, x)
    assert back.verify()
    out, _acc = back.replay()
    assert np.array_equal(out.view(np.uint64), res.outputs.view(np.uint64))
    # a changed output is detected
    back.outputs[5, 0] = np.nextafter(back.outputs[5, 0], np.inf)
    assert not back.verify()


def test_recording_errors(tmp_path):
    pipe = make()
    x = samples(10, pipe.n_inputs)
    out, acc = pipe.process_block(x, accepted=True)
    ok = {"fs": FS, "samples": x, "outputs": out, "accepted": acc, "stage_position": np.zeros(10),
          "config": pipe.config}
    with pytest.raises(RecordingError, match="outputs"):
        Recording(**dict(ok, outputs=out[:, :-1]))
    with pytest.raises(RecordingError, match="accepted"):
        Recording(**dict(ok, accepted=acc.astype(int)))
    with pytest.raises(RecordingError, match="fs"):
        Recording(**dict(ok, fs=2 * FS))
    with pytest.raises(RecordingError, match="JSON"):
        Recording(**ok, metadata={"f": object()})
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(RecordingError, match="not a readable"):
        Recording.load(bad)
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(RecordingError, match="not a tactile-mirror recording"):
        Recording.load(tmp_path / "other.npz")
    rec = Recording(**ok)
    rec.save(tmp_path / "r.npz")
    with np.load(tmp_path / "r.npz") as z:
        d = dict(z)
    d["format_version"] = np.array(99)
    np.savez(tmp_path / "v99.npz", **d)
    with pytest.raises(RecordingError, match="version 99"):
        Recording.load(tmp_path / "v99.npz")
    with pytest.raises(FileNotFoundError):
        Recording.load(tmp_path / "missing.npz")


def test_boosted_shear_law_is_proportional_and_scheduled_by_y_pred():
    # ramp_gain 0: no relay term; the speed is the shear feedback, its gain raised by y_pred.
    c = VelocityController(threshold=0.2, y_full=0.6, v_max=5.0, a_max=1e6, shear_gain=0.5, ramp_gain=0.0,
                           pred_boost=3.0, asym_tau=1e6, x_min=-100.0, x_max=100.0)
    n = 40
    asym = np.zeros(n)
    asym[0] = 1.0 * FS  # a step of the asymmetry integrator to a = 1 (rate x s)
    _, v_low = c.run(np.full(n, 0.1), asym, FS)      # below the threshold: plain shear gain
    _, v_high = c.run(np.full(n, 0.6), asym, FS)     # at y_full: gain x (1 + pred_boost)
    _, v_mid = c.run(np.full(n, 0.4), asym, FS)
    np.testing.assert_allclose(v_low[5:], 0.5, rtol=1e-6)  # the integrator leaks 4e-8
    np.testing.assert_allclose(v_high[5:], 0.5 * 4.0, rtol=1e-6)
    np.testing.assert_allclose(v_mid[5:], 0.5 * 2.5, rtol=1e-6)
    _, v_neg = c.run(np.full(n, 0.6), -asym, FS)    # no relay: the speed follows the sign of a
    np.testing.assert_allclose(v_neg, -v_high, rtol=1e-12)
    _, v_none = c.run(np.full(n, 0.9), np.zeros(n), FS)  # high y_pred alone does not move the stage
    assert np.all(v_none == 0.0)


def test_slip_guard_holds_then_retares():
    c = VelocityController(threshold=0.2, y_full=0.6, v_max=5.0, a_max=1e6, shear_gain=0.5, ramp_gain=0.0,
                           asym_tau=1e6, x_min=-100.0, x_max=100.0, slip_hold=0.01)
    n = 60
    asym = np.zeros(n)
    asym[0] = FS  # a = 1 from the first tick
    slip = np.zeros(n, dtype=bool)
    slip[20:25] = True
    _, v = c.run(np.zeros(n), asym, FS, slip=slip)
    _, v_free = c.run(np.zeros(n), asym, FS)
    np.testing.assert_allclose(v[:20], v_free[:20])
    hold = round(0.01 * FS)
    assert np.all(v[20:24 + hold] == 0.0)  # held through the slip and slip_hold after it
    assert np.all(v[24 + hold:] == 0.0)    # then tared: the asymmetry of before counts no more
    assert np.all(v_free[20:] > 0.4)
    with pytest.raises(ValueError, match="slip"):
        c.run(np.zeros(n), asym, FS, slip=np.zeros(n + 1, dtype=bool))


def test_slip_guard_waits_for_a_confirmed_slip():
    # slip_confirm: a slip shorter than it leaves the law alone; a longer one starts the
    # guard on its (confirm + 1)-th tick; C++ (pipeline controller) and reference agree.
    c = VelocityController(threshold=0.2, y_full=0.6, v_max=5.0, a_max=1e6, shear_gain=0.5, ramp_gain=0.0,
                           asym_tau=1e6, x_min=-100.0, x_max=100.0, slip_hold=0.01, slip_confirm=0.003)
    n = 80
    asym = np.zeros(n)
    asym[0] = FS
    _, v_free = c.run(np.zeros(n), asym, FS)
    short = np.zeros(n, dtype=bool)
    short[20:23] = True                      # 3 ticks = slip_confirm: not yet a slip
    _, v = c.run(np.zeros(n), asym, FS, slip=short)
    np.testing.assert_array_equal(v, v_free)
    long = np.zeros(n, dtype=bool)
    long[20:26] = True                       # 6 ticks: the guard starts on the 4th
    _, v = c.run(np.zeros(n), asym, FS, slip=long)
    np.testing.assert_array_equal(v[:23], v_free[:23])
    assert np.all(v[23:] == 0.0)             # held, then tared
    with pytest.raises(ValueError, match="slip_confirm"):
        VelocityController(slip_confirm=-1.0)


def test_slip_guard_ignores_a_slip_reported_without_shear():
    # slip_min_asym: a slip reported while |asymmetry| is below the gate leaves the law alone;
    # above it, the guard holds as before.
    kw = dict(threshold=0.2, y_full=0.6, v_max=5.0, a_max=1e6, shear_gain=0.5, ramp_gain=0.0, asym_tau=1e6,
              x_min=-100.0, x_max=100.0, slip_hold=0.01)
    n = 60
    asym = np.zeros(n)
    asym[0] = FS  # a = 1
    slip = np.zeros(n, dtype=bool)
    slip[20:25] = True
    _, v_free = VelocityController(**kw).run(np.zeros(n), asym, FS)
    _, v_gated = VelocityController(**kw, slip_min_asym=1.5).run(np.zeros(n), asym, FS, slip=slip)
    np.testing.assert_array_equal(v_gated, v_free)
    _, v_open = VelocityController(**kw, slip_min_asym=0.5).run(np.zeros(n), asym, FS, slip=slip)
    assert np.all(v_open[20:] == 0.0)
    with pytest.raises(ValueError, match="slip_min_asym"):
        VelocityController(slip_min_asym=-1.0)
