"""The stage on the DAQ's analog path: the path that holds 1 kHz.

A servo amplifier takes a velocity (or position) command in volts from the DAQ's analog
output; the carriage's encoder goes to one of the DAQ's counters (quadrature, X4: four
counts per line). :class:`AnalogStage` writes one output value per tick and reads the
counter once per tick, so a command costs one analog write, not a message on a serial line.
"""
from __future__ import annotations

import math
import time

from tactile_mirror.checks import real_number
from tactile_mirror.loop.stage import StageLimits
from tactile_mirror.rig.daq import StageIO

__all__ = ["ANALOG_MODES", "AnalogStage"]

#: What the amplifier's command input means: ``"velocity"`` (V per m/s) or ``"position"`` (V per m).
ANALOG_MODES = ("velocity", "position")


class AnalogStage:
    """A stage driven through a DAQ's analog output, its position from an encoder counter.

    The stage protocol of :class:`tactile_mirror.loop.Stage`, with a fault latch, the age of
    the position reading and the measured command time.

    Parameters
    ----------
    io : StageIO
        The analog output and the counter (:class:`~tactile_mirror.rig.daq.StageIO`).
    limits : StageLimits
        Soft limits of travel (m; a command that would leave them raises ValueError naming
        it and is never written), and the speed (m/s) and acceleration (m/s^2) a velocity
        command may ask for.
    counts_per_m : float
        Encoder counts per metre (X4 decoding: four per line of the scale; from the encoder's
        data sheet, never guessed; negative if the counter counts down as the stage moves to
        +y).
    mode : {"velocity", "position"}
        What the amplifier's command input means.
    volts_per_m_s : float
        Velocity mode: command volts per m/s (the amplifier's setting; the sign is the
        direction). The full speed ``limits.v_max`` must fit the output's range.
    volts_per_m : float
        Position mode: command volts per m of position.
    volts_offset : float
        Position mode: the command volts for position 0 m.
    gain : float
        Velocity mode: the position loop's gain, 1/s: each tick, :meth:`move_to` asks for
        ``gain * (target - position)``, limited to ``v_max`` and to the speed from which
        ``a_max`` stops the stage on the target.
    offset : float
        Position (m) at count 0.

    Notes
    -----
    :meth:`position` reads the counter (one read per tick, before :meth:`move_to` in the
    loop); :meth:`move_to` works from that reading. :meth:`stop` writes 0 V in velocity
    mode; in position mode 0 V is a position, so it writes the command of the last position
    read within the soft limits (the stage holds there; a reading outside them, an encoder
    glitch, is never made a target).
    """

    command_mode = "per_tick"

    def __init__(self, io: StageIO, limits: StageLimits, counts_per_m: float, mode: str = "velocity",
                 volts_per_m_s: float | None = None, volts_per_m: float | None = None,
                 volts_offset: float = 0.0, gain: float = 50.0, offset: float = 0.0):
        if not isinstance(limits, StageLimits):
            raise TypeError(f"limits must be StageLimits, got {type(limits).__name__}")
        if mode not in ANALOG_MODES:
            raise ValueError(f"mode must be one of {ANALOG_MODES}, got {mode!r}")
        self.io = io
        self._limits = limits
        self.mode = mode
        self.counts_per_m = real_number(counts_per_m, "counts_per_m", unit="counts/m")
        if self.counts_per_m == 0:
            raise ValueError("counts_per_m must not be 0")
        lo, hi = (float(v) for v in io.ao_range)
        self.ao_range = (lo, hi)
        if mode == "velocity":
            if volts_per_m_s is None or volts_per_m is not None:
                raise ValueError("mode 'velocity' takes volts_per_m_s (V per m/s) and no volts_per_m")
            self.volts_per_m_s = real_number(volts_per_m_s, "volts_per_m_s", unit="V/(m/s)")
            if self.volts_per_m_s == 0:
                raise ValueError("volts_per_m_s must not be 0")
            self.volts_per_m = None
            ends = (-limits.v_max * self.volts_per_m_s, limits.v_max * self.volts_per_m_s)
            what = f"the full speed +-{limits.v_max:g} m/s"
        else:
            if volts_per_m is None or volts_per_m_s is not None:
                raise ValueError("mode 'position' takes volts_per_m (V per m) and no volts_per_m_s")
            self.volts_per_m = real_number(volts_per_m, "volts_per_m", unit="V/m")
            if self.volts_per_m == 0:
                raise ValueError("volts_per_m must not be 0")
            self.volts_per_m_s = None
            ends = (limits.x_min * self.volts_per_m, limits.x_max * self.volts_per_m)
            what = f"the travel [{limits.x_min:g}, {limits.x_max:g}] m"
        self.volts_offset = real_number(volts_offset, "volts_offset", unit="V")
        if mode == "position":
            ends = tuple(e + self.volts_offset for e in ends)
        if not all(lo <= e <= hi for e in ends):
            raise ValueError(f"{what} needs commands of {min(ends):g} to {max(ends):g} V, outside the analog "
                             f"output's range [{lo:g}, {hi:g}] V")
        self.gain = real_number(gain, "gain", unit="1/s", positive=True)
        self.offset = real_number(offset, "offset", unit="m")
        self._x = math.nan           # last position read, m
        self._t_ns = -1              # its time
        self._x_prev = math.nan
        self._t_prev = -1
        self._x_hold = math.nan      # last position read within the soft limits
        self._target = math.nan
        self._volts = math.nan       # last value written
        self._fault: str | None = None
        self._closed = False
        self._write_ns_sum = 0
        self._writes = 0
        self._read_ns = -1
        self.n_rejected = 0

    # ------------------------------------------------------------------ the stage protocol
    @property
    def limits(self) -> StageLimits:
        return self._limits

    def position(self) -> float:
        """Read the counter: the position now, m (NaN before the first reading; after a
        failed read, the last one, and the fault is latched)."""
        if self._fault is None:
            try:
                t = time.perf_counter_ns()
                count, t_ns = self.io.read_counter()
                self._read_ns = time.perf_counter_ns() - t
            except Exception as exc:  # (any driver error: latched, the loop sees fault())
                self._fault = f"encoder counter read failed: {type(exc).__name__}: {exc}"
            else:
                self._x_prev, self._t_prev = self._x, self._t_ns
                self._x = self.offset + int(count) / self.counts_per_m
                self._t_ns = int(t_ns)
                if self._limits.x_min <= self._x <= self._limits.x_max:
                    self._x_hold = self._x
        return self._x

    def position_age(self) -> float:
        """Age of the last counter reading, s (inf before the first)."""
        if self._t_ns < 0:
            return math.inf
        return max(0.0, (time.monotonic_ns() - self._t_ns) / 1e9)

    def velocity(self) -> float:
        """From the last two counter readings, m/s (0 before two)."""
        if self._t_prev < 0 or self._t_ns <= self._t_prev:
            return 0.0
        return (self._x - self._x_prev) / ((self._t_ns - self._t_prev) / 1e9)

    def move_to(self, x: float) -> None:
        """Command the target ``x`` (m) for this tick. ValueError, and nothing written, if
        ``x`` lies outside the soft limits. After a fault, nothing is written (only
        :meth:`stop`)."""
        x = real_number(x, "x", unit="m")
        lim = self._limits
        if not lim.x_min <= x <= lim.x_max:
            self.n_rejected += 1
            raise ValueError(f"target x = {x!r} m lies outside the soft limits "
                             f"[{lim.x_min:g}, {lim.x_max:g}] m: not written")
        if self._fault is not None or self._closed:
            return
        self._target = x
        if self.mode == "position":
            self._write(self.volts_offset + x * self.volts_per_m)
            return
        if self._t_ns < 0:
            self.position()
            if self._fault is not None:
                return
        e = x - self._x
        v_lim = min(lim.v_max, math.sqrt(2.0 * lim.a_max * abs(e)))
        v = max(-v_lim, min(v_lim, self.gain * e))
        self._write(v * self.volts_per_m_s)

    def set_velocity(self, v: float) -> None:
        """Velocity mode: command the speed ``v`` (m/s) now. ValueError, and nothing written,
        if ``|v| > v_max`` or if braking at ``a_max`` from the last position read would stop
        beyond the soft limits."""
        if self.mode != "velocity":
            raise ValueError("set_velocity needs mode 'velocity' (this stage takes positions)")
        v = real_number(v, "v", unit="m/s")
        lim = self._limits
        if abs(v) > lim.v_max:
            self.n_rejected += 1
            raise ValueError(f"v = {v!r} m/s exceeds the speed limit {lim.v_max:g} m/s: not written")
        if self._fault is not None or self._closed:
            return
        if self._t_ns < 0:
            self.position()
            if self._fault is not None:
                return
        stop_at = self._x + v * abs(v) / (2.0 * lim.a_max)
        if not lim.x_min <= stop_at <= lim.x_max:
            self.n_rejected += 1
            raise ValueError(f"v = {v!r} m/s from {self._x:.6g} m would stop at {stop_at:.6g} m, outside "
                             f"the soft limits [{lim.x_min:g}, {lim.x_max:g}] m: not written")
        self._target = math.nan
        self._write(v * self.volts_per_m_s)

    def stop(self) -> None:
        """Stop now: 0 V in velocity mode; in position mode the command of the last position
        read within the soft limits (nothing if there is none). Written after a fault too."""
        if self.mode == "velocity":
            self._write(0.0, stopping=True)
        elif math.isfinite(self._x_hold):
            self._write(self.volts_offset + self._x_hold * self.volts_per_m, stopping=True)
        self._target = math.nan

    def close(self) -> None:
        """Stop, then accept no more commands (the DAQ itself belongs to its owner)."""
        try:
            self.stop()
        finally:
            self._closed = True

    def fault(self) -> str | None:
        """The latched fault (a failed output write or counter read), in words; None if none."""
        return self._fault

    def status(self) -> dict:
        return {"position": self._x, "velocity": self.velocity(), "target": self._target,
                "volts": self._volts, "fault": self._fault, "position_age": self.position_age(),
                "mode": self.mode, "writes": self._writes, "rejected": self.n_rejected}

    @property
    def command_interval(self) -> float:
        """Mean time one output write takes, s (0 before the first): the shortest interval
        between two commands."""
        return self._write_ns_sum / self._writes / 1e9 if self._writes else 0.0

    def round_trip(self) -> float:
        """Time the last counter read took, s (NaN before the first)."""
        return self._read_ns / 1e9 if self._read_ns >= 0 else math.nan

    # ------------------------------------------------------------------ output
    def _write(self, volts: float, stopping: bool = False) -> None:
        lo, hi = self.ao_range
        volts = min(max(volts, lo), hi) if stopping else volts
        if not lo <= volts <= hi:  # (the checks above keep commands inside; a last guard)
            raise ValueError(f"command {volts!r} V lies outside the analog output's range "
                             f"[{lo:g}, {hi:g}] V: not written")
        t = time.perf_counter_ns()
        try:
            self.io.write_ao(volts)
        except Exception as exc:
            if self._fault is None:
                self._fault = f"analog output write failed: {type(exc).__name__}: {exc}"
            raise
        self._write_ns_sum += time.perf_counter_ns() - t
        self._writes += 1
        self._volts = volts

    def __repr__(self) -> str:
        scale = (f"volts_per_m_s={self.volts_per_m_s}" if self.mode == "velocity"
                 else f"volts_per_m={self.volts_per_m}")
        return (f"AnalogStage(mode={self.mode!r}, {scale}, counts_per_m={self.counts_per_m}, "
                f"limits={self._limits})")
