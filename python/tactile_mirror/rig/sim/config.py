"""Settings of the simulated rig (:class:`SimRigConfig`) and what its process records
(:class:`SimRigLog`)."""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tactile_mirror.checks import integer, real_number, sample_rate
from tactile_mirror.loop.stage import StageLimits
from tactile_mirror.noise import SensorNoise

__all__ = ["FAULTS", "SIM_PLANTS", "SimRigConfig", "SimRigLog"]

#: Plants of the simulated rig: ``"realtime"`` (:meth:`FemPad.realtime`), ``"fem"`` (the
#: default FEM pad, which does not keep up with 1 kHz) and ``"brush"`` (the brush model).
SIM_PLANTS = ("realtime", "fem", "brush")

#: Faults the simulated rig can be told to make (:meth:`SimulatedRig.inject`):
#:
#: - ``"silent"``: the stage's device goes silent (the analog path: the encoder counter
#:   stops counting, its reading ages; a serial controller stops answering);
#: - ``"error_reply"``: the device reports an error (the analog path: every DAQ call on the
#:   host fails with a device error; a serial controller answers with its error reply);
#: - ``"out_of_limit"``: the position read lies ``offset`` m beyond the soft limit's end;
#: - ``"closed_port"``: the device is gone (the analog path: the DAQ is removed, every call
#:   raises OSError; a serial port is closed);
#: - ``"nan_burst"``: the PVDF channels read NaN for ``ticks`` samples.
FAULTS = ("silent", "error_reply", "out_of_limit", "closed_port", "nan_burst")


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
    finger_wait
        False: the finger presses in for ``press`` s from the clock's start, then follows its
        path (``duration`` s in all). True: it rides with the pad (no shear, as a finger not
        yet placed) until the host places it (:meth:`SimulatedRig.place_finger`), rests
        there until :meth:`SimulatedRig.start_finger` (a person told to start moving), then
        follows a path of ``duration`` s from there.
    noise, noise_record
        Sensor noise (None: none), drawn once for ``noise_record`` s and played in a loop
        (2 s holds whole periods of 50 and 60 Hz hum at 1 kHz).
    circuit
        The front end's component values, keyword arguments of
        :class:`~tactile_mirror.circuit.PVDFCircuit` (None: its defaults).
    force_noise, pad_mass
        White noise of the force sensor (N rms) and the mass it carries (kg).
    ao_mode, volts_per_m_s, volts_per_m, volts_offset
        The servo amplifier's command input: ``"velocity"`` (V per m/s) or ``"position"``
        (V per m, and the volts at 0 m).
    counts_per_m
        The encoder's counts per metre (X4).
    limits, lag, x0
        The axis: travel (its end stops), speed and acceleration; servo time constant, s;
        where it stands when the process starts, m.
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
        picklable: a module-level function); None: :func:`~tactile_mirror.rig.sim.axis.analog_axis`.
    axis_options
        Settings an ``axis_factory`` reads (e.g. a serial axis's dialect and baud rate).
    rt_priority
        The process's real-time (``SCHED_RR``) priority where the system permits it, 0: none
        (:func:`~tactile_mirror.rig.realtime.raised_priority`; a raised nice value either way).
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
    finger_wait: bool = False
    noise: SensorNoise | None = field(default_factory=lambda: SensorNoise(hum=2e-3))
    noise_record: float = 2.0
    circuit: dict | None = None
    force_noise: float = 2e-3
    pad_mass: float = 0.02
    ao_mode: str = "velocity"
    volts_per_m_s: float = 200.0
    volts_per_m: float = 500.0
    volts_offset: float = 0.0
    counts_per_m: float = 1e7
    limits: StageLimits = StageLimits(-0.02, 0.02, 0.05, 2.0)
    lag: float = 0.002
    x0: float = 0.0
    ao_range: tuple[float, float] = (-10.0, 10.0)
    lead: float | None = None
    watchdog: float = 0.1
    axis_factory: Callable | None = None
    axis_options: dict = field(default_factory=dict)
    rt_priority: int = 0

    def __post_init__(self) -> None:
        sample_rate(self.fs)
        integer(self.block_size, "block_size", 1)
        integer(self.buffer_blocks, "buffer_blocks", 1)
        integer(self.n_ridges, "n_ridges", 1, 64)
        integer(self.seed, "seed", 0)
        integer(self.rt_priority, "rt_priority", 0, 99)
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
        x0 = real_number(self.x0, "x0", unit="m")
        if not self.limits.x_min <= x0 <= self.limits.x_max:
            raise ValueError(f"x0 = {x0!r} m lies outside the axis's travel [{self.limits.x_min:g}, "
                             f"{self.limits.x_max:g}] m")
        if self.noise is not None and not isinstance(self.noise, SensorNoise):
            raise TypeError(f"noise must be a SensorNoise or None, got {type(self.noise).__name__}")
        if self.circuit is not None and not isinstance(self.circuit, dict):
            raise TypeError(f"circuit must be a dict of PVDFCircuit fields or None, got {type(self.circuit).__name__}")
        if not isinstance(self.finger_wait, bool):
            raise TypeError(f"finger_wait must be True or False, got {self.finger_wait!r}")
        if self.lead is not None:
            lead = real_number(self.lead, "lead", unit="s", positive=True)
            if lead > self.block_size / self.fs:
                raise ValueError(f"lead must be at most one block ({self.block_size / self.fs:g} s), "
                                 f"got {lead!r}")
        if self.axis_factory is not None and not callable(self.axis_factory):
            raise TypeError("axis_factory must be callable (config, ring) -> SimAxis")
        if not isinstance(self.axis_options, dict):
            raise TypeError(f"axis_options must be a dict, got {type(self.axis_options).__name__}")

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
        The axis's command log (:meth:`SimAxis.log`); for the analog axis: ``t_ns`` (when
        the host wrote each value), ``volts``, ``seen_ns`` (when the axis took it), ``lost``.
    faults : list of (int, str)
        Faults made on the host's request (:meth:`SimulatedRig.inject`): when, which.
    resets : list of int
        Times the charge amplifiers were reset (:meth:`SimulatedRig.reset_amplifiers`).
    finger_start : int
        Tick the finger's path started at (0 unless ``finger_wait``; -1: it never started).
    finger, pad : ndarray
        The finger's and the pad's position at every tick computed, m.
    slip_fraction : ndarray, shape (n_ridges, ticks)
        Share of each ridge's contact at the friction limit, every tick.
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
    faults: list = field(default_factory=list)
    resets: list = field(default_factory=list)
    finger_start: int = 0
    finger: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    slip_fraction: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def missed(self) -> int:
        """Deadline misses."""
        return int(self.missed_blocks.size)

    def tick_ns(self, i) -> np.ndarray:
        """``monotonic_ns`` time of tick (sample) ``i`` (array or int)."""
        return self.t0_ns + np.round((np.asarray(i) + 1) * 1e9 / self.fs).astype(np.int64)

    def gross_slips(self, start: int | None = None, stop: int | None = None) -> int:
        """Gross-slip events of the contact over ticks ``start`` (default: the finger's start)
        to ``stop`` (:func:`~tactile_mirror.loop.scene.gross_slip_events`)."""
        from tactile_mirror.loop.scene import gross_slip_events

        if start is None:
            start = max(self.finger_start, 0)
        sf = self.slip_fraction[:, start:stop]
        return gross_slip_events(sf) if sf.size else 0

    def tracking(self, start: int | None = None, stop: int | None = None) -> dict:
        """RMS and largest ``|finger - pad - (finger - pad)[start]|`` (m) over the ticks: how far
        the stage let the relative displacement wander from where it started."""
        if start is None:
            start = max(self.finger_start, 0)
        e = self.finger[start:stop] - self.pad[start:stop]
        if e.size == 0:
            return {"rms": math.nan, "max": math.nan}
        e = e - e[0]
        return {"rms": float(np.sqrt(np.mean(e * e))), "max": float(np.max(np.abs(e)))}

    def stop_after(self, t_ns: int) -> tuple[int, str] | None:
        """When the axis was stopped after ``t_ns`` (``monotonic_ns``), and how: ``"stop
        received"`` (the first command the axis took that the host sent at ``t_ns`` or later:
        the stop; a command log with ``stop_ns`` gives the stops themselves, a serial
        controller's) or ``"watchdog"`` (a communication watchdog: the process's, or the
        controller's own, ``watchdog_ns``); None if neither happened."""
        out = []
        cmd = self.commands
        if "stop_ns" in cmd:
            s = np.asarray(cmd["stop_ns"], dtype=np.int64)
            s = s[s >= t_ns]
            if s.size:
                out.append((int(s.min()), "stop received"))
            w = np.asarray(cmd.get("watchdog_ns", ()), dtype=np.int64)
            w = w[w >= t_ns]
            if w.size:
                out.append((int(w.min()), "watchdog"))
        elif "t_ns" in cmd and "seen_ns" in cmd:
            sent = np.asarray(cmd["t_ns"], dtype=np.int64)
            k = np.flatnonzero(sent >= t_ns)
            if k.size:
                out.append((int(np.asarray(cmd["seen_ns"])[k[0]]), "stop received"))
        w = self.watchdog_trips_ns[self.watchdog_trips_ns >= t_ns]
        if w.size:
            out.append((int(w.min()), "watchdog"))
        return min(out) if out else None

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
