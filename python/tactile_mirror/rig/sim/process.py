"""The simulated rig: a separate process that stands in for the pad, the sensors, the DAQ and
the stage, in real time.

:class:`SimulatedRig` starts the process (``multiprocessing``, spawn) and hands the host a
:class:`~tactile_mirror.rig.sim.daq_shm.ShmDaq` over their shared memory. The process runs,
tick by tick, on the DAQ's clock (the wall clock, ``time.monotonic_ns()``):

* the finger: a seeded band-limited path (:func:`~tactile_mirror.loop.finger.pressed_finger_path`,
  at rest while it presses in, at rest again after its ``duration``);
* the stage's axis (:class:`SimAxis`; by default :class:`AnalogAxis`: the analog output's
  volts as a velocity or position command to a servo with a lag, the encoder's counts from
  its position);
* the contact plant stepped with ``finger - pad`` (by default
  :meth:`FemPad.realtime <tactile_mirror.contact.FemPad.realtime>`, the FEM pad that keeps
  up with 1 kHz), its strips' change of load through the PVDF circuit
  (:class:`~tactile_mirror.circuit.CircuitStream`) with the sensor noise of
  :class:`~tactile_mirror.noise.SensorNoise` (mains hum included), and the force sensor's
  ``F_y`` (the finger's force less the pad's inertia) and ``F_z``, with white noise.

Each tick is computed ``lead`` s ahead of its sample time (the axis takes the commands
that arrived by then: a dead time of ``lead``), so that block ``k`` is ready when it is due
at ``t0 + (k + 1) n / fs``; it is published then. A block finished after its due time is a
missed deadline: counted, published at once, and the clock goes on (the next blocks are due
when they would have been). A communication watchdog stops the axis when no command has
come for ``watchdog`` s (it is armed by the first command; a new command moves the axis
again). On shutdown the process returns its log (:class:`SimRigLog`): every command with
its time, the stops, the deadline misses, each block's compute time.

The hook for other command paths (a serial line on a pseudo-terminal): ``axis_factory``
in :class:`SimRigConfig` builds any :class:`SimAxis` in the process; its :meth:`SimAxis.info`
reaches the host as :attr:`SimulatedRig.axis_info` (e.g. the name of its port).
"""
from __future__ import annotations

import math
import multiprocessing
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from tactile_mirror.checks import integer, real_number, sample_rate
from tactile_mirror.loop.stage import SimulatedStage, StageLimits
from tactile_mirror.noise import SensorNoise
from tactile_mirror.rig.daq import input_names
from tactile_mirror.rig.sim.daq_shm import DaqRing, RingState, ShmDaq

__all__ = ["SIM_PLANTS", "AnalogAxis", "SimAxis", "SimRigConfig", "SimRigLog", "SimulatedRig", "analog_axis"]

#: Plants of the simulated rig: ``"realtime"`` (:meth:`FemPad.realtime`), ``"fem"`` (the
#: default FEM pad, which does not keep up with 1 kHz) and ``"brush"`` (the brush model).
SIM_PLANTS = ("realtime", "fem", "brush")


@runtime_checkable
class SimAxis(Protocol):
    """An axis the simulated rig moves tick by tick, fed by its own command path.

    Every tick the process calls :meth:`poll` (take the commands that arrived by
    ``now_ns``), then, unless the watchdog stopped it, :meth:`advance`. The watchdog reads
    :meth:`last_command_ns` and calls :meth:`stop`.
    """

    def poll(self, now_ns: int) -> None:
        """Take the commands that arrived by ``now_ns`` (``monotonic_ns``)."""

    def advance(self, dt: float) -> float:
        """Move on by ``dt`` s; the position, m."""

    def position(self) -> float:
        """The position, m."""

    def last_command_ns(self) -> int:
        """``monotonic_ns`` time of the last command received (-1: none yet)."""

    def stop(self) -> None:
        """Stop now (decelerate to rest and hold)."""

    def info(self) -> dict:
        """What the host needs to reach the axis (picklable), sent when the rig is ready."""

    def log(self) -> dict:
        """Its record of the commands it received (picklable), for :class:`SimRigLog`."""

    def close(self) -> None:
        """Release what it holds (ports, threads)."""


