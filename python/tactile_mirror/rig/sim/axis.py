"""Axes of the simulated rig: what moves the pad, fed by a command path.

:class:`SimAxis` is what the simulated rig's process needs from an axis; :class:`AnalogAxis`
is the analog path's (the host's analog-output values as a servo amplifier's command, the
encoder's counts from its position). A serial controller's axis on a pseudo-terminal plugs in
through :attr:`SimRigConfig.axis_factory <tactile_mirror.rig.sim.config.SimRigConfig>`.
"""
from __future__ import annotations

import math
from typing import Protocol, runtime_checkable

import numpy as np

from tactile_mirror.loop.stage import SimulatedStage, StageLimits
from tactile_mirror.rig.sim.config import SimRigConfig
from tactile_mirror.rig.sim.daq_shm import DaqRing

__all__ = ["AnalogAxis", "SimAxis", "analog_axis"]


@runtime_checkable
class SimAxis(Protocol):
    """An axis the simulated rig moves tick by tick, fed by its own command path.

    Every tick the process calls :meth:`poll` (take the commands that arrived by
    ``now_ns``), then, unless the watchdog stopped it, :meth:`advance`. The watchdog reads
    :meth:`last_command_ns` and calls :meth:`stop`.

    An axis may also have ``inject(kind, options) -> bool``: make the fault ``kind``
    (:data:`~tactile_mirror.rig.sim.config.FAULTS`) on its own command path (a serial
    controller going silent, answering with errors, closing its port) and return True;
    False, or no such method, leaves the fault to the process, which makes it on the DAQ
    (the analog path's encoder and output).
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

    def inject(self, kind: str, options: dict) -> bool:
        return False   # (the analog path's faults are made on the DAQ by the process)


def analog_axis(config: SimRigConfig, ring: DaqRing) -> AnalogAxis:
    """The default axis of :class:`SimRigConfig`: an :class:`AnalogAxis` with its settings."""
    return AnalogAxis(ring, config.ao_mode, config.limits, config.lag, config.volts_per_m_s,
                      config.volts_per_m, config.volts_offset, config.x0)
