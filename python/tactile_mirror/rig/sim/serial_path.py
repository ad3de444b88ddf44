"""The serial command path of the simulated rig: a simulated controller on a pseudo-terminal.

:func:`serial_axis` is an ``axis_factory`` of
:class:`~tactile_mirror.rig.sim.config.SimRigConfig`: in the simulated rig's process it starts
the controller, a :class:`~tactile_mirror.rig.sim.serial_axis.SerialAxis` (the dialect's
commands on a pty, its bytes paced at the baud rate, its own communication watchdog), in a
process of its own, and returns a :class:`SerialPathAxis`, the
:class:`~tactile_mirror.rig.sim.axis.SimAxis` the simulated rig ticks. A real controller is a
device of its own: in one process with the FEM pad's ticks, its thread waited for the
interpreter for up to 56 ms now and then, longer than the driver's bound on an answer.

The controller tells the axis, through a pipe, every move it accepted, its stops and its
watchdog's stops, each with the time it arrived; the pad that the contact plant sees moves
with a copy of the controller's model advanced tick by tick and fed with those (so the plant
sees a smooth motion, not the steps of a model moved on at each command). The axis writes the
pad's position at every tick into a small ring in shared memory, and the controller answers a
position query with the pad at the last tick whose time had come when the query arrived, as an
encoder on the carriage would: the ticks are computed ahead of their time, so a command acts
on the pad a little later than on the controller's own model, and the reading must show it.
The simulated rig's faults on this path are made in the controller (silent, error reply,
closed port) or in what it reports (a position out of the soft limits).

``axis_options`` holds the dialect (a built-in's name, or a table for :meth:`Dialect.generic
<tactile_mirror.rig.dialects.Dialect.generic>`), ``units_per_m``, ``baud``, ``axis``,
``device`` and ``processing`` (the controller's time per command);
:func:`serial_path_options` makes them.
"""
from __future__ import annotations

import json
import pickle
import socket
import subprocess
import sys
import threading
import time

import numpy as np

from tactile_mirror.loop.stage import SimulatedStage

__all__ = ["SerialPathAxis", "make_dialect", "serial_axis", "serial_path_options", "serve_controller"]

_RING = 64   # ticks of the pad's position shared with the controller (64 ms at 1 kHz)


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
    return SerialPathAxis(config, ring)


class _PositionRing:
    """The pad's position at the last ticks, in memory shared through a file descriptor (a
    temporary file, mapped by both processes): the number written (int64), then ``(sample
    time ns, m)`` rows; one writer (the axis), one reader (the controller)."""

    SIZE = 8 + 16 * _RING

    def __init__(self, fd: int | None = None):
        import mmap
        import tempfile

        self.file = None
        if fd is None:
            self.file = tempfile.TemporaryFile()
            self.file.truncate(self.SIZE)
            fd = self.file.fileno()
        self.fd = fd
        self.map = mmap.mmap(fd, self.SIZE)
        self.count = np.ndarray((1,), dtype=np.int64, buffer=self.map, offset=0)
        self.rows = np.ndarray((_RING, 2), dtype=np.float64, buffer=self.map, offset=8)

    def write(self, t_ns: int, x: float) -> None:
        n = int(self.count[0])
        row = self.rows[n % _RING]
        row[1] = x
        row[0] = float(t_ns)
        self.count[0] = n + 1   # (the row is whole before it is counted)

    def at(self, t_ns: int) -> float | None:
        """The position at the last tick at or before ``t_ns`` (None: none written yet)."""
        n = int(self.count[0])
        for k in range(n - 1, max(n - _RING, 0) - 1, -1):
            t, x = self.rows[k % _RING]
            if t <= t_ns:
                return float(x)
        return None

    def close(self) -> None:
        self.count = self.rows = None   # (the views go first: the map cannot close under them)
        self.map.close()
        if self.file is not None:
            self.file.close()