@dataclass(frozen=True)
class SimRigConfig:
    """Settings of the simulated rig (SI units).

    Attributes
    ----------
    fs, block_size, buffer_blocks
        Sample rate (Hz), samples per block, blocks the DAQ's ring holds.
    n_ridges, plant, mu
        The pad: ridges, :data:`SIM_PLANTS`, static friction (None: the plant's default).
    seed, duration, press, trajectory
        The finger: seed of its path, the path's length (s; the finger rests after it), the
        press (s, the FEM pads press in first), keyword arguments of
        :func:`~tactile_mirror.loop.finger.finger_trajectory`.
    noise, noise_record
        Sensor noise (None: none), drawn once for ``noise_record`` s and played in a loop
        (2 s holds whole periods of 50 and 60 Hz hum at 1 kHz).
    force_noise, pad_mass
        White noise of the force sensor (N rms) and the mass it carries (kg).
    ao_mode, volts_per_m_s, volts_per_m, volts_offset
        The servo amplifier's command input: ``"velocity"`` (V per m/s) or ``"position"``
        (V per m, and the volts at 0 m).
    counts_per_m
        The encoder's counts per metre (X4).
    limits, lag
        The axis: travel (its end stops), speed and acceleration; servo time constant, s.
    ao_range
        The analog output's range, V.
    lead
        How far ahead of its sample time each tick is computed, s (at most a block; None:
        two sample periods, or the block if shorter): the axis's command dead time, and the
        slack a tick has before its block is late.
    watchdog
        The axis stops when no command has come for this long, s.
    axis_factory
        ``axis_factory(config, ring) -> SimAxis``, called in the process (so it must be
        picklable: a module-level function); None: :func:`analog_axis`.
    """

    fs: float = 1000.0
    block_size: int = 10
    buffer_blocks: int = 100
    n_ridges: int = 6
    plant: str = "realtime"
    mu: float | None = None
    seed: int = 0
    duration: float = 10.0
    press: float = 0.5
    trajectory: dict = field(default_factory=dict)
    noise: SensorNoise | None = field(default_factory=lambda: SensorNoise(hum=2e-3))
    noise_record: float = 2.0
    force_noise: float = 2e-3
    pad_mass: float = 0.02
    ao_mode: str = "velocity"
    volts_per_m_s: float = 200.0
    volts_per_m: float = 500.0
    volts_offset: float = 0.0
    counts_per_m: float = 1e7
    limits: StageLimits = StageLimits(-0.02, 0.02, 0.05, 2.0)
    lag: float = 0.002
    ao_range: tuple[float, float] = (-10.0, 10.0)
    lead: float | None = None
    watchdog: float = 0.1
    axis_factory: Callable | None = None

    def __post_init__(self) -> None:
        sample_rate(self.fs)
        integer(self.block_size, "block_size", 1)
        integer(self.buffer_blocks, "buffer_blocks", 1)
        integer(self.n_ridges, "n_ridges", 1, 64)
        integer(self.seed, "seed", 0)
        if self.plant not in SIM_PLANTS:
            raise ValueError(f"plant must be one of {SIM_PLANTS}, got {self.plant!r}")
        if self.ao_mode not in ("velocity", "position"):
            raise ValueError(f"ao_mode must be 'velocity' or 'position', got {self.ao_mode!r}")
        if self.mu is not None:
            real_number(self.mu, "mu", positive=True)
        for name in ("duration", "noise_record", "watchdog"):
            real_number(getattr(self, name), name, unit="s", positive=True)
        for name in ("press", "force_noise", "pad_mass", "lag"):
            real_number(getattr(self, name), name, nonnegative=True)
        for name in ("volts_per_m_s", "volts_per_m", "counts_per_m"):
            if real_number(getattr(self, name), name) == 0:
                raise ValueError(f"{name} must not be 0")
        real_number(self.volts_offset, "volts_offset", unit="V")
        if not isinstance(self.limits, StageLimits):
            raise TypeError(f"limits must be StageLimits, got {type(self.limits).__name__}")
        if self.noise is not None and not isinstance(self.noise, SensorNoise):
            raise TypeError(f"noise must be a SensorNoise or None, got {type(self.noise).__name__}")
        if self.lead is not None:
            lead = real_number(self.lead, "lead", unit="s", positive=True)
            if lead > self.block_size / self.fs:
                raise ValueError(f"lead must be at most one block ({self.block_size / self.fs:g} s), "
                                 f"got {lead!r}")
        if self.axis_factory is not None and not callable(self.axis_factory):
            raise TypeError("axis_factory must be callable (config, ring) -> SimAxis")

    @property
    def n_inputs(self) -> int:
        """Inputs of a sample: ``v_out``, ``u_out`` of every strip, ``F_y``, ``F_z``."""
        return 4 * self.n_ridges + 2

    @property
    def lead_s(self) -> float:
        """:attr:`lead`, or two sample periods (at most a block) if None."""
        return min(2, self.block_size) / self.fs if self.lead is None else float(self.lead)


