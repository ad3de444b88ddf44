"""The rig's acquisition side: the simulated DAQ's shared-memory ring, the analog stage, the
simulated rig's process, and the NI-DAQmx adapters.

The NI-DAQmx adapters are tested against a STAND-IN of the ``nidaqmx`` module (``_FakeNidaqmx``
below, injected through ``sys.modules``): a small fake written for these tests after NI's
documented Python API (``nidaqmx.Task``, ``ai_channels.add_ai_voltage_chan``,
``timing.cfg_samp_clk_timing``, ``in_stream``, ``stream_readers.AnalogMultiChannelReader``,
``ci_channels.add_ci_lin_encoder_chan`` / ``add_ci_ang_encoder_chan``,
``ao_channels.add_ao_voltage_chan``, DAQmx error codes). It checks what the adapters ask of
that API and how they treat its errors, as the fake models them; it is no device and no
driver. The test against a real device runs only when ``TM_NIDAQ_DEVICE`` names one (e.g.
``Dev1``), and is skipped otherwise.

The simulated rig runs on the wall clock of a machine that may be shared: its deadline
misses are checked to be counted and reported, not to be zero.
"""
from __future__ import annotations

import math
import os
import sys
import threading
import time
import types
from multiprocessing import active_children, shared_memory

import numpy as np
import pytest
from tactile_mirror.loop.stage import StageLimits
from tactile_mirror.rig.analog_stage import AnalogStage
from tactile_mirror.rig.daq import Block, BlockSource, Daq, InputChannel, Overrun, StageIO, input_names
from tactile_mirror.rig.sim.config import SimRigConfig
from tactile_mirror.rig.sim.daq_shm import DaqRing, RingState, ShmBlockSource, ShmDaq
from tactile_mirror.rig.sim.process import SimulatedRig

FS, N = 1000.0, 10


# ---------------------------------------------------------------------- the ring
def _value(index, n_inputs):
    """What the test writer puts in sample ``index``: the index, plus the channel / 100."""
    return np.asarray(index, dtype=np.float64)[:, None] + np.arange(n_inputs) / 100.0


class _ClockedWriter(threading.Thread):
    """Publishes ``n_blocks`` blocks of :func:`_value` at their due times (the simulator's
    side of the ring, without the simulation), then marks the acquisition stopped."""

    def __init__(self, ring: DaqRing, n_blocks: int):
        super().__init__(daemon=True)
        self.ring, self.n_blocks = ring, n_blocks

    def run(self):
        ring = self.ring
        while not ring.t0_ns:
            time.sleep(1e-4)
        for k in range(self.n_blocks):
            ring.slot(k)[:] = _value(np.arange(k * N, (k + 1) * N), ring.n_inputs)
            wait = ring.due_ns(k) - time.monotonic_ns()
            if wait > 0:
                time.sleep(wait / 1e9)
            ring.publish(k)
        ring.set_state(RingState.STOPPED)


@pytest.fixture
def ring():
    r = DaqRing.create(FS, N, 3, capacity=8)
    yield r
    r.close()
    r.unlink()


def _drain(src):
    blocks = []
    while True:
        try:
            blocks.append(src.read_block(timeout=2.0))
        except EOFError:
            return blocks


def test_ring_blocks_arrive_in_order_on_the_wall_clock(ring):
    src = ShmBlockSource(ring)
    assert isinstance(src, BlockSource)
    src.start()
    writer = _ClockedWriter(ring, 30)
    writer.start()
    blocks = []
    for _ in range(30):
        b = src.read_block(timeout=2.0)
        assert time.monotonic_ns() >= b.t_ns  # not before its last sample's time
        blocks.append(b)
    writer.join()
    for k, b in enumerate(blocks):
        assert isinstance(b, Block) and b.samples.shape == (N, 3) and b.samples.dtype == np.float64
        assert b.samples.flags.c_contiguous                             # rows go to the pipeline as they are
        assert b.index == k * N and b.lost == 0
        assert b.t_ns == ring.t0_ns + round((k + 1) * N * 1e9 / FS)   # block k due at t0 + (k+1) n/fs
        np.testing.assert_array_equal(b.samples, _value(np.arange(b.index, b.index + N), 3))
    assert src.lost_samples == 0 and src.overruns == 0
    with pytest.raises(EOFError):
        src.read_block(timeout=0.5)