def serve_controller(fd: int) -> None:
    """The simulated controller's process (started by :class:`SerialPathAxis` as a plain
    subprocess: the simulated rig's own process is a daemon and may have no children of
    ``multiprocessing``'s). ``fd`` is its end of a socket pair: it reads its settings from it
    (and the descriptor of the pad's positions, passed to it too), then serves a
    :class:`~tactile_mirror.rig.sim.serial_axis.SerialAxis` on its pty, sends what the
    controller does (moves, stops, watchdog stops, its port closing) and takes what it is told
    (faults, its log, quit). It ends when told to or when the other end closes."""
    import gc
    from multiprocessing.connection import Connection

    from tactile_mirror.rig.realtime import gc_paused, raised_priority
    from tactile_mirror.rig.sim.serial_axis import SerialAxis

    conn = Connection(fd)
    options, c, ring_fd = conn.recv()
    ring = _PositionRing(ring_fd)
    lock = threading.Lock()

    def send(message) -> None:
        with lock:
            try:
                conn.send(message)
            except (OSError, ValueError):   # (the simulated rig is gone: nobody to tell)
                pass

    d = make_dialect(options["dialect"], options["units_per_m"], options.get("axis", ""), options.get("device", ""))
    controller = None
    # a device of its own: it only ever waits, and its log grows by hundreds of lines a second,
    # whose collections by the garbage collector held it up 15 ms after 3 s
    gc.collect()
    paused, priority = gc_paused(), raised_priority(rt_priority=c["rt_priority"])
    paused.__enter__()
    priority.__enter__()
    try:
        controller = SerialAxis(d, pickle.loads(c["limits"]), baudrate=options["baud"], watchdog=c["watchdog"],
                                x0=c["x0"], lag=c["lag"], home_position=c["x0"],
                                latency=options.get("processing", 0.5e-3), on_event=send, position_source=ring.at)
        controller.start()
        send(("ready", {"port": controller.port, "dialect": d.name, "baud": controller.baudrate}))
        while True:
            try:
                message = conn.recv()
            except (EOFError, OSError):
                return
            if message[0] == "quit":
                return
            if message[0] == "log":
                send(("log", {"targets": controller.targets(), "stops": controller.stop_times(),
                              "watchdog": controller.watchdog_stops(), "commands": controller.commands(),
                              "rejected": controller.rejected(), "dropped": int(controller.dropped)}))
            elif message[0] == "inject":
                kind, opts = message[1], message[2]
                if kind == "silent":
                    controller.go_silent()
                elif kind == "error_reply":
                    controller.answer_error(opts.get("code"))
                elif kind == "out_of_limit":
                    controller.report_position(controller.limits.x_max + float(opts.get("offset", 0.005)))
                elif kind == "closed_port":
                    controller.close_port()
    except BaseException as exc:  # noqa: BLE001 (the simulated rig says what failed)
        send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        if controller is not None:
            controller.close()
        ring.close()
        conn.close()
        priority.__exit__(None, None, None)
        paused.__exit__(None, None, None)