@dataclass
class SimRigLog:
    """What the simulated rig's process recorded (times ``monotonic_ns``).

    Attributes
    ----------
    fs, block_size, t0_ns
        The DAQ clock.
    blocks : int
        Blocks published.
    block_compute_ns : ndarray of int64
        Compute time of each block (its ticks, without the waits), ns.
    missed_blocks, lateness_ns : ndarray of int64
        Blocks finished after their due time, and by how much.
    stops : list of (int, str)
        Stops of the axis and their cause (``"watchdog"``, ``"acquisition stopped"``,
        ``"shutdown"``).
    watchdog_trips_ns : ndarray of int64
    commands : dict
        The axis's command log (:meth:`SimAxis.log`); for :class:`AnalogAxis`: ``t_ns`` (when
        the host wrote each value), ``volts``, ``seen_ns`` (when the axis took it), ``lost``.
    """

    fs: float
    block_size: int
    t0_ns: int
    blocks: int
    block_compute_ns: np.ndarray
    missed_blocks: np.ndarray
    lateness_ns: np.ndarray
    stops: list
    watchdog_trips_ns: np.ndarray
    commands: dict

    @property
    def missed(self) -> int:
        """Deadline misses."""
        return int(self.missed_blocks.size)

    def summary(self) -> dict:
        """Blocks, misses and the block compute time's p50 / p99 / max, us."""
        c = self.block_compute_ns.astype(np.float64) / 1e3
        p50, p99 = (np.percentile(c, [50, 99]) if c.size else (math.nan, math.nan))
        return {"blocks": self.blocks, "missed_deadlines": self.missed,
                "compute_p50_us": float(p50), "compute_p99_us": float(p99),
                "compute_max_us": float(c.max()) if c.size else math.nan,
                "block_period_us": 1e6 * self.block_size / self.fs,
                "lateness_max_us": float(self.lateness_ns.max()) / 1e3 if self.lateness_ns.size else 0.0,
                "watchdog_trips": int(self.watchdog_trips_ns.size)}


class AnalogAxis:
    """The axis of the analog path: the host's analog-output values (from the shared memory)
    as the command of a servo amplifier.

    Velocity mode: the commanded speed ``volts / volts_per_m_s`` (within ``v_max``) is
    followed through a first-order lag ``lag`` at most at ``a_max``; the travel's ends are
    hard stops (counted in :attr:`end_stops`). Position mode: ``(volts - volts_offset) /
    volts_per_m`` is the target of a :class:`~tactile_mirror.loop.SimulatedStage`.
    """

    def __init__(self, ring: DaqRing, mode: str, limits: StageLimits, lag: float,
                 volts_per_m_s: float = 200.0, volts_per_m: float = 500.0, volts_offset: float = 0.0,
                 x0: float = 0.0):
        self.ring = ring
        self.mode = mode
        self.limits = limits
        self.lag = float(lag)
        self.volts_per_m_s = float(volts_per_m_s)
        self.volts_per_m = float(volts_per_m)
        self.volts_offset = float(volts_offset)
        self._x = float(x0)
        self._v = 0.0
        self._vc = 0.0
        self._stage = SimulatedStage(limits, delay=0.0, lag=lag, x0=x0) if mode == "position" else None
        self._last_ns = -1
        self._t: list[int] = []
        self._volts: list[float] = []
        self._seen: list[int] = []
        self.end_stops = 0

    def poll(self, now_ns: int) -> None:
        cmds = self.ring.take_commands()
        if not cmds:
            return
        for t, v in cmds:
            self._t.append(t)
            self._volts.append(v)
            self._seen.append(now_ns)
        t, v = cmds[-1]
        self._last_ns = t
        if self._stage is not None:
            self._stage.move_to((v - self.volts_offset) / self.volts_per_m)
        else:
            self._vc = min(max(v / self.volts_per_m_s, -self.limits.v_max), self.limits.v_max)

    def advance(self, dt: float) -> float:
        if self._stage is not None:
            self._x = self._stage.advance(dt)
            return self._x
        lim = self.limits
        target = self._vc
        v = self._v + (target - self._v) * (1.0 - math.exp(-dt / self.lag)) if self.lag > 0 else target
        dv = min(max(v - self._v, -lim.a_max * dt), lim.a_max * dt)
        self._v += dv
        x = self._x + self._v * dt
        if not lim.x_min <= x <= lim.x_max:
            x = min(max(x, lim.x_min), lim.x_max)
            self._v = 0.0
            self.end_stops += 1
        self._x = x
        return x

    def position(self) -> float:
        return self._x

    def last_command_ns(self) -> int:
        return self._last_ns

    def stop(self) -> None:
        if self._stage is not None:
            self._stage.stop()
        self._vc = 0.0

    def info(self) -> dict:
        return {"path": "analog", "mode": self.mode}

    def log(self) -> dict:
        return {"t_ns": np.asarray(self._t, dtype=np.int64),
                "volts": np.asarray(self._volts, dtype=np.float64),
                "seen_ns": np.asarray(self._seen, dtype=np.int64), "lost": int(self.ring.commands_lost),
                "end_stops": self.end_stops}

    def close(self) -> None:
        pass


