"""A simulated stage controller on a pseudo-terminal: the other end of a serial stage driver.

:class:`SerialAxis` opens a pseudo-terminal (POSIX ``os.openpty``), gives its slave's name as
:attr:`SerialAxis.port` (what the driver opens) and, in its own thread, reads the commands of
a :class:`~tactile_mirror.rig.dialects.Dialect` on the master side and answers them as the
controller would. A pty moves bytes instantly whatever the baud rate, so the simulator paces
the line itself: 10 bits per byte (8N1) at ``baudrate``, each direction on its own (full
duplex); a command counts as received when its last byte would have arrived, commands are
handled one at a time in the order they came (``latency`` each), answers go out in that
order, and an answer is written (whole) when its last byte would have gone out (86.8 us per
byte at 115200 Bd).

The axis is a :class:`tactile_mirror.loop.SimulatedStage` (speed and acceleration limits,
servo lag) advanced on the wall clock; a target outside the controller's own travel is refused
with the dialect's error (``bad_target_code``: answered at once, or latched for the error query
of a dialect such as PI GCS); a communication watchdog stops the axis when no byte has come for
``watchdog`` seconds (also once the port has closed: it counts from the last byte received).
Faults are injected for tests (:meth:`SerialAxis.go_silent`,
:meth:`~SerialAxis.answer_error`, :meth:`~SerialAxis.send_malformed`,
:meth:`~SerialAxis.truncate_next`, :meth:`~SerialAxis.close_port`,
:meth:`~SerialAxis.report_position`, :meth:`~SerialAxis.set_flag`,
:meth:`~SerialAxis.send_unsolicited`). Every command received is logged with the
``time.monotonic_ns()`` of its arrival, with the stops and the watchdog's stops.

Runs in a thread here; the simulated rig runs it in a process of its own
(:func:`~tactile_mirror.rig.sim.serial_path.serve_controller`).
"""
from __future__ import annotations

import collections
import math
import os
import select
import threading
import time

from tactile_mirror.checks import integer, real_number
from tactile_mirror.loop.stage import SimulatedStage, StageLimits
from tactile_mirror.rig.dialects import Dialect

__all__ = ["SerialAxis"]

_KINDS = ("move", "query_position", "stop", "query_error", "enable", "home", "query_ready", "set_velocity")
_MAX_LINE = 1024  # bytes of a command line the controller buffers


