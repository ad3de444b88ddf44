"""A stage driver over a serial line (RS-232/USB serial, or a TCP bridge with ``socket://``).

:class:`SerialStage` speaks a :class:`~tactile_mirror.rig.dialects.Dialect` to one axis of a
controller. One I/O thread owns the port and does, strictly one exchange at a time (a command,
then its reply):

- the latest target of the one-slot mailbox filled by :meth:`SerialStage.move_to` (targets
  given faster than the line carries them are coalesced; the latest wins), at most once per
  ``command_interval``, confirmed by the controller's answer (or, for a dialect whose set
  commands are not answered, by its error query);
- a position query at ``poll_interval`` (0: whenever the line is free; a move is always
  followed by a query, so the position stays fresh while targets stream);
- the error query every ``error_interval`` for a dialect that latches its errors (PI GCS).

Every reply is parsed strictly; anything unexpected (an error reply, a malformed, truncated or
over-long reply, bytes nobody asked for, no reply within ``timeout``, a closed port, a
position outside the soft limits) latches a fault in words with the bytes shown, after which
the driver sends the stop command and nothing else, and its I/O thread ends. It never
reconnects. :meth:`SerialStage.move_to` never blocks: it checks the target against the soft
limits and swaps it into the mailbox under a lock that no I/O is ever done under.

Not run against a real controller: the tests drive it through a pseudo-terminal against
:class:`tactile_mirror.rig.sim.SerialAxis`, which paces the bytes at the line's baud rate.
pyserial (the ``rig`` extra) is imported when a driver is made.
"""
from __future__ import annotations

import collections
import contextlib
import math
import statistics
import threading
import time

from tactile_mirror.checks import integer, real_number
from tactile_mirror.loop.stage import StageLimits
from tactile_mirror.rig.dialects import ControllerError, Dialect, ReplyError
from tactile_mirror.rig.stage import check_reading, check_target

__all__ = ["SerialStage"]

_WINDOW = 16  # exchanges whose durations give the round trip and the command interval


class _Fault(Exception):
    """Internal: a fault of the line or the controller, in words (latched by the I/O thread)."""


def _show(data) -> str:
    data = bytes(data)
    return repr(data) if len(data) <= 120 else f"{data[:120]!r}... ({len(data)} bytes)"