def analog_axis(config: SimRigConfig, ring: DaqRing) -> AnalogAxis:
    """The default axis of :class:`SimRigConfig`: an :class:`AnalogAxis` with its settings."""
    return AnalogAxis(ring, config.ao_mode, config.limits, config.lag, config.volts_per_m_s,
                      config.volts_per_m, config.volts_offset)


class SimulatedRig:
    """The simulated rig's process, seen from the host.

    >>> with SimulatedRig(SimRigConfig()) as rig:       # doctest: +SKIP
    ...     src = rig.daq.analog_input
    ...     src.start()
    ...     block = src.read_block(timeout=1.0)
    ...     rig.daq.write_ao(0.5)
    >>> rig.log.summary()                                # doctest: +SKIP

    :meth:`start` spawns the process and waits until it has built its plant; the DAQ clock
    starts with ``rig.daq.analog_input.start()``. :meth:`stop` shuts the process down and
    removes the shared memory, and returns the process's :class:`SimRigLog`.
    """

    def __init__(self, config: SimRigConfig | None = None):
        self.config = config if config is not None else SimRigConfig()
        if not isinstance(self.config, SimRigConfig):
            raise TypeError(f"config must be a SimRigConfig, got {type(config).__name__}")
        self._ring: DaqRing | None = None
        self._daq: ShmDaq | None = None
        self._process = None
        self._conn = None
        self.axis_info: dict = {}
        self.log: SimRigLog | None = None
        self.error: str | None = None

    @property
    def daq(self) -> ShmDaq:
        """The host's side of the simulated DAQ (after :meth:`start`)."""
        if self._daq is None:
            raise RuntimeError("start() the simulated rig first")
        return self._daq

    @property
    def process(self):
        """The ``multiprocessing.Process`` (None before :meth:`start`)."""
        return self._process

    @property
    def shm_name(self) -> str | None:
        """Name of the shared memory (None before :meth:`start`)."""
        return self._ring.name if self._ring is not None else None

    def start(self, timeout: float = 120.0) -> SimulatedRig:
        """Spawn the process and wait (up to ``timeout`` s) until it is ready."""
        if self._process is not None:
            raise RuntimeError("the simulated rig has already been started")
        c = self.config
        ctx = multiprocessing.get_context("spawn")
        self._ring = DaqRing.create(c.fs, c.block_size, c.n_inputs, c.buffer_blocks, c.ao_range)
        self._conn, child = ctx.Pipe(duplex=False)
        self._process = ctx.Process(target=_process_main, args=(self._ring.name, c, child),
                                    name="tactile-mirror-simulated-rig", daemon=True)
        try:
            self._process.start()
            child.close()
            deadline = time.monotonic() + timeout
            while not self._conn.poll(0.05):
                if not self._process.is_alive():
                    raise RuntimeError(f"the simulated rig's process ended before it was ready "
                                       f"(exit code {self._process.exitcode})")
                if time.monotonic() > deadline:
                    raise TimeoutError(f"the simulated rig was not ready within {timeout:g} s")
            kind, payload = self._conn.recv()
            if kind == "error":
                self.error = payload
                raise RuntimeError(f"the simulated rig failed to start:\n{payload}")
            self.axis_info = payload
        except BaseException:
            self.stop(timeout=5.0)
            raise
        self._daq = ShmDaq(self._ring, input_names(c.n_ridges))
        return self

    def status(self) -> dict:
        """The process's live counters (:meth:`DaqRing.counters`) and whether it is alive."""
        out = self._ring.counters() if self._ring is not None else {}
        out["alive"] = bool(self._process is not None and self._process.is_alive())
        return out

    def stop(self, timeout: float = 10.0) -> SimRigLog | None:
        """Shut the process down (it stops the axis and returns its log), wait for it to end
        (terminated after ``timeout`` s), remove the shared memory. Returns the log (None if
        the process gave none; if it raised, its traceback is in :attr:`error`). Calling it
        again returns the same."""
        if self._ring is None:
            return self.log
        ring, proc, conn = self._ring, self._process, self._conn
        try:
            ring.request_shutdown()
            deadline = time.monotonic() + timeout
            while proc is not None and conn is not None:
                if conn.poll(0.05):
                    try:
                        kind, payload = conn.recv()
                    except EOFError:
                        break
                    if kind == "log":
                        self.log = SimRigLog(**payload)
                        break
                    if kind == "error":
                        self.error = payload
                        break
                elif not proc.is_alive() or time.monotonic() > deadline:
                    break
            if proc is not None:
                proc.join(max(0.0, deadline - time.monotonic()))
                if proc.is_alive():
                    proc.terminate()
                    proc.join(2.0)
                if proc.is_alive():
                    proc.kill()
                    proc.join(2.0)
        finally:
            if conn is not None:
                conn.close()
            self._daq = None
            self._ring = None
            try:
                ring.close()
            finally:
                ring.unlink()
        return self.log

    def close(self) -> None:
        self.stop()

    def __enter__(self) -> SimulatedRig:
        return self.start() if self._process is None else self

    def __exit__(self, *exc) -> None:
        self.stop()