def test_ring_stalled_reader_sees_the_exact_loss(ring):
    src = ShmBlockSource(ring)
    src.start()
    writer = _ClockedWriter(ring, 40)
    writer.start()
    first = [src.read_block(timeout=2.0) for _ in range(3)]
    while ring.published < 3 + ring.capacity + 6:   # stall until 6 unread blocks fell out of the ring's 8
        time.sleep(N / FS)
    blocks = first + _drain(src)
    writer.join()
    stalled = blocks[3]
    assert stalled.lost > 0 and stalled.lost % N == 0
    assert stalled.lost >= 6 * N           # at least what fell out while stalled
    assert stalled.lost == stalled.index - (first[-1].index + N)
    assert src.overruns >= 1 and src.lost_samples == sum(b.lost for b in blocks)
    end = 0
    for b in blocks:   # contiguous: each block starts where the previous ended plus what it lost
        assert b.index == end + b.lost
        np.testing.assert_array_equal(b.samples[:, 0], np.arange(b.index, b.index + N))
        end = b.index + N
    # every sample published was returned or counted lost
    assert ring.published == 40
    assert sum(N + b.lost for b in blocks) == 40 * N


def test_ring_read_waits_and_times_out(ring):
    src = ShmBlockSource(ring, start_delay=5.0)   # the clock starts 5 s from now
    with pytest.raises(RuntimeError, match="start"):
        src.read_block(0.1)
    src.start()
    t = time.monotonic()
    with pytest.raises(TimeoutError, match="no block 0"):
        src.read_block(timeout=0.05)
    assert 0.04 <= time.monotonic() - t < 1.0
    with pytest.raises(RuntimeError, match="already"):
        src.start()
    ring.set_state(RingState.FAILED)
    with pytest.raises(RuntimeError, match="failed"):
        src.read_block(timeout=0.05)


def test_ring_analog_output_and_encoder(ring):
    daq = ShmDaq(ring)
    assert isinstance(daq, Daq) and isinstance(daq, StageIO)
    for v in (0.5, -1.25, 3.0):
        daq.write_ao(v)
    with pytest.raises(ValueError, match="range"):
        daq.write_ao(12.0)
    got = ring.take_commands()
    assert [v for _, v in got] == [0.5, -1.25, 3.0]
    stamps = [t for t, _ in got]
    assert all(0 < t <= time.monotonic_ns() for t in stamps) and stamps == sorted(stamps)
    assert ring.take_commands() == [] and ring.last_command()[1] == 3.0
    # the encoder: the initial count before the clock, then the count of the last tick whose time has come
    ring.set_initial_count(-7)
    count, t_ns = daq.read_counter()
    assert count == -7 and abs(t_ns - time.monotonic_ns()) < 1e9
    ring.start_clock(time.monotonic_ns() - 50_000_000)   # started 50 ms ago: ticks 0..48 have come
    for i in range(60):                                  # the simulator writes ahead of the ticks' times
        ring.write_count(i, 100 + i)
    count, t_ns = daq.read_counter()
    i = count - 100
    assert 48 <= i < 60 and t_ns == ring.tick_ns(i) <= time.monotonic_ns()
    daq.close()
    assert ring.last_command()[1] == 0.0   # close writes 0 V
    assert ring.stop_requested


# ---------------------------------------------------------------------- the analog stage
LIMITS = StageLimits(-0.01, 0.01, 0.05, 2.0)
CPM = 2.0e6   # counts per metre (X4)


@pytest.fixture
def shm_daq(ring):
    daq = ShmDaq(ring)
    ring.start_clock(time.monotonic_ns() - 10_000_000)
    return daq


def _set_count(ring, count):
    """The simulator's side: the encoder reads ``count`` from now on."""
    now_tick = math.floor((time.monotonic_ns() - ring.t0_ns) * ring.fs / 1e9) - 1
    for i in range(max(now_tick - 2, 0), now_tick + 40):
        ring.write_count(i, count)


