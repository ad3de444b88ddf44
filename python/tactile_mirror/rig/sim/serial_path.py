"""The serial command path of the simulated rig: a simulated controller on a pseudo-terminal.

:func:`serial_axis` is an ``axis_factory`` of
:class:`~tactile_mirror.rig.sim.config.SimRigConfig`: in the simulated rig's process it starts a
:class:`~tactile_mirror.rig.sim.serial_axis.SerialAxis` (the controller: the dialect's commands
on a pty, its bytes paced at the baud rate, its own communication watchdog) and returns a
:class:`SerialPathAxis`, the :class:`~tactile_mirror.rig.sim.axis.SimAxis` the process ticks.

The pad that the contact plant sees moves with a copy of the controller's model advanced tick
by tick, fed with the moves the controller accepted, its stops and its watchdog's stops, each
at the time it arrived (so the plant sees a smooth motion, not the steps of a model moved on at
each command). The controller answers its position queries with that pad's position at the
last tick whose time has come (``SerialAxis.report_position``, updated every tick), as an
encoder on the carriage would: the ticks are computed ahead of their time, so a command acts
on the pad a little later than on the controller's own model, and the reading must show it.

``axis_options`` holds the dialect (a built-in's name, or a table for :meth:`Dialect.generic
<tactile_mirror.rig.dialects.Dialect.generic>`), ``units_per_m``, ``baud``, ``axis``,
``device`` and ``processing`` (the controller's time per command);
:func:`serial_path_options` makes them.
"""
from __future__ import annotations

import numpy as np

from tactile_mirror.loop.stage import SimulatedStage

__all__ = ["SerialPathAxis", "make_dialect", "serial_axis", "serial_path_options"]


def make_dialect(dialect, units_per_m: float, axis: str = "", device: str = ""):
    """The :class:`~tactile_mirror.rig.dialects.Dialect` a rig configuration names: a built-in
    (``"pi_gcs2"``, ``"zaber_ascii"``) or a table of strings (``generic``), with the
    controller's ``units_per_m`` and (when given) its axis and device."""
    import dataclasses

    from tactile_mirror.rig.dialects import DIALECTS, Dialect

    if isinstance(dialect, dict):
        d = Dialect.generic(dialect, units_per_m=units_per_m)
    elif dialect in DIALECTS:
        d = DIALECTS[dialect].with_units(units_per_m)
    else:
        raise ValueError(f"dialect must be one of {sorted(DIALECTS)} or a table of strings, got {dialect!r}")
    changes = {k: v for k, v in (("axis", axis), ("device", device)) if v}
    return dataclasses.replace(d, **changes) if changes else d


def serial_path_options(dialect, units_per_m: float, baud: int, axis: str = "", device: str = "",
                        processing: float = 0.5e-3) -> dict:
    """``SimRigConfig`` fields for a serial controller: ``axis_factory`` and ``axis_options``
    (``processing``: the controller's time per command, s)."""
    return {"axis_factory": serial_axis,
            "axis_options": {"dialect": dialect, "units_per_m": float(units_per_m), "baud": int(baud),
                             "axis": axis, "device": device, "processing": float(processing)}}


def serial_axis(config, ring) -> SerialPathAxis:
    """The ``axis_factory`` of the serial path (called in the simulated rig's process)."""
    from tactile_mirror.rig.sim.serial_axis import SerialAxis

    o = config.axis_options
    d = make_dialect(o["dialect"], o["units_per_m"], o.get("axis", ""), o.get("device", ""))
    controller = SerialAxis(d, config.limits, baudrate=o["baud"], watchdog=config.watchdog, x0=config.x0,
                            lag=config.lag, home_position=config.x0, latency=o.get("processing", 0.5e-3))
    return SerialPathAxis(controller, config, ring)


class SerialPathAxis:
    """The simulated rig's axis on the serial path (see the module notes)."""

    def __init__(self, controller, config, ring):
        self.controller = controller
        self.config = config
        self.ring = ring
        self._model = SimulatedStage(config.limits, lag=config.lag, x0=config.x0)
        self._seen = {"moves": 0, "stops": 0, "dog": 0}
        self._ticks = 0
        self._history: list[tuple[int, float]] = []   # (sample time ns, pad m) of the ticks ahead
        self._reading = True      # the controller reports the pad (until a fault says otherwise)
        self._closed_ns = -1      # when the line was found closed
        controller.report_position(config.x0)
        controller.start()

    def poll(self, now_ns: int) -> None:
        c = self.controller
        if c.closed and self._closed_ns < 0:
            self._closed_ns = now_ns
        if self._reading and self.ring.t0_ns:
            h = self._history
            k = 0
            while k < len(h) and h[k][0] <= now_ns:
                k += 1
            if k:
                c.report_position(h[k - 1][1])
                del h[:k - 1]
        seen = self._seen
        # (only what is new: the logs grow by hundreds of entries a second, the ticks come at 1 kHz)
        moves, stops, dog = c.targets(seen["moves"]), c.stop_times(seen["stops"]), c.watchdog_stops(seen["dog"])
        if not (moves or stops or dog):
            return
        seen["moves"] += len(moves)
        seen["stops"] += len(stops)
        seen["dog"] += len(dog)
        events = [(t, "move", x) for t, x, ok in moves if ok]
        events += [(t, "stop", 0.0) for t in stops]
        events += [(t, "stop", 0.0) for t in dog]
        for _, kind, x in sorted(events, key=lambda e: e[0]):
            if kind == "move":
                self._model.move_to(x)
            else:
                self._model.stop()

    def advance(self, dt: float) -> float:
        x = self._model.advance(dt)
        if self.ring.t0_ns:
            self._history.append((self.ring.tick_ns(self._ticks), x))
        self._ticks += 1
        return x

    def position(self) -> float:
        return self._model.position()

    def last_command_ns(self) -> int:
        # The controller keeps its own communication watchdog while it serves the line; once the
        # line is closed nothing comes any more: the time it closed arms the process's watchdog.
        return self._closed_ns

    def stop(self) -> None:
        self._model.stop()

    def info(self) -> dict:
        c = self.controller
        return {"path": "serial", "port": c.port, "dialect": c.dialect.name, "baud": c.baudrate}

    def log(self) -> dict:
        c = self.controller
        moves = c.targets()
        cmds = c.commands()
        return {"t_ns": np.array([t for t, _, _ in moves], dtype=np.int64),
                "x": np.array([x for _, x, _ in moves], dtype=np.float64),
                "accepted": np.array([ok for _, _, ok in moves], dtype=bool),
                "stop_ns": np.array(c.stop_times(), dtype=np.int64),
                "watchdog_ns": np.array(c.watchdog_stops(), dtype=np.int64),
                "command_t_ns": np.array([t for t, _ in cmds], dtype=np.int64),
                "commands": [text for _, text in cmds],
                "rejected": [list(r) for r in c.rejected()], "dropped": int(c.dropped)}

    def close(self) -> None:
        self.controller.close()

    def inject(self, kind: str, options: dict) -> bool:
        c = self.controller
        if kind == "silent":
            c.go_silent()
        elif kind == "error_reply":
            c.answer_error(options.get("code"))
        elif kind == "out_of_limit":
            self._reading = False
            c.report_position(self.config.limits.x_max + float(options.get("offset", 0.005)))
        elif kind == "closed_port":
            c.close_port()
        else:
            return False
        return True