class SerialPathAxis:
    """The simulated rig's axis on the serial path (see the module notes); its controller runs
    in a process of its own (:attr:`process`, a ``subprocess.Popen``)."""

    def __init__(self, config, ring, timeout: float = 60.0):
        from multiprocessing.connection import Connection

        self.config = config
        self.ring = ring
        self._model = SimulatedStage(config.limits, lag=config.lag, x0=config.x0)
        self._ticks = 0
        self._closed_ns = -1      # when the line was found closed
        self._positions = _PositionRing()
        self._positions.write(0, config.x0)   # (the pad where it stands, before the clock starts)
        self._log: dict | None = None
        self._info: dict = {}
        self.process = None
        ours, theirs = socket.socketpair()
        self._conn = Connection(ours.detach())
        try:
            code = ("import sys, json; sys.path[:0] = json.loads(sys.argv[1]); "
                    "from tactile_mirror.rig.sim.serial_path import serve_controller; serve_controller(int(sys.argv[2]))")
            self.process = subprocess.Popen([sys.executable, "-c", code, json.dumps(sys.path), str(theirs.fileno())],
                                            pass_fds=(theirs.fileno(), self._positions.fd), close_fds=True)
            theirs.close()
            fields = {"limits": pickle.dumps(config.limits), "watchdog": config.watchdog, "x0": config.x0,
                      "lag": config.lag, "rt_priority": config.rt_priority}
            self._conn.send((dict(config.axis_options), fields, self._positions.fd))
            deadline = time.monotonic() + timeout
            while not self._conn.poll(0.05):
                if self.process.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("the simulated controller's process did not start")
            kind, payload = self._conn.recv()
            if kind != "ready":
                raise RuntimeError(f"the simulated controller failed to start: {payload}")
            self._info = payload
        except BaseException:
            theirs.close()
            self.close()
            raise

    def poll(self, now_ns: int) -> None:
        events = self._conn
        if not events.poll():
            return
        moves = []
        while events.poll():
            try:
                message = events.recv()
            except (EOFError, OSError):
                break
            kind = message[0]
            if kind == "move":
                if message[3]:
                    moves.append((message[1], "move", message[2]))
            elif kind in ("stop", "watchdog"):
                moves.append((message[1], "stop", 0.0))
            elif kind == "closed":
                if self._closed_ns < 0:
                    self._closed_ns = message[1]
            elif kind == "log":
                self._log = message[1]
        for _, kind, x in sorted(moves, key=lambda e: e[0]):
            if kind == "move":
                self._model.move_to(x)
            else:
                self._model.stop()

    def advance(self, dt: float) -> float:
        x = self._model.advance(dt)
        if self.ring.t0_ns:
            self._positions.write(self.ring.tick_ns(self._ticks), x)
        self._ticks += 1
        return x

    def position(self) -> float:
        return self._model.position()

    def last_command_ns(self) -> int:
        # The controller keeps its own communication watchdog while it serves the line (and
        # after it closed); the time the line closed also arms the simulated rig's watchdog.
        return self._closed_ns

    def stop(self) -> None:
        self._model.stop()

    def info(self) -> dict:
        return {"path": "serial", **self._info}

    def log(self) -> dict:
        log = self._controller_log() or {"targets": [], "stops": [], "watchdog": [], "commands": [], "rejected": [],
                                         "dropped": 0}
        moves, cmds = log["targets"], log["commands"]
        return {"t_ns": np.array([t for t, _, _ in moves], dtype=np.int64),
                "x": np.array([x for _, x, _ in moves], dtype=np.float64),
                "accepted": np.array([ok for _, _, ok in moves], dtype=bool),
                "stop_ns": np.array(log["stops"], dtype=np.int64),
                "watchdog_ns": np.array(log["watchdog"], dtype=np.int64),
                "command_t_ns": np.array([t for t, _ in cmds], dtype=np.int64),
                "commands": [text for _, text in cmds],
                "rejected": [list(r) for r in log["rejected"]], "dropped": int(log["dropped"])}

    def _controller_log(self, timeout: float = 5.0) -> dict | None:
        if self._log is not None:
            return self._log
        if self.process is None or self.process.poll() is not None:
            return None
        try:
            self._conn.send(("log",))
        except (OSError, ValueError):
            return None
        deadline = time.monotonic() + timeout
        while self._log is None and time.monotonic() < deadline:
            if self._conn.poll(0.05):
                self.poll(time.monotonic_ns())
        return self._log

    def close(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self._controller_log()
            try:
                self._conn.send(("quit",))
            except (OSError, ValueError):
                pass
            try:
                self.process.wait(5.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(2.0)
        if not self._conn.closed:
            self._conn.close()
        if self._positions is not None:
            self._positions.close()
            self._positions = None

    def inject(self, kind: str, options: dict) -> bool:
        if kind not in ("silent", "error_reply", "out_of_limit", "closed_port"):
            return False
        try:
            self._conn.send(("inject", kind, dict(options)))
        except (OSError, ValueError):
            return False
        return True