def test_analog_stage_counts_to_metres(ring, shm_daq):
    stage = AnalogStage(shm_daq, LIMITS, CPM, volts_per_m_s=150.0, offset=1e-3)
    assert stage.command_mode == "per_tick"
    assert stage.position() == pytest.approx(1e-3)   # no tick written yet: the initial count, 0
    assert stage.position_age() < 1.0
    _set_count(ring, 4000)
    assert stage.position() == pytest.approx(1e-3 + 4000 / CPM)
    _set_count(ring, -3000)
    assert stage.position() == pytest.approx(1e-3 - 3000 / CPM)
    assert 0.0 <= stage.position_age() < 1.0
    assert stage.round_trip() >= 0.0
    # a counter counting down as the stage moves to +y: a negative scale
    down = AnalogStage(shm_daq, LIMITS, -CPM, volts_per_m_s=150.0)
    assert down.position() == pytest.approx(3000 / CPM)
    fresh = AnalogStage(shm_daq, LIMITS, CPM, volts_per_m_s=150.0)
    assert fresh.position_age() == math.inf


def test_analog_stage_soft_limits_are_never_written(ring, shm_daq):
    stage = AnalogStage(shm_daq, LIMITS, CPM, volts_per_m_s=150.0, gain=50.0)
    _set_count(ring, 0)
    stage.position()
    for bad in (0.0101, -0.02, 1.0):
        with pytest.raises(ValueError, match=f"x = {bad!r} m lies outside the soft limits"):
            stage.move_to(bad)
    with pytest.raises(ValueError, match="exceeds the speed limit"):
        stage.set_velocity(0.06)
    _set_count(ring, round(0.0095 * CPM))   # 0.5 mm from the end: 0.05 m/s needs 0.6 mm to stop
    stage.position()
    with pytest.raises(ValueError, match="would stop at"):
        stage.set_velocity(0.05)
    assert ring.take_commands() == []            # nothing was written
    assert stage.status()["rejected"] == 5
    stage.set_velocity(-0.05)                    # away from the end: written
    stage.move_to(0.0095 + 1e-4)                 # 0.1 mm ahead: gain * e = 5 mm/s
    stage.move_to(0.0)                           # 9.5 mm back: the speed limit
    volts = [v for _, v in ring.take_commands()]
    assert volts == pytest.approx([-0.05 * 150.0, 1e-4 * 50.0 * 150.0, -0.05 * 150.0])
    assert all(abs(v) <= 0.05 * 150.0 + 1e-12 for v in volts)


def test_analog_stage_stop_writes_zero(ring, shm_daq):
    stage = AnalogStage(shm_daq, LIMITS, CPM, volts_per_m_s=150.0)
    _set_count(ring, 0)
    stage.position()
    stage.set_velocity(0.02)
    stage.stop()
    assert [v for _, v in ring.take_commands()] == [3.0, 0.0]
    stage.close()
    assert ring.take_commands()[-1][1] == 0.0
    stage.move_to(0.001)                         # closed: nothing more
    assert ring.take_commands() == []


def test_analog_stage_position_mode(ring, shm_daq):
    stage = AnalogStage(shm_daq, LIMITS, CPM, mode="position", volts_per_m=500.0, volts_offset=0.5)
    _set_count(ring, round(0.004 * CPM))
    stage.position()
    stage.move_to(-0.008)
    with pytest.raises(ValueError, match="soft limits"):
        stage.move_to(0.011)
    with pytest.raises(ValueError, match="mode 'velocity'"):
        stage.set_velocity(0.01)
    stage.stop()                                 # holds where it was read: 0.004 m
    assert [v for _, v in ring.take_commands()] == pytest.approx([0.5 - 4.0, 0.5 + 2.0])