class SerialStage:
    """One axis of a stage controller on a serial line (a :class:`~tactile_mirror.rig.StageDriver`).

    Parameters
    ----------
    port : str
        A serial device (``/dev/ttyUSB0``, ``COM3``) or a pyserial URL (``socket://host:port``);
        opened here with ``serial.serial_for_url``.
    dialect : Dialect
        The controller's command dialect, with its ``units_per_m`` (from the rig configuration).
    limits : StageLimits
        The soft limits (m): a target outside is refused, a reading outside (by more than
        ``position_margin``) is a fault.
    baudrate : int
        The line's baud rate (8N1).
    timeout : float
        The longest wait for a reply (and for a write), s: beyond it, a fault.
    poll_interval : float
        Shortest interval between two position queries, s (0: as often as the line allows).
    error_interval : float
        Interval of the error query of a dialect whose errors latch (``query_error`` without
        ``ack_reply``), s; moves are confirmed by it at once regardless.
    position_margin : float
        How far beyond the soft limits a reading may lie (the servo's following error), m.
    max_reply : int
        The longest reply accepted, bytes: a longer one is a fault (the buffer never grows).

    Use: make it, bring the axis up (:meth:`enable`, :meth:`home`, blocking), :meth:`start`
    the I/O thread, then :meth:`move_to` / :meth:`position` from the loop; :meth:`close` at
    the end (also as a context manager).
    """

    command_mode = "per_block"  # a serial line carries a command per block, not per 1 kHz tick

    def __init__(self, port: str, dialect: Dialect, limits: StageLimits, *, baudrate: int = 115200,
                 timeout: float = 0.1, poll_interval: float = 0.0, error_interval: float = 0.1,
                 position_margin: float = 1e-4, max_reply: int = 256):
        if not isinstance(dialect, Dialect):
            raise TypeError(f"dialect must be a Dialect, got {type(dialect).__name__}")
        if dialect.units_per_m is None:
            raise ValueError(f"the {dialect.name} dialect has no units_per_m: give the controller's units per metre "
                             "from the rig configuration (Dialect.with_units); it is never guessed")
        if not isinstance(limits, StageLimits):
            raise TypeError(f"limits must be StageLimits, got {type(limits).__name__}")
        self._dialect = dialect
        self._limits = limits
        self._baudrate = integer(baudrate, "baudrate", 1)
        self._timeout = real_number(timeout, "timeout", unit="s", positive=True)
        self._poll_interval = real_number(poll_interval, "poll_interval", unit="s", nonnegative=True)
        self._error_interval = real_number(error_interval, "error_interval", unit="s", positive=True)
        self._margin = real_number(position_margin, "position_margin", unit="m", nonnegative=True)
        self._max_reply = integer(max_reply, "max_reply", 8)
        self._term = dialect.reply_terminator.encode(dialect.encoding)
        self._query = dialect.command("query_position")
        self._query_label = self._label(self._query)
        self._confirm_by_error_query = bool(dialect.query_error) and not dialect.ack_reply

        import serial  # (the optional 'rig' extra)
        self._serial = serial
        self._port_name = str(port)
        self._port = serial.serial_for_url(port, baudrate=self._baudrate, timeout=self._timeout,
                                           write_timeout=self._timeout)
        self._rx = bytearray()
        self._dead = False            # the port failed: nothing more can be written

        self._lock = threading.Lock()  # guards the mailbox only (never held across I/O)
        self._slot: float | None = None
        self._wake = threading.Event()
        self._stop_request = threading.Event()
        self._thread: threading.Thread | None = None
        self._state = "open"          # open -> running -> stopped -> closed
        self._fault: str | None = None

        self._reading = (math.nan, -math.inf, 0.0)  # (position m, monotonic s of the query, velocity m/s)
        self._target = math.nan
        self._polls: collections.deque = collections.deque(maxlen=_WINDOW)
        self._moves: collections.deque = collections.deque(maxlen=_WINDOW)
        self._round_trip = math.nan
        self._interval = math.nan
        self._min_spacing = math.inf
        self._counts = {"moves": 0, "coalesced": 0, "polls": 0, "error_queries": 0, "stops_sent": 0}
        self._cleared_error: str | None = None

    # -- the StageDriver protocol --------------------------------------------------------

    @property
    def limits(self) -> StageLimits:
        return self._limits

    @property
    def dialect(self) -> Dialect:
        return self._dialect

    @property
    def command_interval(self) -> float:
        """The measured interval between two moves the line sustains, s: the median move
        exchange (the command and its confirmation) over the last moves, plus the median
        position query when queries come at least as often (``poll_interval`` shorter than
        that: a query follows every move, so the position stays fresh while targets stream);
        before the first move, twice the query's round trip; NaN before :meth:`start`. Moves
        are never sent closer than this."""
        return self._interval

    def move_to(self, x: float) -> None:
        """Set the target (m): checked against the soft limits (ValueError outside, nothing
        sent), put into the mailbox for the I/O thread; returns at once. RuntimeError if the
        driver is not running (not started, stopped, or faulted: the fault is named)."""
        x = check_target(x, self._limits)
        if self._state != "running" or self._fault is not None:
            raise RuntimeError(self._why_not_running("target not sent"))
        with self._lock:
            if self._slot is not None:
                self._counts["coalesced"] += 1
            self._slot = x
        self._wake.set()

    def position(self) -> float:
        """The last position reading, m (NaN before the first)."""
        return self._reading[0]

    def position_age(self) -> float:
        """Seconds since the query that gave the last reading was sent (inf before the first)."""
        return time.monotonic() - self._reading[1]

    def velocity(self) -> float:
        """The velocity from the last two readings, m/s."""
        return self._reading[2]

    def fault(self) -> str | None:
        return self._fault

    def round_trip(self) -> float:
        """The median round trip of the last position queries, s (NaN before the first)."""
        return self._round_trip

    def stop(self) -> None:
        """Stop the axis: the dialect's stop command goes out ahead of any queued target, then
        the I/O thread ends (waits for it up to ``2 * timeout + 1`` s). Without a running
        thread the stop is sent from here. Never raises for a dead line (the fault says it)."""
        thread = self._thread
        if self._state in ("open", "running"):
            self._state = "stopped"
        if thread is not None and thread.is_alive():
            self._stop_request.set()
            self._wake.set()
            if threading.current_thread() is not thread:
                thread.join(2 * self._timeout + 1.0)
        elif self._port.is_open:
            self._send_stop()

    def close(self) -> None:
        """Stop the axis and close the port (again: nothing)."""
        if self._state == "closed":
            return
        self.stop()
        self._state = "closed"
        with contextlib.suppress(Exception):  # (a port that fails to close is closed for us)
            self._port.close()

    def status(self) -> dict:
        x, _, v = self._reading
        return {"position": x, "velocity": v, "target": self._target, "fault": self._fault,
                "position_age": self.position_age(), "command_interval": self._interval,
                "round_trip": self._round_trip, "min_move_spacing": self._min_spacing, **self._counts,
                "cleared_error": self._cleared_error, "state": self._state, "port": self._port_name,
                "dialect": self._dialect.name}

    # -- bring-up (blocking; before start) -----------------------------------------------

    def enable(self) -> None:
        """Switch the axis on (the dialect's ``enable``, e.g. PI's servo on; nothing for a
        dialect without one). Blocking; before :meth:`start`. RuntimeError with the cause if
        the controller refuses or the line fails."""
        if self._dialect.enable:
            self._bring_up(lambda: self._set_command("enable"))
        elif self._state != "open":
            raise RuntimeError(self._why_not_running("bring-up commands go before start()"))

    def set_velocity(self, v: float) -> None:
        """Set the axis' speed for moves (m/s; the dialect's ``set_velocity``). Before :meth:`start`."""
        v = real_number(v, "v", unit="m/s", positive=True)
        if v > self._limits.v_max:
            raise ValueError(f"v={v!r} m/s exceeds the stage's v_max={self._limits.v_max!r} m/s")
        self._bring_up(lambda: self._set_command("set_velocity", v))

    def home(self, timeout: float = 60.0) -> None:
        """Reference the axis (the dialect's ``home``) and wait until it reports ready
        (``query_ready``), at most ``timeout`` s (TimeoutError). Blocking; before :meth:`start`."""
        timeout = real_number(timeout, "timeout", unit="s", positive=True)
        d = self._dialect
        if not d.home:
            raise ValueError(f"the {d.name} dialect has no home command")

        def run():
            deadline = time.monotonic() + timeout
            self._set_command("home")
            while d.query_ready:
                if self._query_ready():
                    return
                if time.monotonic() > deadline:
                    raise TimeoutError(f"the axis did not report ready within {timeout} s of {d.home!r}")
                time.sleep(0.02)

        self._bring_up(run)

    def start(self) -> None:
        """Clear an error left from before (kept as ``status()['cleared_error']``), read the
        position (three queries: the round trip), then start the I/O thread. RuntimeError if
        a reply is wrong or the position lies outside the soft limits (a fault: the stop is sent)."""
        if self._state != "open":
            raise RuntimeError(self._why_not_running("cannot start"))
        try:
            if self._dialect.query_error:
                try:
                    self._query_error()
                except _Fault as f:
                    if not isinstance(f.__cause__, ControllerError):
                        raise
                    self._cleared_error = f.__cause__.code
            for _ in range(3):
                self._poll()
        except _Fault as f:
            self._latch(str(f))
            self._send_stop()
            self._state = "stopped"
            raise RuntimeError(f"the stage did not start: {f}") from None
        self._interval = 2.0 * self._round_trip
        self._state = "running"
        self._thread = threading.Thread(target=self._run, name=f"SerialStage {self._port_name}", daemon=True)
        self._thread.start()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"SerialStage({self._port_name!r}, {self._dialect.name}, {self._baudrate} Bd, state={self._state}, "
                f"fault={self._fault!r})")

    # -- the I/O thread ------------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._loop()
        except _Fault as f:
            self._latch(str(f))
        except Exception as exc:  # noqa: BLE001 (a bug must still stop the axis and say so)
            self._latch(f"driver error: {type(exc).__name__}: {exc}")
        finally:
            self._send_stop()
            if self._state == "running":
                self._state = "stopped"

    def _loop(self) -> None:
        clock = time.monotonic
        last_move = last_poll = -math.inf
        last_error = clock()
        last_was_move = False
        by_error_query = self._confirm_by_error_query
        while not self._stop_request.is_set():
            self._wake.clear()
            now = clock()
            if by_error_query and now >= last_error + self._error_interval:
                self._query_error()
                last_error = clock()
                continue
            poll_due = now >= last_poll + self._poll_interval
            if self._slot is not None and now >= last_move + self._interval and not (poll_due and last_was_move):
                with self._lock:
                    x, self._slot = self._slot, None
                t0 = clock()
                if last_move > -math.inf:
                    self._min_spacing = min(self._min_spacing, t0 - last_move)
                self._set_command("move", x)
                t1 = clock()
                self._target = x
                self._counts["moves"] += 1
                self._moves.append(t1 - t0)
                move = statistics.median(self._moves)
                cycle = move + self._round_trip  # a move, then the query a due poll puts behind it
                self._interval = cycle if self._poll_interval < cycle else move
                last_move, last_was_move = t0, True
                if by_error_query:
                    last_error = t1
                continue
            remaining = last_move + self._interval - now
            if self._slot is not None and not last_was_move and 0 < remaining < self._round_trip:
                self._wake.wait(remaining)  # the next move is due sooner than a query would end
                continue
            if poll_due:
                last_poll = clock()
                self._poll()
                last_was_move = False
                continue
            wait = last_poll + self._poll_interval - now
            if self._slot is not None:
                wait = min(wait, last_move + self._interval - now)
            if by_error_query:
                wait = min(wait, last_error + self._error_interval - now)
            self._wake.wait(max(wait, 0.0))

    def _poll(self) -> None:
        request = self._query_label
        t0 = time.monotonic()
        self._expect_quiet(request)
        self._write(self._query, request)
        reply = self._read_reply(request)
        t1 = time.monotonic()
        x = self._parse(self._dialect.parse_position, reply, request)
        problem = check_reading(x, self._limits, self._margin)
        if problem is not None:
            raise _Fault(f"{problem} (reply {_show(reply)} to {request!r})")
        x_old, t_old, _ = self._reading
        v = (x - x_old) / (t0 - t_old) if math.isfinite(t_old) and t0 > t_old else 0.0
        self._reading = (x, t0, v)
        self._counts["polls"] += 1
        self._polls.append(t1 - t0)
        self._round_trip = statistics.median(self._polls)

    def _set_command(self, kind: str, x: float | None = None) -> None:
        """Send a set command and check the controller took it: its answer (``ack_reply``),
        or the error query sent right behind it (``query_error``), or nothing to check."""
        d = self._dialect
        data = d.command(kind, x)
        request = self._label(data)
        self._expect_quiet(request)
        if d.ack_reply:
            self._write(data, request)
            self._parse(d.parse_ack, self._read_reply(request), request)
        elif d.query_error:
            query = d.command("query_error")
            request = f"{request} + {self._label(query)}"
            self._write(data + query, request)
            self._counts["error_queries"] += 1
            self._parse(d.parse_error, self._read_reply(request), request)
        else:
            self._write(data, request)

    def _query_error(self) -> None:
        d = self._dialect
        data = d.command("query_error")
        request = self._label(data)
        self._expect_quiet(request)
        self._write(data, request)
        self._counts["error_queries"] += 1
        self._parse(d.parse_error, self._read_reply(request), request)

    def _query_ready(self) -> bool:
        d = self._dialect
        data = d.command("query_ready")
        request = self._label(data)
        self._expect_quiet(request)
        self._write(data, request)
        return self._parse(d.parse_ready, self._read_reply(request), request)

    def _send_stop(self) -> None:
        """The stop command, whatever came before (a fault included); its answer, if the dialect
        has one, is read and not judged. Nothing if the port is dead."""
        if self._dead or not self._port.is_open:
            return
        d = self._dialect
        data = d.command("stop")
        request = self._label(data)
        try:
            self._rx.clear()
            self._write(data, request)
            self._counts["stops_sent"] += 1
            if d.ack_reply:
                try:
                    self._read_reply(request)
                except _Fault:
                    pass
        except _Fault as f:
            self._latch(f"{f} (sending the stop)")

    # -- the line ------------------------------------------------------------------------

    def _write(self, data: bytes, request: str) -> None:
        try:
            self._port.write(data)
        except self._serial.SerialTimeoutException:
            raise _Fault(f"communication timeout: could not write {request!r} within {self._timeout} s") from None
        except (self._serial.SerialException, OSError) as exc:
            self._dead = True
            raise _Fault(f"port closed: {exc} (writing {request!r})") from None

    def _read_some(self, room: int, request: str) -> bytes:
        """At most ``room`` bytes: blocks up to the port's timeout for the first, then takes
        what has arrived."""
        port = self._port
        try:
            data = port.read(1)
            if data and room > 1:
                n = port.in_waiting
                if n:
                    data += port.read(min(n, room - 1))
        except (self._serial.SerialException, OSError) as exc:
            self._dead = True
            raise _Fault(f"port closed: {exc} (reading the reply to {request!r})") from None
        return data

    def _read_reply(self, request: str) -> bytes:
        """One whole reply, its terminator included, within ``timeout``; bytes beyond it, a reply
        longer than ``max_reply`` or none in time are faults."""
        term, buf = self._term, self._rx
        deadline = time.monotonic() + self._timeout
        while True:
            i = buf.find(term)
            if i >= 0:
                end = i + len(term)
                reply = bytes(buf[:end])
                if len(buf) > end:
                    raise _Fault(f"unexpected bytes {_show(buf[end:])} after the reply {_show(reply)} to {request!r}")
                buf.clear()
                return reply
            if len(buf) >= self._max_reply:
                raise _Fault(f"reply too long: no terminator in {_show(buf)} (reply to {request!r}; "
                             f"at most {self._max_reply} bytes)")
            if time.monotonic() > deadline:
                if buf:
                    raise _Fault(f"truncated reply: {_show(buf)} has no terminator {self._term!r} after "
                                 f"{self._timeout} s (reply to {request!r})")
                raise _Fault(f"communication timeout: no reply to {request!r} within {self._timeout} s")
            buf += self._read_some(self._max_reply - len(buf), request)

    def _expect_quiet(self, request: str) -> None:
        """Nothing may be waiting before a command: bytes nobody asked for are a fault."""
        data = bytes(self._rx)
        try:
            n = self._port.in_waiting
            if n:
                data += self._port.read(min(n, self._max_reply))
        except (self._serial.SerialException, OSError) as exc:
            self._dead = True
            raise _Fault(f"port closed: {exc} (before {request!r})") from None
        if data:
            raise _Fault(f"unexpected bytes {_show(data)} from the controller (before {request!r})")

    def _parse(self, parse, reply: bytes, request: str):
        try:
            return parse(reply, request)
        except (ReplyError, ControllerError) as exc:
            raise _Fault(str(exc)) from exc

    # -- helpers -------------------------------------------------------------------------

    def _label(self, data: bytes) -> str:
        return data.decode(self._dialect.encoding).strip()

    def _latch(self, fault: str) -> None:
        if self._fault is None:
            self._fault = fault

    def _why_not_running(self, what: str) -> str:
        if self._fault is not None:
            return f"the stage driver has faulted ({self._fault}); {what}"
        if self._state == "open":
            return f"the stage driver is not started (call start() after the bring-up); {what}"
        return f"the stage driver is {self._state}; {what}"

    def _bring_up(self, run) -> None:
        if self._state != "open":
            raise RuntimeError(self._why_not_running("bring-up commands go before start()"))
        try:
            run()
        except _Fault as f:
            raise RuntimeError(str(f)) from f.__cause__