# ---------------------------------------------------------------------- the process
class _Simulation:
    """The process's state: the finger, the axis, the plant, the circuit and the noise."""

    def __init__(self, config: SimRigConfig, ring: DaqRing):
        from tactile_mirror.circuit import PVDFCircuit
        from tactile_mirror.loop.finger import pressed_finger_path

        c = self.config = config
        self.ring = ring
        R = c.n_ridges
        if c.plant == "brush":
            from tactile_mirror.contact.brush import BrushRidges

            mu = 1.0 if c.mu is None else c.mu
            self.plant = BrushRidges(R, mu=mu * (1 + 0.04 * np.linspace(-1, 1, R)))
            press = 0.0
        else:
            from tactile_mirror.contact.plants import FemPad

            make = FemPad.realtime if c.plant == "realtime" else FemPad
            self.plant = make(R, mu=c.mu, fs=c.fs)
            press = c.press
        self.finger = pressed_finger_path(c.seed, c.duration, c.fs, press, **c.trajectory)
        self.circuit = PVDFCircuit().stream(c.fs, 2 * R)
        rng = np.random.default_rng(30_000 + c.seed)
        L = max(1, round(c.noise_record * c.fs))
        if c.noise is not None:
            self.noise_v, self.noise_u = c.noise.draw(c.fs, L, 2 * R, seed=rng)
        else:
            self.noise_v = self.noise_u = np.zeros((2 * R, L))
        self.noise_f = rng.normal(0.0, c.force_noise, (2, L)) if c.force_noise else np.zeros((2, L))
        factory = c.axis_factory or analog_axis
        self.axis = factory(c, ring)
        self.cpm = float(c.counts_per_m)
        ring.set_initial_count(math.floor(self.axis.position() * self.cpm))
        self._stress0 = None
        self._pads = [0.0, 0.0]
        self._watchdog_ns = round(c.watchdog * 1e9)
        self._tripped = False
        self.stops: list[tuple[int, str]] = []
        self.trips: list[int] = []
        self.block_compute: list[int] = []
        self.missed: list[int] = []
        self.lateness: list[int] = []

    def run(self, parent) -> None:
        """Tick until the acquisition is stopped, the process is asked to shut down or the
        host's process is gone.

        Two timers: tick ``i`` is computed from ``tick_ns(i) - lead`` on, a finished block is
        published at its due time (before any tick that comes later); in between, it sleeps.
        """
        c, ring = self.config, self.ring
        n = c.block_size
        lead_ns = round(c.lead_s * 1e9)
        ring.set_state(RingState.RUNNING)
        i = 0
        slot = None
        compute = 0
        pending: list[tuple[int, int, int]] = []   # finished blocks: (index, finished ns, compute ns)
        while True:
            now = time.monotonic_ns()
            if pending:
                k, done, cost = pending[0]
                due = ring.due_ns(k)
                if due <= now:
                    ring.publish(k)
                    late = done > due
                    if late:
                        self.missed.append(k)
                        self.lateness.append(done - due)
                    ring.count_block(cost, late)
                    self.block_compute.append(cost)
                    pending.pop(0)
                    continue
            target = ring.tick_ns(i) - lead_ns
            if target > now:
                wake = min(target, due) if pending else target
                if pending and wake == due:
                    if due - now > 150_000:   # sleep, then wait out the last 0.1 ms
                        time.sleep((due - now - 100_000) / 1e9)
                    while time.monotonic_ns() < due:
                        pass
                else:
                    time.sleep((wake - now) / 1e9)
                continue
            k, j = divmod(i, n)
            if j == 0:
                if ring.stop_requested or (k % 100 == 0 and parent is not None and not parent.is_alive()):
                    break
                slot = ring.slot(k)
                compute = 0
            c0 = time.perf_counter_ns()
            self._tick(i, slot[j])
            compute += time.perf_counter_ns() - c0
            if j == n - 1:
                pending.append((k, time.monotonic_ns(), compute))
            i += 1

    def _tick(self, i: int, row: np.ndarray) -> None:
        """Tick ``i``: commands, watchdog, axis, encoder, plant, circuit, noise -> ``row``."""
        c, ring, axis = self.config, self.ring, self.axis
        R, fs = c.n_ridges, c.fs
        now = time.monotonic_ns()
        axis.poll(now)
        last = axis.last_command_ns()
        if last >= 0 and now - last > self._watchdog_ns:
            if not self._tripped:
                axis.stop()
                self._tripped = True
                self.trips.append(now)
                self.stops.append((now, "watchdog"))
                ring.count_watchdog_trip()
        else:
            self._tripped = False
        pad = axis.advance(1.0 / fs)
        ring.write_count(i, math.floor(pad * self.cpm))
        st = self.plant.advance(self.finger[min(i, self.finger.size - 1)] - pad)
        load = st.stress.reshape(-1)
        if self._stress0 is None:
            self._stress0 = load.copy()  # the static normal preload is no change of stress
        v, u = self.circuit.step_load(load - self._stress0)
        m = i % self.noise_v.shape[1]
        row[:2 * R] = v + self.noise_v[:, m]
        row[2 * R:4 * R] = u + self.noise_u[:, m]
        p0, p1 = self._pads
        acc = (pad - 2.0 * p1 + p0) * fs * fs if i >= 2 else 0.0
        self._pads = [p1, pad]
        row[4 * R] = st.force_y - c.pad_mass * acc + self.noise_f[0, m]
        row[4 * R + 1] = st.force_z + self.noise_f[1, m]

    def record(self) -> dict:
        c, ring = self.config, self.ring
        return {"fs": c.fs, "block_size": c.block_size, "t0_ns": ring.t0_ns, "blocks": ring.published,
                "block_compute_ns": np.asarray(self.block_compute, dtype=np.int64),
                "missed_blocks": np.asarray(self.missed, dtype=np.int64),
                "lateness_ns": np.asarray(self.lateness, dtype=np.int64), "stops": list(self.stops),
                "watchdog_trips_ns": np.asarray(self.trips, dtype=np.int64), "commands": self.axis.log()}