def test_analog_stage_checks_its_scales(shm_daq):
    with pytest.raises(ValueError, match="outside the analog output's range"):
        AnalogStage(shm_daq, LIMITS, CPM, volts_per_m_s=250.0)      # 0.05 m/s -> 12.5 V
    with pytest.raises(ValueError, match="outside the analog output's range"):
        AnalogStage(shm_daq, LIMITS, CPM, mode="position", volts_per_m=1200.0)
    with pytest.raises(ValueError, match="volts_per_m_s"):
        AnalogStage(shm_daq, LIMITS, CPM)                            # no scale: never guessed
    with pytest.raises(ValueError, match="volts_per_m"):
        AnalogStage(shm_daq, LIMITS, CPM, mode="position", volts_per_m_s=100.0)
    with pytest.raises(ValueError, match="counts_per_m"):
        AnalogStage(shm_daq, LIMITS, 0.0, volts_per_m_s=100.0)


class _BrokenIO:
    ao_range = (-10.0, 10.0)

    def __init__(self):
        self.writes = []

    def write_ao(self, volts):
        self.writes.append(volts)
        if volts != 0.0:
            raise OSError("device removed")

    def read_counter(self):
        return 0, time.monotonic_ns()


def test_analog_stage_latches_a_fault():
    io = _BrokenIO()
    stage = AnalogStage(io, LIMITS, CPM, volts_per_m_s=100.0)
    stage.position()
    with pytest.raises(OSError):
        stage.move_to(0.005)
    assert "analog output write failed" in stage.fault()
    stage.move_to(0.005)                         # after a fault: nothing but stop
    stage.stop()
    assert io.writes == [5.0, 0.0]                # the full speed, 0.05 m/s at 100 V/(m/s); then 0 V


# ---------------------------------------------------------------------- the simulated rig
def _gone(name):
    try:
        shm = shared_memory.SharedMemory(name=name)
    except FileNotFoundError:
        return True
    shm.close()
    return False


def test_simulated_rig_end_to_end():
    """~1.3 s at 1 kHz, 6 ridges on the real-time FEM pad, blocks of 10; the host commands the
    stage through the analog path once per block, then falls silent and the watchdog stops it;
    the process shuts down cleanly."""
    cfg = SimRigConfig(duration=2.0, seed=1, n_ridges=6, plant="realtime", block_size=10, watchdog=0.1)
    rig = SimulatedRig(cfg).start()
    name = rig.shm_name
    try:
        assert rig.axis_info == {"path": "analog", "mode": "velocity"}
        daq = rig.daq
        assert daq.analog_input.channels == input_names(6)
        src = daq.analog_input
        stage = AnalogStage(daq, LIMITS, cfg.counts_per_m, volts_per_m_s=cfg.volts_per_m_s)
        src.start()
        blocks = []
        for _ in range(100):                     # 1 s: the finger presses in, the stage goes to 2 mm
            blocks.append(src.read_block(timeout=5.0))
            stage.position()
            stage.move_to(0.002)
        assert stage.position() == pytest.approx(0.002, abs=2e-4)
        stage.set_velocity(0.01)                 # then silence: the watchdog stops the axis
        track = []
        for _ in range(30):
            blocks.append(src.read_block(timeout=5.0))
            track.append(stage.position())
        live = rig.status()
    finally:
        log = rig.stop()
    # blocks: contiguous (or their loss counted), finite, the sensors' layout
    end = 0
    for b in blocks:
        assert b.samples.shape == (10, 26) and np.all(np.isfinite(b.samples))
        assert b.index == end + b.lost
        end = b.index + 10
    s = np.concatenate([b.samples for b in blocks])
    assert s[-1, 25] > 1.0                       # F_z: the finger pressed in
    assert np.std(s[:, :24]) > 1e-4              # PVDF outputs with noise and hum
    # the watchdog stopped the axis: ~1 mm on at 10 mm/s for 0.1 s, then it stood still
    assert log.watchdog_trips_ns.size == 1 and any(why == "watchdog" for _, why in log.stops)
    assert 0.0025 < track[-1] < 0.0045 and track[-1] == track[-5]
    # misses counted and reported (a shared machine: not asserted to be 0)
    assert log.blocks >= 130 and log.block_compute_ns.size == log.blocks
    assert log.missed == log.lateness_ns.size and np.all(log.lateness_ns > 0)
    assert live["missed_deadlines"] <= log.missed
    summary = log.summary()
    assert summary["missed_deadlines"] == log.missed and summary["compute_p50_us"] > 0
    # every command the host wrote was logged with its time, none beyond the full speed
    volts = log.commands["volts"]
    assert volts.size == 101 and log.commands["lost"] == 0
    assert np.all(np.abs(volts) <= LIMITS.v_max * cfg.volts_per_m_s + 1e-9)
    assert np.all(np.diff(log.commands["t_ns"]) > 0)
    # shut down cleanly: the process has ended, the shared memory is gone
    assert not rig.process.is_alive() and rig.process.exitcode == 0
    assert rig.process not in active_children()
    assert _gone(name)
    assert rig.stop() is log                     # again: the same log