class SerialAxis:
    """A simulated controller speaking ``dialect`` on a pseudo-terminal (POSIX only).

    Parameters
    ----------
    dialect : Dialect
        With ``units_per_m`` and the controller-side answers (``position_answer``,
        ``error_answer``, ``ack_answer`` if it has ``ack_reply``, ``ready_answer`` if it has
        ``query_ready``) and the codes ``bad_target_code`` / ``bad_command_code``.
    limits : StageLimits, optional
        The controller's own travel and its speed/acceleration (default: +-50 mm, 50 mm/s,
        2 m/s^2).
    baudrate : int
        The line's baud rate the bytes are paced at (10 bits per byte).
    watchdog : float, optional
        Stop the axis when no byte has come for this long, s (None: no watchdog); armed by the
        first byte received, once per silence.
    x0 : float
        Start position, m.
    lag : float
        The servo's time constant, s (:class:`~tactile_mirror.loop.SimulatedStage`).
    home_position : float
        Where ``home`` takes the axis, m.
    on_event : callable, optional
        Called from the serving thread with ``("move", t_ns, x, accepted)``, ``("stop", t_ns)``,
        ``("watchdog", t_ns)`` and ``("closed", t_ns)`` as they happen (the simulated rig's
        axis, in another process, learns the controller's moves so).
    position_source : callable, optional
        ``position_source(t_ns) -> float or None``: the position the controller reports to a
        query that arrived at ``t_ns`` (the pad's encoder; None: its own model's), unless
        :meth:`report_position` forces one.
    latency : float
        The controller's processing time per command, s: it handles one command at a time,
        each once its last byte is in and the one before is done; the answer's first byte goes
        out then (or once the answers before it are out). The two directions of the line are
        paced independently (full duplex): commands keep coming in while answers go out.
    """

    def __init__(self, dialect: Dialect, limits: StageLimits | None = None, *, baudrate: int = 115200,
                 watchdog: float | None = None, x0: float = 0.0, lag: float = 0.0, home_position: float = 0.0,
                 latency: float = 0.0, on_event=None, position_source=None):
        if os.name != "posix":
            raise OSError("SerialAxis needs a pseudo-terminal (os.openpty, POSIX)")
        if not isinstance(dialect, Dialect):
            raise TypeError(f"dialect must be a Dialect, got {type(dialect).__name__}")
        if dialect.units_per_m is None:
            raise ValueError(f"the {dialect.name} dialect has no units_per_m (Dialect.with_units)")
        needed = ["position_answer", "error_answer", "bad_target_code", "bad_command_code"]
        needed += ["ack_answer"] if dialect.ack_reply else []
        needed += ["ready_answer"] if dialect.query_ready else []
        for name in needed:
            if not getattr(dialect, name):
                raise ValueError(f"the {dialect.name} dialect has no {name}: the simulator cannot answer for it")
        self.dialect = dialect
        self._units = float(dialect.units_per_m)
        self.limits = limits if limits is not None else StageLimits(-0.05, 0.05, 0.05, 2.0)
        self.baudrate = integer(baudrate, "baudrate", 1)
        self.byte_time = 10.0 / self.baudrate
        self.watchdog = None if watchdog is None else real_number(watchdog, "watchdog", unit="s", positive=True)
        self.latency = real_number(latency, "latency", unit="s", nonnegative=True)
        self._on_event = on_event
        self._source = position_source
        self.home_position = real_number(home_position, "home_position", unit="m")
        self._stage = SimulatedStage(self.limits, lag=lag, x0=x0)
        self._patterns = [(k, p) for k in _KINDS if (p := dialect.command_pattern(k)) is not None]
        self._inline_errors = not dialect.query_error
        self._sep = dialect.line_end.encode(dialect.encoding)[-1]
        self._strip = dialect.line_end + "\r\n"

        self._master, self._slave = os.openpty()
        import tty
        tty.setraw(self._slave)  # raw until the driver's own settings (no echo, no line editing)
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)

        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._quit = False
        self._close_request = False
        self.closed = False
        self._t_model: float | None = None
        # injected faults
        self._silent = False
        self._error_next: str | None = None
        self._malformed: bytes | None = None
        self._truncate = False
        self._reported: float | None = None
        self._flag = "--"
        self._unsolicited = b""
        self._latched = dialect.no_error
        # what happened
        self._log: list[tuple[int, str]] = []
        self._targets: list[tuple[int, float, bool]] = []
        self._stops: list[int] = []
        self._watchdog_stops: list[int] = []
        self._rejected: list[tuple[int, str, str]] = []
        self.enabled = False
        self.velocity_setting: float | None = None
        self.dropped = 0

    # -- running -------------------------------------------------------------------------

    def start(self) -> SerialAxis:
        """Start serving the line in a thread (returns self)."""
        if self._thread is not None:
            raise RuntimeError("this SerialAxis is already started")
        self._thread = threading.Thread(target=self._serve, name=f"SerialAxis {self.port}", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop serving and close the pseudo-terminal."""
        with self._lock:
            self._quit = True
        self._poke()
        if self._thread is not None:
            self._thread.join(5.0)
        self._close_fds()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        self._wake_r = self._wake_w = -1

    def __enter__(self):
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- injected faults -----------------------------------------------------------------

    def go_silent(self, silent: bool = True) -> None:
        """Answer nothing (commands are still read, logged and acted on)."""
        with self._lock:
            self._silent = bool(silent)

    def answer_error(self, code: str | None = None) -> None:
        """Report error ``code`` (default: ``bad_target_code``): a dialect with inline errors
        answers the next command with it, one whose errors latch reports it at the next error query."""
        code = self.dialect.bad_target_code if code is None else str(code)
        with self._lock:
            if self._inline_errors:
                self._error_next = code
            else:
                self._latched = code

    def send_malformed(self, data: bytes | None = None) -> None:
        """Replace the next answer by ``data`` (default: ``b'garbage'`` and the terminator)."""
        if data is None:
            data = b"garbage" + self.dialect.reply_terminator.encode(self.dialect.encoding)
        with self._lock:
            self._malformed = bytes(data)

    def truncate_next(self) -> None:
        """Send only the first half of the next answer (no terminator), then nothing more for it."""
        with self._lock:
            self._truncate = True

    def close_port(self) -> None:
        """Close the pseudo-terminal now (the driver sees the port closed)."""
        with self._lock:
            self._close_request = True
        self._poke()
        if self._thread is None:
            self._close_fds()

    def report_position(self, x: float | None) -> None:
        """Report ``x`` (m) as the position from now on, whatever the axis does (None: the axis')."""
        with self._lock:
            self._reported = None if x is None else float(x)

    def set_flag(self, flag: str = "--") -> None:
        """The warning flag in the answers (``{flag}``; ``--``: none), e.g. ``FS`` (a fault)."""
        with self._lock:
            self._flag = str(flag)

    def send_unsolicited(self, data: bytes) -> None:
        """Write ``data`` now, unasked (paced like any answer)."""
        with self._lock:
            self._unsolicited += bytes(data)
        self._poke()

    # -- what happened -------------------------------------------------------------------

    def commands(self) -> list[tuple[int, str]]:
        """``(monotonic_ns of its arrival, text)`` of every command line received."""
        with self._lock:
            return list(self._log)

    def targets(self, start: int = 0) -> list[tuple[int, float, bool]]:
        """``(monotonic_ns, target m, accepted)`` of every move received (from the ``start``-th on)."""
        with self._lock:
            return self._targets[start:]

    def stop_times(self, start: int = 0) -> list[int]:
        """monotonic_ns of every stop command received (from the ``start``-th on)."""
        with self._lock:
            return self._stops[start:]

    def watchdog_stops(self, start: int = 0) -> list[int]:
        """monotonic_ns of every stop by the communication watchdog (from the ``start``-th on)."""
        with self._lock:
            return self._watchdog_stops[start:]

    def rejected(self) -> list[tuple[int, str, str]]:
        """``(monotonic_ns, command, code)`` of every command refused with an error."""
        with self._lock:
            return list(self._rejected)

    def position(self) -> float:
        """The axis' position, m (as of its last update)."""
        return self._stage.position()

    def wire_time(self, n_bytes: int) -> float:
        """Seconds ``n_bytes`` take on the line (10 bits each)."""
        return n_bytes * self.byte_time

    # -- the controller ------------------------------------------------------------------

    def _serve(self) -> None:
        clock = time.monotonic
        bt = self.byte_time
        rx_free = tx_free = busy = 0.0
        lines: collections.deque = collections.deque()  # (arrival s, command bytes)
        # answers, each written whole when its last byte would have gone out (the host reads
        # whole lines: a byte at a time would only wake both sides 11520 times a second)
        tx: collections.deque = collections.deque()     # (due s, bytes)
        partial = bytearray()
        last_rx: float | None = None  # the watchdog arms at the first byte received
        dog_fired = False
        master = self._master
        while True:
            with self._lock:
                quit_, close, extra = self._quit, self._close_request, self._unsolicited
                self._unsolicited = b""
            if quit_:
                return
            if close:
                self._close_fds()
                # the line is gone, the controller is not: its watchdog still counts from the last byte
                if self.watchdog is not None and last_rx is not None and not dog_fired:
                    self._watch_after_close(last_rx + self.watchdog)
                return
            now = clock()
            answers = []
            while lines and lines[0][0] <= now:
                arrival, line = lines.popleft()
                # one command at a time: each is handled once it is in and the one before is done
                busy = max(busy, arrival) + self.latency
                answers.append((busy, self._handle(line, arrival)))
            if extra:
                answers.append((now, extra))
            for ready, data in answers:
                if data:
                    tx_free = max(tx_free, ready) + len(data) * bt
                    tx.append((tx_free, data))
            out = bytearray()
            while tx and tx[0][0] <= now:
                out += tx.popleft()[1]
            if out:
                try:
                    n = os.write(master, out)
                except BlockingIOError:
                    n = 0
                except OSError:
                    return
                self.dropped += len(out) - n
            dog_due = None if self.watchdog is None or last_rx is None or dog_fired else last_rx + self.watchdog
            if dog_due is not None and now >= dog_due:
                self._advance(now)
                self._stage.stop()
                dog_fired = True
                self._record_watchdog()
            wake = now + 0.05
            if lines:
                wake = min(wake, lines[0][0])
            if tx:
                wake = min(wake, tx[0][0])
            if dog_due is not None and not dog_fired:
                wake = min(wake, dog_due)
            try:
                ready, _, _ = select.select([master, self._wake_r], [], [], max(wake - clock(), 0.0))
            except (OSError, ValueError):
                return
            if self._wake_r in ready:
                try:
                    os.read(self._wake_r, 4096)
                except OSError:
                    pass
            if master in ready:
                try:
                    data = os.read(master, 4096)
                except BlockingIOError:
                    data = b""
                except OSError:  # (EIO: nobody holds the slave; this object does while it lives)
                    data = b""
                if data:
                    t = clock()
                    arrival = max(rx_free, t)
                    for b in data:
                        arrival += bt
                        partial.append(b)
                        if b == self._sep or len(partial) >= _MAX_LINE:
                            lines.append((arrival, bytes(partial)))
                            partial.clear()
                    rx_free = arrival
                    last_rx, dog_fired = arrival, False   # (the last byte's arrival on the line)

    def _watch_after_close(self, due: float) -> None:
        """The port has closed: stop the axis at ``due`` (the watchdog's time) unless told to quit."""
        while True:
            with self._lock:
                if self._quit:
                    return
            now = time.monotonic()
            if now >= due:
                self._advance(now)
                self._stage.stop()
                self._record_watchdog()
                return
            time.sleep(min(due - now, 0.01))

    def _record_watchdog(self) -> None:
        t = time.monotonic_ns()
        with self._lock:
            self._watchdog_stops.append(t)
        self._event(("watchdog", t))

    def _event(self, event: tuple) -> None:
        if self._on_event is not None:
            self._on_event(event)

    def _handle(self, line: bytes, arrival: float) -> bytes:
        """Act on one command line; the answer's bytes (b"" for none)."""
        d = self.dialect
        t_ns = round(arrival * 1e9)
        text = line.decode(d.encoding, errors="replace").rstrip(self._strip)
        with self._lock:
            self._log.append((t_ns, text))
        self._advance(time.monotonic())
        kind, match = None, {}
        for k, pattern in self._patterns:
            m = pattern.fullmatch(text)
            if m:
                kind, match = k, m.groupdict()
                break
        st = self._stage
        status = st.status()
        moving = status["set_point"] != status["target"] or status["velocity"] != 0.0
        with self._lock:
            fields = {"state": "BUSY" if moving else "IDLE", "flag": self._flag}
            forced = self._error_next
            self._error_next = None
        ack = d.answer("ack", **fields) if d.ack_reply else b""

        def refuse(code: str) -> bytes:
            with self._lock:
                self._rejected.append((t_ns, text, code))
                if self._inline_errors:
                    return d.answer("error", code=code, **fields)
                self._latched = code
            return b""

        if kind == "move":
            x = float(match["pos"]) / self._units
            ok = forced is None and self.limits.x_min <= x <= self.limits.x_max
            with self._lock:
                self._targets.append((t_ns, x, ok))
            self._event(("move", t_ns, x, ok))
            if forced is not None:
                answer = refuse(forced)
            elif not ok:
                answer = refuse(d.bad_target_code)
            else:
                st.move_to(x)
                answer = ack
        elif forced is not None:
            answer = refuse(forced)
        elif kind is None:
            answer = refuse(d.bad_command_code)
        elif kind == "query_position":
            with self._lock:
                x = self._reported
            if x is None and self._source is not None:
                x = self._source(t_ns)
            if x is None:
                x = st.position()
            answer = d.answer("position", pos=d.format_units(x * self._units), **fields)
        elif kind == "stop":
            st.stop()
            with self._lock:
                self._stops.append(t_ns)
            self._event(("stop", t_ns))
            answer = ack
        elif kind == "query_error":
            with self._lock:
                code, self._latched = self._latched, d.no_error
            answer = d.answer("error", code=code, **fields)
        elif kind == "enable":
            self.enabled = True
            answer = ack
        elif kind == "home":
            if self.limits.x_min <= self.home_position <= self.limits.x_max:
                st.move_to(self.home_position)
                answer = ack
            else:
                answer = refuse(d.bad_target_code)
        elif kind == "query_ready":
            on_target = not moving and abs(status["position"] - status["target"]) < 1e-9
            answer = d.answer("ready", ready="1" if on_target else "0", **fields)
        else:  # set_velocity
            v = float(match["vel"]) / self._units
            if 0 < v <= self.limits.v_max:
                self.velocity_setting = v  # (recorded; the model keeps the limits' v_max)
                answer = ack
            else:
                answer = refuse(d.bad_target_code)
        with self._lock:
            if self._silent:
                return b""
            if answer and self._malformed is not None:
                answer, self._malformed = self._malformed, None
            elif answer and self._truncate:
                answer, self._truncate = answer[:max(1, len(answer) // 2)], False
        return answer

    def _advance(self, now: float) -> None:
        """Move the axis model on to ``now`` (steps of at most 1 ms, at most 1000 of them)."""
        if self._t_model is None:
            self._t_model = now
            return
        dt = now - self._t_model
        if dt <= 0:
            return
        n = min(max(1, math.ceil(dt / 1e-3)), 1000)
        for _ in range(n):
            self._stage.advance(dt / n)
        self._t_model = now

    def _poke(self) -> None:
        try:
            os.write(self._wake_w, b"!")
        except (OSError, ValueError):
            pass

    def _close_fds(self) -> None:
        with self._lock:
            if self.closed:
                return
            self.closed = True
            for fd in (self._master, self._slave):
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._event(("closed", time.monotonic_ns()))

    def __repr__(self) -> str:
        return f"SerialAxis({self.dialect.name}, port={self.port!r}, {self.baudrate} Bd)"