def _process_main(name: str, config: SimRigConfig, conn) -> None:
    """The simulated rig's process: build, wait for the clock, run, report."""
    parent = multiprocessing.parent_process()
    ring = DaqRing.attach(name)
    sim = None
    try:
        sim = _Simulation(config, ring)
        ring.set_state(RingState.READY)
        conn.send(("ready", sim.axis.info()))
        while not ring.t0_ns and not ring.shutdown_requested:
            if parent is not None and not parent.is_alive():
                return
            time.sleep(5e-4)
        if ring.t0_ns and not ring.stop_requested:
            sim.run(parent)
        sim.axis.stop()
        why = "shutdown" if ring.shutdown_requested else "acquisition stopped"
        sim.stops.append((time.monotonic_ns(), why))
        ring.set_state(RingState.STOPPED)
        while not ring.shutdown_requested:
            if parent is not None and not parent.is_alive():
                return
            time.sleep(2e-3)
        conn.send(("log", sim.record()))
        ring.set_state(RingState.EXITED)
    except BaseException:
        ring.set_state(RingState.FAILED)
        try:
            conn.send(("error", traceback.format_exc()))
        except Exception:  # (the host is gone: nothing to tell)
            pass
    finally:
        if sim is not None:
            sim.axis.close()
        conn.close()
        ring.close()