def test_simulated_rig_resets_its_charge_amplifiers_in_place():
    """The amplifiers' reset, asked for while the finger presses in: from the tick it is taken
    on, the PVDF circuits restart from rest at the present load (their outputs near 0, where
    the press had driven them away) and the force channels are tared; the reset is logged."""
    cfg = SimRigConfig(duration=2.0, seed=1, n_ridges=6, plant="realtime", block_size=10, noise=None,
                       force_noise=0.0)
    rig = SimulatedRig(cfg).start()
    try:
        src = rig.daq.analog_input
        src.start()
        before = np.concatenate([src.read_block(timeout=5.0).samples for _ in range(25)])   # pressing in
        rig.reset_amplifiers()
        after = np.concatenate([src.read_block(timeout=5.0).samples for _ in range(4)])
    finally:
        log = rig.stop()
    assert len(log.resets) == 1
    level = np.abs(before[-10:, :12]).max()
    assert before[-1, 25] > 1.0 and level > 1e-3                # F_z and v_out away from 0
    tared = np.flatnonzero(np.abs(after[:, 25]) < 0.02 * before[-1, 25])
    assert tared.size, after[:, 25]                             # (taken within a block or two)
    r = tared[0]
    assert np.abs(after[r, :12]).max() < 0.1 * level and abs(after[r, 24]) < 0.02 * abs(before[-1, 24]) + 1e-3
    assert np.all(np.abs(after[:r, 25]) > 0.5 * before[-1, 25])  # (before it: the old offset)


def test_simulated_rig_reports_a_failed_start():
    cfg = SimRigConfig(plant="brush", duration=1.0, axis_factory=int)   # int(config, ring) raises
    rig = SimulatedRig(cfg)
    with pytest.raises(RuntimeError, match="failed to start") as info:
        rig.start(timeout=60.0)
    assert "TypeError" in str(info.value)
    assert not rig.process.is_alive() and rig.shm_name is None


def test_sim_rig_config_checks():
    with pytest.raises(ValueError, match="lead"):
        SimRigConfig(lead=0.02)
    with pytest.raises(ValueError, match="plant"):
        SimRigConfig(plant="rubber")
    with pytest.raises(ValueError, match="counts_per_m"):
        SimRigConfig(counts_per_m=0.0)
    assert SimRigConfig().n_inputs == 26 and SimRigConfig().lead_s == pytest.approx(2e-3)


# ---------------------------------------------------------------------- NI-DAQmx (a stand-in)
class _DaqError(Exception):
    def __init__(self, message, error_code):
        super().__init__(f"{message} (Status Code: {error_code})")
        self.error_code = error_code


def _enum(name, **members):
    return types.SimpleNamespace(__name__=name, **{k: f"{name}.{k}" for k in members or {}})


def _constants():
    c = types.ModuleType("nidaqmx.constants")
    c.AcquisitionType = _enum("AcquisitionType", FINITE=1, CONTINUOUS=1)
    c.TerminalConfiguration = _enum("TerminalConfiguration", DEFAULT=1, DIFF=1, RSE=1, NRSE=1, PSEUDO_DIFF=1)
    c.OverwriteMode = _enum("OverwriteMode", OVERWRITE_UNREAD_SAMPLES=1, DO_NOT_OVERWRITE_UNREAD_SAMPLES=1)
    c.ReadRelativeTo = _enum("ReadRelativeTo", CURRENT_READ_POSITION=1, MOST_RECENT_SAMPLE=1, FIRST_SAMPLE=1)
    c.EncoderType = _enum("EncoderType", X_1=1, X_2=1, X_4=1)
    c.LengthUnits = _enum("LengthUnits", METERS=1, TICKS=1)
    c.AngleUnits = _enum("AngleUnits", DEGREES=1, TICKS=1)
    return c


class _InStream:
    """The stand-in's input buffer: the test moves the acquisition on with :meth:`acquire`."""

    def __init__(self, task):
        self.task = task
        self.input_buf_size = 0
        self.overwrite = None
        self.relative_to = "ReadRelativeTo.CURRENT_READ_POSITION"
        self.offset = 0
        self.total_samp_per_chan_acquired = 0
        self.curr_read_pos = 0
        self.fail_next = None     # an error code the next read raises

    @property
    def avail_samp_per_chan(self):
        return self.total_samp_per_chan_acquired - self.curr_read_pos

    def acquire(self, n):
        self.total_samp_per_chan_acquired += n


class _Collection:
    def __init__(self, task, kind):
        self.task, self.kind = task, kind

    def __getattr__(self, name):
        def add(*args, **kwargs):
            self.task.calls.append((name, args, kwargs))
        return add


class _FakeTask:
    tasks: list = []

    def __init__(self, new_task_name=""):
        self.name = new_task_name
        self.calls = []
        self.in_stream = _InStream(self)
        self.ai_channels = _Collection(self, "ai")
        self.ao_channels = _Collection(self, "ao")
        self.ci_channels = _Collection(self, "ci")
        self.timing = _Collection(self, "timing")
        self.state = "created"
        self.written = []
        self.count = 0.0
        _FakeTask.tasks.append(self)

    def start(self):
        self.state = "running"

    def stop(self):
        self.state = "stopped"

    def close(self):
        self.state = "closed"

    def write(self, value, auto_start=None, timeout=10.0):
        self.written.append(value)

    def read(self, number_of_samples_per_channel=None, timeout=10.0):
        return self.count


def _volts(index, channel):
    """The stand-in's analog input: sample ``index`` of ``channel``, V."""
    return 1e-3 * np.asarray(index, dtype=np.float64) + 0.1 * channel


class _Reader:
    """The stand-in of ``stream_readers.AnalogMultiChannelReader`` over a buffer of
    ``input_buf_size`` samples that overwrites unread samples (a read of overwritten samples
    raises -200279; one of samples not yet acquired -200284)."""

    def __init__(self, in_stream):
        self.s = in_stream

    def read_many_sample(self, data, number_of_samples_per_channel=-1, timeout=10.0):
        s, n = self.s, number_of_samples_per_channel
        if s.fail_next is not None:
            code, s.fail_next = s.fail_next, None
            raise _DaqError("stand-in failure", code)
        if s.relative_to.endswith("MOST_RECENT_SAMPLE"):
            start = s.total_samp_per_chan_acquired + s.offset
        else:
            start = s.curr_read_pos + s.offset
        if s.total_samp_per_chan_acquired - start > s.input_buf_size:
            raise _DaqError("Attempted to read samples that are no longer available", -200279)
        if s.total_samp_per_chan_acquired - start < n:
            raise _DaqError("Some or all of the samples requested have not yet been acquired", -200284)
        assert data.shape == (data.shape[0], n) and data.flags.c_contiguous
        idx = np.arange(start, start + n)
        for c in range(data.shape[0]):
            data[c] = _volts(idx, c)
        s.curr_read_pos = start + n
        return n


@pytest.fixture
def fake_nidaqmx(monkeypatch):
    """Install the stand-in of ``nidaqmx`` (not the real package, not a device)."""
    mod = types.ModuleType("nidaqmx")
    mod.Task = _FakeTask
    mod.constants = _constants()
    mod.errors = types.ModuleType("nidaqmx.errors")
    mod.errors.DaqError = _DaqError
    mod.stream_readers = types.ModuleType("nidaqmx.stream_readers")
    mod.stream_readers.AnalogMultiChannelReader = _Reader
    for name, m in (("nidaqmx", mod), ("nidaqmx.constants", mod.constants), ("nidaqmx.errors", mod.errors),
                    ("nidaqmx.stream_readers", mod.stream_readers)):
        monkeypatch.setitem(sys.modules, name, m)
    _FakeTask.tasks = []
    return mod


CHANNELS = (InputChannel("v_out_0L", "Dev1/ai0", v_range=(-5.0, 5.0), terminal="diff"),
            InputChannel("u_out_0L", "Dev1/ai1", terminal="diff"),
            InputChannel("force_y", "Dev1/ai4", kind="force", n_per_v=-50.0, v_range=(-10.0, 10.0),
                         terminal="rse"))


def test_nidaq_channel_map_and_timing(fake_nidaqmx):
    from tactile_mirror.rig.nidaq import NiAnalogInput

    ai = NiAnalogInput(CHANNELS, fs=FS, block_size=N, buffer_blocks=20)
    assert isinstance(ai, BlockSource) and ai.n_inputs == 3 and ai.buffer_size == 200
    task = _FakeTask.tasks[0]
    adds = [(args, kw) for name, args, kw in task.calls if name == "add_ai_voltage_chan"]
    assert [a[0] for a, _ in adds] == ["Dev1/ai0", "Dev1/ai1", "Dev1/ai4"]
    assert [kw["name_to_assign_to_channel"] for _, kw in adds] == ["v_out_0L", "u_out_0L", "force_y"]
    terminals = [kw["terminal_config"] for _, kw in adds]
    assert terminals == ["TerminalConfiguration.DIFF"] * 2 + ["TerminalConfiguration.RSE"]
    assert [(kw["min_val"], kw["max_val"]) for _, kw in adds] == [(-5.0, 5.0), (-10.0, 10.0), (-10.0, 10.0)]
    (name, args, kw), = [c for c in task.calls if c[0] == "cfg_samp_clk_timing"]
    assert args == (FS,) and kw == {"sample_mode": "AcquisitionType.CONTINUOUS", "samps_per_chan": 200}
    assert task.in_stream.input_buf_size == 200
    assert task.in_stream.overwrite == "OverwriteMode.OVERWRITE_UNREAD_SAMPLES"
    with pytest.raises(ValueError, match="no physical terminal"):
        NiAnalogInput([InputChannel("v_out_0L")], fs=FS, block_size=N)
    with pytest.raises(ValueError, match="n_per_v"):
        InputChannel("force_z", "Dev1/ai5", kind="force")


def test_nidaq_scaling_and_overflow(fake_nidaqmx):
    from tactile_mirror.rig.nidaq import NiAnalogInput

    ai = NiAnalogInput(CHANNELS, fs=FS, block_size=N, buffer_blocks=20)
    stream = _FakeTask.tasks[0].in_stream
    with pytest.raises(RuntimeError, match="start"):
        ai.read_block(0.1)
    ai.start()
    stream.acquire(2 * N)
    b0, b1 = ai.read_block(1.0), ai.read_block(1.0)
    idx = np.arange(N)
    np.testing.assert_allclose(b0.samples[:, 0], _volts(idx, 0))           # PVDF: volts as read
    np.testing.assert_allclose(b0.samples[:, 2], -50.0 * _volts(idx, 2))   # force: N/V times volts
    assert b0.samples.shape == (N, 3) and b0.samples.flags.c_contiguous
    assert (b0.index, b0.lost, b1.index, b1.lost) == (0, 0, N, 0)
    assert b1.t_ns <= time.monotonic_ns()
    # the host falls behind by more than the buffer: the oldest samples are lost, counted exactly
    stream.acquire(350)                                  # 350 unread, the buffer holds 200
    b2 = ai.read_block(1.0)
    assert b2.lost > 0 and b2.index == 2 * N + b2.lost
    assert b2.index == 370 - 100                          # resumed half a buffer behind the newest
    np.testing.assert_allclose(b2.samples[:, 1], _volts(np.arange(b2.index, b2.index + N), 1))
    b3 = ai.read_block(1.0)
    assert (b3.index, b3.lost) == (b2.index + N, 0)
    assert (ai.lost_samples, ai.overruns, ai.blocks) == (b2.lost, 1, 4)
    rest = [ai.read_block(1.0) for _ in range(stream.avail_samp_per_chan // N)]
    assert [b.index for b in rest] == list(range(b3.index + N, 370, N))
    # a block not yet acquired: a timeout, nothing consumed
    stream.acquire(N - 1)
    with pytest.raises(TimeoutError, match="no block"):
        ai.read_block(0.05)
    stream.acquire(1)
    assert ai.read_block(0.5).index == 370
    # the device's FIFO overflowed: the acquisition cannot go on
    stream.acquire(N)
    stream.fail_next = -200361
    with pytest.raises(Overrun) as info:
        ai.read_block(1.0)
    assert info.value.code == -200361 and info.value.index == 380
    ai.close()
    assert _FakeTask.tasks[0].state == "closed"


def test_nidaq_stage_io(fake_nidaqmx):
    from tactile_mirror.rig.nidaq import NiAnalogInput, NiDaq, NiStageIO

    io = NiStageIO("Dev1/ao0", "Dev1/ctr0", encoder="linear", ao_range=(-5.0, 5.0))
    ao, ci = _FakeTask.tasks
    assert ao.calls == [("add_ao_voltage_chan", ("Dev1/ao0",), {"min_val": -5.0, "max_val": 5.0})]
    assert ci.calls == [("add_ci_lin_encoder_chan", ("Dev1/ctr0",),
                         {"decoding_type": "EncoderType.X_4", "units": "LengthUnits.TICKS"})]
    assert ao.state == ci.state == "running" and ao.written == [0.0]
    io.write_ao(1.5)
    with pytest.raises(ValueError, match="range"):
        io.write_ao(5.5)
    assert ao.written == [0.0, 1.5]
    ci.count = 12345.0
    count, t_ns = io.read_counter()
    assert count == 12345 and isinstance(count, int) and t_ns <= time.monotonic_ns()
    stage = AnalogStage(io, LIMITS, 4.0e6, volts_per_m_s=100.0)
    assert stage.position() == pytest.approx(12345 / 4.0e6)
    stage.stop()
    assert ao.written[-1] == 0.0
    io.close()
    assert ao.written[-1] == 0.0 and ao.state == ci.state == "closed"
    angular = NiStageIO("Dev1/ao1", "Dev1/ctr1", encoder="angular")
    assert _FakeTask.tasks[-1].calls[0][0] == "add_ci_ang_encoder_chan"
    assert _FakeTask.tasks[-1].calls[0][2]["units"] == "AngleUnits.TICKS"
    daq = NiDaq(NiAnalogInput(CHANNELS, fs=FS, block_size=N), angular)
    assert isinstance(daq, Daq)
    daq.close()
    with pytest.raises(ValueError, match="encoder"):
        NiStageIO("Dev1/ao0", "Dev1/ctr0", encoder="magnetic")


def test_nidaq_module_loads_without_nidaqmx(monkeypatch):
    """``nidaqmx`` is imported by the adapters' constructors, not by the module."""
    import importlib

    monkeypatch.setitem(sys.modules, "nidaqmx", None)     # as if not installed
    nidaq = importlib.import_module("tactile_mirror.rig.nidaq")
    with pytest.raises(ImportError):
        nidaq.NiAnalogInput(CHANNELS, fs=FS, block_size=N)


@pytest.mark.skipif(not os.environ.get("TM_NIDAQ_DEVICE"), reason="no NI device named (set TM_NIDAQ_DEVICE)")
def test_nidaq_real_device():
    """On a real NI device (``TM_NIDAQ_DEVICE``, e.g. ``Dev1``): 0.2 s of ai0 at 1 kHz in
    blocks of 10, read in time: contiguous, nothing lost."""
    pytest.importorskip("nidaqmx")
    from tactile_mirror.rig.nidaq import NiAnalogInput

    dev = os.environ["TM_NIDAQ_DEVICE"]
    ai = NiAnalogInput([InputChannel("ai0", f"{dev}/ai0")], fs=1000.0, block_size=10)
    try:
        ai.start()
        blocks = [ai.read_block(1.0) for _ in range(20)]
    finally:
        ai.close()
    assert [b.index for b in blocks] == list(range(0, 200, 10))
    assert all(b.lost == 0 and b.samples.shape == (10, 1) for b in blocks)
