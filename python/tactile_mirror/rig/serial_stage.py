"""A stage driver over a serial line (RS-232/USB serial, or a TCP bridge with ``socket://``).

:class:`SerialStage` speaks a :class:`~tactile_mirror.rig.dialects.Dialect` to one axis of a
controller. A serial line is full duplex and a controller answers its commands in the order it
got them, so the driver's one I/O thread pipelines: it writes the next command without waiting
for the answers still on their way back, keeps the commands whose answers are due in a queue
(at most ``max_in_flight``) and matches every answer line to the head of that queue. What it
writes:

- the latest target of the one-slot mailbox filled by :meth:`SerialStage.move_to` (targets
  given faster than the line carries them are coalesced; the latest wins), at most once per
  :attr:`~SerialStage.command_interval`, confirmed by the controller's answer (``ack_reply``)
  or, for a dialect whose set commands are not answered (PI GCS), by its error query written
  right behind it;
- a position query riding behind a move whenever the next move would come too late to keep
  the reading's age within ``target_age``, at least behind every ``k``-th (``k`` the most moves
  per query that keep it so at the top rate); while no moves stream, a query whenever its
  answer would follow the one on its way back to back (``poll_interval`` apart), with the
  line let go quiet every ``error_interval`` (an answer nobody asked for would otherwise shift
  the answers behind it unseen). While moves stream, no query is put on the line between
  them: it would hold the next move up;
- the error query every ``error_interval`` for a dialect whose errors latch (PI GCS).

The driver paces itself on the line's clock: it knows the bytes it wrote and the baud rate, so
it knows when each command's last byte reaches the controller and when each answer is due
(its bytes after those before it, plus the controller's processing time, measured). It never
writes more than one move's worth of bytes ahead of the line (a stop written at a fault waits
behind little), and an answer overdue by more than ``reply_overdue`` is a communication
timeout: a silent controller is found a few milliseconds after its first missing answer. A
reading is stamped with the time its query reached the controller (the earliest the controller
can have measured it), so :meth:`~SerialStage.position_age` is an upper bound of the reading's
true age.

Every answer is parsed strictly; anything unexpected (an error reply, a malformed, truncated or
over-long reply, bytes nobody asked for, an answer overdue, a closed port, a position outside
the soft limits or one the stage cannot have reached at ``max_speed``) latches a fault in words
with the bytes shown, after which the driver sends the stop command and nothing else, and its
I/O thread ends. It never reconnects. A reply whose terminator was lost on the line runs into
the next one: the merged line is refused as malformed, or the reply after it never comes (a
communication timeout). :meth:`SerialStage.move_to` never blocks: it checks the target against
the soft limits and swaps it into the mailbox under a lock that no I/O is ever done under.

Not run against a real controller: the tests drive it through a pseudo-terminal against
:class:`tactile_mirror.rig.sim.SerialAxis`, which paces the bytes at the line's baud rate in
each direction. pyserial (the ``rig`` extra) is imported when a driver is made.
"""
from __future__ import annotations

import collections
import contextlib
import math
import os
import select
import statistics
import threading
import time

from tactile_mirror.checks import integer, real_number
from tactile_mirror.loop.stage import StageLimits
from tactile_mirror.rig.dialects import ControllerError, Dialect, ReplyError
from tactile_mirror.rig.stage import check_reading, check_target

__all__ = ["SerialStage"]

_WINDOW = 16     # clean position queries whose round trips give the round trip and the processing time
_MAX_K = 8       # at most this many moves per position query while moves stream
_GUESS = 32      # bytes assumed for an answer a dialect gives no template of


class _Fault(Exception):
    """Internal: a fault of the line or the controller, in words (latched by the I/O thread)."""


class _Pending:
    """A command whose answer is due: what it was, when it reached the controller, when its
    answer is due (s, ``time.monotonic``)."""

    __slots__ = ("kind", "label", "t_sent", "t_arrive", "due", "clean")

    def __init__(self, kind: str, label: str, t_sent: float, t_arrive: float, due: float, clean: bool):
        self.kind, self.label, self.t_sent, self.t_arrive, self.due, self.clean = \
            kind, label, t_sent, t_arrive, due, clean


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
        The line's baud rate (8N1: 10 bits per byte); the driver's clock of the line.
    timeout : float
        The longest wait for a write, and for an answer during bring-up (:meth:`enable`,
        :meth:`home`, :meth:`start`), s.
    reply_overdue : float
        How long an answer may come after its due time (its bytes at the baud rate behind
        those before it, plus the controller's processing time) before it is a communication
        timeout, s. A TCP bridge adds its own latency: give it here.
    processing : float, optional
        The controller's time from a command's last byte to its answer's first, s (None:
        measured by :meth:`start` from the position queries' round trips).
    target_age : float
        The position reading's age the query schedule keeps while moves stream at the top
        rate, s (it sets how many moves go per position query).
    poll_interval : float
        Shortest interval between two position queries sent while the line is idle, s (0: as
        soon as both directions are free).
    error_interval : float
        Interval of the error query of a dialect whose errors latch (``query_error`` without
        ``ack_reply``), s; moves are confirmed by it at once regardless. Also the longest the
        line goes without a quiet moment while only queries go.
    max_in_flight : int
        Most commands whose answers are outstanding (a move, its confirmation and a position
        query may go in one write: at least 2).
    position_margin : float
        How far beyond the soft limits a reading may lie (the servo's following error), m.
    max_speed : float, optional
        A reading that would have the stage move faster than this from the previous one is a
        fault (a corrupted reply), m/s (None: twice ``limits.v_max``; ``math.inf``: never).
    max_reply : int
        The longest reply accepted, bytes: a longer one is a fault (the buffer never grows).

    Use: make it, bring the axis up (:meth:`enable`, :meth:`home`, blocking), :meth:`start`
    the I/O thread, then :meth:`move_to` / :meth:`position` from the loop; :meth:`close` at
    the end (also as a context manager).
    """

    command_mode = "per_block"  # a serial line carries a command per block, not per 1 kHz tick

    def __init__(self, port: str, dialect: Dialect, limits: StageLimits, *, baudrate: int = 115200,
                 timeout: float = 0.1, reply_overdue: float = 0.01, processing: float | None = None,
                 target_age: float = 0.008, poll_interval: float = 0.0, error_interval: float = 0.1,
                 max_in_flight: int = 4, position_margin: float = 1e-4, max_speed: float | None = None,
                 max_reply: int = 256):
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
        self._bt = 10.0 / self._baudrate
        self._timeout = real_number(timeout, "timeout", unit="s", positive=True)
        self._overdue = real_number(reply_overdue, "reply_overdue", unit="s", positive=True)
        self._fixed_processing = (None if processing is None
                                  else real_number(processing, "processing", unit="s", nonnegative=True))
        self._target_age = real_number(target_age, "target_age", unit="s", positive=True)
        self._poll_interval = real_number(poll_interval, "poll_interval", unit="s", nonnegative=True)
        self._error_interval = real_number(error_interval, "error_interval", unit="s", positive=True)
        self._max_in_flight = integer(max_in_flight, "max_in_flight", 2)
        self._margin = real_number(position_margin, "position_margin", unit="m", nonnegative=True)
        if max_speed is None:
            self._max_speed = 2.0 * limits.v_max
        elif max_speed == math.inf:
            self._max_speed = math.inf
        else:
            self._max_speed = real_number(max_speed, "max_speed", unit="m/s", positive=True)
        self._max_reply = integer(max_reply, "max_reply", 8)
        self._term = dialect.reply_terminator.encode(dialect.encoding)
        self._query = dialect.command("query_position")
        self._query_label = self._label(self._query)
        self._confirm_by_error_query = bool(dialect.query_error) and not dialect.ack_reply
        self._error_query = dialect.command("query_error") if dialect.query_error else b""
        self._sizes = self._answer_sizes()

        import serial  # (the optional 'rig' extra)
        self._serial = serial
        self._port_name = str(port)
        self._port = serial.serial_for_url(port, baudrate=self._baudrate, timeout=self._timeout,
                                           write_timeout=self._timeout)
        # on POSIX the line is read and written through its descriptor, non-blocking (pyserial's
        # write with a timeout waits for the line to drain and may call a finished write late)
        try:
            self._fd = self._port.fileno() if os.name == "posix" else None
            if self._fd is not None:
                os.set_blocking(self._fd, False)
        except Exception:  # noqa: BLE001 (a port without a file descriptor goes through pyserial, polled)
            self._fd = None
        self._rx = bytearray()
        self._dead = False            # the port failed: nothing more can be written

        self._lock = threading.Lock()  # guards the mailbox only (never held across I/O)
        self._slot: float | None = None
        self._wake = threading.Event()
        self._stop_request = threading.Event()
        self._thread: threading.Thread | None = None
        self._state = "open"          # open -> running -> stopped -> closed
        self._fault: str | None = None

        # the line's clock: when the bytes written so far will have left, when the answers due will have come
        self._tx_free = 0.0
        self._rx_free = 0.0
        self._pending: collections.deque[_Pending] = collections.deque()
        self._reading = (math.nan, -math.inf, 0.0)  # (position m, monotonic s it was measured, velocity m/s)
        self._target = math.nan
        self._round_trips: collections.deque = collections.deque(maxlen=_WINDOW)
        self._round_trip = math.nan
        self._processing = self._fixed_processing if self._fixed_processing is not None else 0.0
        self._move_bytes = len(dialect.move_command(limits.x_min if abs(limits.x_min) > abs(limits.x_max)
                                                    else limits.x_max))
        self._k = 1
        self._interval = math.nan
        self._min_spacing = math.inf
        self._counts = {"moves": 0, "coalesced": 0, "polls": 0, "error_queries": 0, "stops_sent": 0,
                        "max_in_flight": 0}
        self._latest_reply = 0.0      # the latest an answer came after its due time, s
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
        """The interval between two moves the line sustains, s: per move, the move and its
        confirmation, and a ``1 / k`` share of a position query and its answer, on the busier
        of the line's two directions (bytes at the baud rate), plus the controller's measured
        processing time; ``k`` (:attr:`moves_per_query`) the most moves per query that keep
        the reading's age within ``target_age`` at that rate. NaN before :meth:`start`. Moves
        are never sent closer than this."""
        return self._interval

    @property
    def moves_per_query(self) -> int:
        """How many moves go per position query while moves stream at the top rate."""
        return self._k

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
        self._poke()

    def position(self) -> float:
        """The last position reading, m (NaN before the first)."""
        return self._reading[0]

    def position_age(self) -> float:
        """Seconds since the controller can at the earliest have measured the last reading (its
        query's last byte reached it; inf before the first reading)."""
        return time.monotonic() - self._reading[1]

    def velocity(self) -> float:
        """The velocity from the last two readings, m/s."""
        return self._reading[2]

    def fault(self) -> str | None:
        return self._fault

    def round_trip(self) -> float:
        """The median round trip of the position queries :meth:`start` sent, one at a time on
        an idle line, s (NaN before)."""
        return self._round_trip

    def processing(self) -> float:
        """The controller's processing time the driver assumes, s (the ``processing`` given, or
        the median round trip of :meth:`start`'s queries less their bytes' time on the line)."""
        return self._processing

    def stop(self) -> None:
        """Stop the axis: the dialect's stop command goes out ahead of any queued target, then
        the I/O thread ends (waits for it up to ``2 * timeout + 1`` s). Without a running
        thread the stop is sent from here. Never raises for a dead line (the fault says it)."""
        thread = self._thread
        if self._state in ("open", "running"):
            self._state = "stopped"
        if thread is not None and thread.is_alive():
            self._stop_request.set()
            self._poke()
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
                "moves_per_query": self._k, "round_trip": self._round_trip, "processing": self._processing,
                "min_move_spacing": self._min_spacing, "latest_reply": self._latest_reply, **self._counts,
                "in_flight": len(self._pending), "cleared_error": self._cleared_error, "state": self._state,
                "port": self._port_name, "dialect": self._dialect.name, "baudrate": self._baudrate}

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
        position (five queries: the round trip and the controller's processing time), then
        start the I/O thread. RuntimeError if a reply is wrong or the position lies outside the
        soft limits (a fault: the stop is sent)."""
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
            for _ in range(5):
                self._exchange([(self._query, self._query_label, "position")])
        except _Fault as f:
            self._latch(str(f))
            self._send_stop()
            self._state = "stopped"
            raise RuntimeError(f"the stage did not start: {f}") from None
        self._plan()
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

    # -- the schedule --------------------------------------------------------------------

    def _answer_sizes(self) -> dict:
        """Bytes of each kind of answer (the dialect's own answers where it has them, the
        longest position within the soft limits; else a guess), for the answers' due times."""
        d = self._dialect
        x = max(abs(self._limits.x_min), abs(self._limits.x_max)) + 1e-3
        sizes = {}
        for kind, template, fields in (("position", d.position_answer, {"pos": d.units_text(-x)}),
                                       ("ack", d.ack_answer, {"state": "BUSY"}),
                                       ("error", d.error_answer, {"code": d.bad_target_code or d.no_error}),
                                       ("ready", d.ready_answer, {"state": "BUSY"})):
            sizes[kind] = len(d.answer(kind, **fields)) if template else _GUESS
        return sizes

    def _plan(self) -> None:
        """The moves per position query ``k`` and the command interval from the bytes per move,
        the baud rate and the processing time (see :attr:`command_interval`)."""
        d, bt, s = self._dialect, self._bt, self._sizes
        tx_move, rx_move = self._move_bytes, 0
        if d.ack_reply:
            rx_move = s["ack"]
        elif self._confirm_by_error_query:
            tx_move += len(self._error_query)
            rx_move = s["error"]
        tx_query, rx_query = len(self._query), s["position"]
        p = self._processing
        best = None
        for k in range(1, _MAX_K + 1):
            cycle = max(tx_move + tx_query / k, rx_move + rx_query / k) * bt + p
            age = k * cycle + p + rx_query * bt     # a reading's age just before the next one comes
            if best is None or age <= self._target_age:
                best = (k, cycle)
        self._k, self._interval = best

    def _poke(self) -> None:
        """Wake the I/O thread (a new target, a stop): an event, not a syscall that would hand
        the interpreter to another thread in the middle of the loop's ``move_to``."""
        self._wake.set()

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
        bt = self._bt
        last_move = last_poll = -math.inf
        last_error = clock()
        moves_since_query = 0
        by_error_query = self._confirm_by_error_query
        pending = self._pending
        query, query_label = self._query, self._query_label
        backlog = self._move_bytes * bt        # the most bytes' time written ahead of the line
        age = self._target_age
        latency = self._processing + self._sizes["position"] * bt   # a query's arrival -> its answer
        # a quiet line now and then (nothing due for as long as the longest answer takes): a
        # line nobody asked for that looks like the answer expected would otherwise shift every
        # answer behind it by one, unseen while only position queries go; on a quiet line it is
        # a fault (unexpected bytes)
        guard = max(self._sizes.values()) * bt + self._processing + 1e-3
        last_quiet, quiet_since = clock(), None
        while not self._stop_request.is_set():
            self._receive()
            now = clock()
            if not pending:
                quiet_since = now if quiet_since is None else quiet_since
                if now >= quiet_since + guard:
                    last_quiet = now
            else:
                quiet_since = None
                if now > pending[0].due + self._overdue:
                    self._overdue_fault()
            wake = now + 0.05
            if len(pending) + 2 <= self._max_in_flight and self._tx_free - now <= backlog:
                if by_error_query and now >= last_error + self._error_interval:
                    self._send([(self._error_query, self._label(self._error_query), "error")])
                    self._counts["error_queries"] += 1
                    last_error = now
                    continue
                if self._slot is not None:
                    if now >= last_move + self._interval:
                        with self._lock:
                            x, self._slot = self._slot, None
                        parts = self._move_parts(x)
                        moves_since_query += 1
                        # a query rides behind this move if the next move (as far off as this one
                        # came after the last) would bring the reading too late, at most every k-th
                        spacing = min(now - last_move, age)
                        if moves_since_query >= self._k or now + spacing - last_poll > age - latency:
                            parts.append((query, query_label, "position"))
                            moves_since_query = 0
                            last_poll = now
                        self._send(parts)
                        if last_move > -math.inf:
                            self._min_spacing = min(self._min_spacing, now - last_move)
                        last_move = now
                        self._target = x
                        self._counts["moves"] += 1
                        if by_error_query:
                            last_error = now
                        continue
                    wake = min(wake, last_move + self._interval)
                elif now < last_move + age and now < last_poll + age:
                    # moves stream and queries ride behind them: the line stays free for the next
                    # move (a query put on it now would hold that move up by its bytes)
                    wake = min(wake, last_move + age, last_poll + age)
                elif now > last_quiet + self._error_interval:
                    if quiet_since is not None:   # (the line is quiet: until the guard has passed)
                        wake = min(wake, quiet_since + guard)
                elif sum(p.kind == "position" for p in pending) < 2:
                    # the next query once its answer would come right behind the one on its way
                    t_next = max(self._tx_free, self._rx_free - (len(query) * bt + self._processing),
                                 last_poll + self._poll_interval)
                    if now >= t_next:
                        self._send([(query, query_label, "position")])
                        moves_since_query = 0
                        last_poll = now
                        continue
                    wake = min(wake, t_next)
                if by_error_query:
                    wake = min(wake, last_error + self._error_interval)
            else:
                wake = min(wake, max(self._tx_free - backlog, now + 1e-4))
            if pending:
                head = pending[0]
                # the answer's bytes come at the line's pace: read it whole once it is due
                if now < head.due:
                    self._sleep(min(wake, head.due), watch_port=False)
                    continue
                wake = min(wake, head.due + self._overdue)
            self._sleep(wake, watch_port=bool(pending))

    def _move_parts(self, x: float) -> list:
        d = self._dialect
        data = self._move_command(x)
        label = self._label(data)
        if d.ack_reply:
            return [(data, label, "ack")]
        if self._confirm_by_error_query:
            self._counts["error_queries"] += 1
            return [(data, label, None), (self._error_query, f"{label} + {self._label(self._error_query)}", "error")]
        return [(data, label, None)]

    def _move_command(self, x: float) -> bytes:
        """The move to ``x`` as written, its position rounded to the controller's resolution
        and, where rounding took it past a soft limit, one step back inside."""
        d, lim = self._dialect, self._limits
        written = float(d.units_text(x)) / d.units_per_m
        if not lim.x_min <= written <= lim.x_max:
            step = 10.0 ** -d.decimals / d.units_per_m
            x = x - step if written > lim.x_max else x + step
        return d.command("move", x)

    def _sleep(self, until: float, watch_port: bool) -> None:
        """Wait until ``until`` (monotonic s) or a wake-up (a target, a stop); with
        ``watch_port`` (an answer is due and has not all come) at most 0.2 ms, so that the
        port is read again. Answers come when they are due: the thread wakes about once per
        answer, not once per byte."""
        wait = until - time.monotonic()
        if wait <= 0:
            return
        self._wake.wait(min(wait, 2e-4) if watch_port else wait)
        self._wake.clear()

    def _overdue_fault(self) -> None:
        """The head's answer is overdue: read what has come (a host that woke late is no fault
        of the line), and if it is still missing, the fault."""
        self._receive()
        pending = self._pending
        if not pending:
            return
        head = pending[0]
        late = time.monotonic() - head.due
        if late <= self._overdue:
            return
        if self._rx:
            raise _Fault(f"truncated reply: {_show(self._rx)} has no terminator {self._term!r} {late * 1e3:.1f} ms "
                         f"after it was due (reply to {head.label!r})")
        raise _Fault(f"communication timeout: no reply to {head.label!r} {late * 1e3:.1f} ms after it was due "
                     f"(its bytes at {self._baudrate} Bd and {self._processing * 1e3:.2f} ms of processing; "
                     f"bound {self._overdue * 1e3:g} ms)")

    # -- the line: writing and reading ---------------------------------------------------

    def _send(self, parts) -> None:
        """Write the commands ``parts`` (``(bytes, label, kind of answer or None)``) in one go
        and put those answered on the queue with their due times."""
        data = b"".join(p[0] for p in parts)
        clean = not self._pending and self._tx_free <= time.monotonic()
        self._write(data, " + ".join(p[1] for p in parts))
        t_sent = time.monotonic()      # (the bytes leave once the write has returned, at the latest)
        t = max(self._tx_free, t_sent)
        bt = self._bt
        for cmd, label, kind in parts:
            t += len(cmd) * bt
            if kind is None:
                continue
            start = max(self._rx_free, t + self._processing)
            due = start + self._sizes[kind] * bt
            self._rx_free = due
            self._pending.append(_Pending(kind, label, t_sent, t, due, clean))
        self._tx_free = t
        if len(self._pending) > self._counts["max_in_flight"]:
            self._counts["max_in_flight"] = len(self._pending)

    def _read_available(self, what: str) -> bytes:
        """The bytes that have come, without waiting (b"" for none); a closed port is a fault."""
        try:
            if self._fd is not None:
                try:
                    data = os.read(self._fd, self._max_reply + 64)
                except BlockingIOError:
                    return b""
                if not data and select.select([self._fd], [], [], 0)[0]:
                    # a tty gives b"" when nothing has come; readable and still empty is a device gone
                    data = os.read(self._fd, self._max_reply + 64)
                    if not data:
                        raise OSError("the device reports data and returns none (it hung up)")
                return data
            n = self._port.in_waiting
            return self._port.read(min(n, self._max_reply + 64)) if n else b""
        except (self._serial.SerialException, OSError) as exc:
            self._dead = True
            raise _Fault(f"port closed: {exc} ({what})") from None

    def _receive(self) -> None:
        """Read what has come (without waiting) and handle every whole answer, in order."""
        buf, term = self._rx, self._term
        label = self._pending[0].label if self._pending else "nothing"
        buf += self._read_available(f"reading the reply to {label!r}")
        if not buf:
            return
        t_recv = time.monotonic()
        while True:
            i = buf.find(term)
            if i < 0:
                break
            end = i + len(term)
            reply = bytes(buf[:end])
            del buf[:end]
            if not self._pending:
                raise _Fault(f"unexpected bytes {_show(reply + bytes(buf))} from the controller (nothing was asked)")
            self._handle(self._pending.popleft(), reply, t_recv)
            if not self._pending:   # (nothing is on its way back: the estimate of the line may not say otherwise)
                self._rx_free = min(self._rx_free, t_recv)
        if buf and not self._pending:
            raise _Fault(f"unexpected bytes {_show(buf)} from the controller (nothing was asked)")
        if len(buf) >= self._max_reply:
            label = self._pending[0].label if self._pending else "nothing"
            raise _Fault(f"reply too long: no terminator in {_show(buf)} (reply to {label!r}; at most "
                         f"{self._max_reply} bytes)")

    def _handle(self, p: _Pending, reply: bytes, t_recv: float) -> None:
        d = self._dialect
        self._latest_reply = max(self._latest_reply, t_recv - p.due)
        if p.kind == "position":
            x = self._parse(d.parse_position, reply, p.label)
            problem = check_reading(x, self._limits, self._margin)
            if problem is not None:
                raise _Fault(f"{problem} (reply {_show(reply)} to {p.label!r})")
            t = min(p.t_arrive, t_recv)
            x_old, t_old, _ = self._reading
            if math.isfinite(t_old) and self._state == "running":
                dt = max(t - t_old, 0.0)
                reach = self._max_speed * (dt + 2 * self._overdue) + self._margin
                if abs(x - x_old) > reach:
                    raise _Fault(f"implausible position reading: {x!r} m, {abs(x - x_old) * 1e3:.3f} mm from the "
                                 f"last reading {dt * 1e3:.1f} ms before (more than {self._max_speed:g} m/s allows; a "
                                 f"corrupted reply?) (reply {_show(reply)} to {p.label!r})")
            v = (x - x_old) / (t - t_old) if math.isfinite(t_old) and t > t_old else 0.0
            self._reading = (x, t, v)
            self._counts["polls"] += 1
            if p.clean and self._state == "open":
                # measured at start only, where the line is watched from the query on: the I/O
                # thread reads an answer when it is due, so its own round trips hold the estimate
                self._round_trips.append(t_recv - p.t_sent)
                self._round_trip = statistics.median(self._round_trips)
                if self._fixed_processing is None:
                    wire = (len(self._query) + len(reply)) * self._bt
                    self._processing = max(0.0, self._round_trip - wire)
        elif p.kind == "ack":
            self._parse(d.parse_ack, reply, p.label)
        elif p.kind == "error":
            self._parse(d.parse_error, reply, p.label)
        else:
            self._ready = self._parse(d.parse_ready, reply, p.label)

    def _exchange(self, parts) -> None:
        """Send ``parts`` and wait for their answers (bring-up: nothing else on the line),
        each within ``timeout``."""
        self._expect_quiet(parts[0][1])
        self._send(parts)
        deadline = time.monotonic() + self._timeout
        while self._pending:
            self._receive()
            if not self._pending:
                break
            if time.monotonic() > deadline:
                head = self._pending[0]
                self._pending.clear()
                if self._rx:
                    raise _Fault(f"truncated reply: {_show(self._rx)} has no terminator {self._term!r} after "
                                 f"{self._timeout} s (reply to {head.label!r})")
                raise _Fault(f"communication timeout: no reply to {head.label!r} within {self._timeout} s")
            self._sleep(min(deadline, max(self._pending[0].due, time.monotonic() + 2e-4)), watch_port=True)

    def _set_command(self, kind: str, x: float | None = None) -> None:
        """Send a set command and check the controller took it (bring-up): its answer
        (``ack_reply``), or the error query sent right behind it (``query_error``), or nothing
        to check."""
        d = self._dialect
        data = d.command(kind, x)
        label = self._label(data)
        if d.ack_reply:
            self._exchange([(data, label, "ack")])
        elif d.query_error:
            self._counts["error_queries"] += 1
            self._exchange([(data, label, None), (self._error_query, f"{label} + {self._label(self._error_query)}",
                                                  "error")])
        else:
            self._expect_quiet(label)
            self._send([(data, label, None)])

    def _query_error(self) -> None:
        self._counts["error_queries"] += 1
        self._exchange([(self._error_query, self._label(self._error_query), "error")])

    def _query_ready(self) -> bool:
        data = self._dialect.command("query_ready")
        self._ready = False
        self._exchange([(data, self._label(data), "ready")])
        return self._ready

    def _send_stop(self) -> None:
        """The stop command, whatever came before (a fault included); the answers still on their
        way and the stop's own (if the dialect has one) are read and not judged. Nothing if the
        port is dead."""
        if self._dead or not self._port.is_open:
            return
        d = self._dialect
        data = d.command("stop")
        request = self._label(data)
        try:
            self._write(data, request)
            self._counts["stops_sent"] += 1
        except _Fault as f:
            self._latch(f"{f} (sending the stop)")
            return
        # the answers due, then the stop's: read and dropped, for the time they take on the line
        now = time.monotonic()
        t = max(self._tx_free, now) + len(data) * self._bt
        end = max(self._rx_free, t + self._processing) + (self._sizes["ack"] if d.ack_reply else 0) * self._bt
        self._pending.clear()
        self._tx_free = t
        if not d.ack_reply:
            self._rx.clear()
            return
        end = min(end + self._overdue, now + self._timeout)
        with contextlib.suppress(Exception):   # (not judged: the stop is out)
            while time.monotonic() < end:
                self._read_available("after the stop")
                self._sleep(min(end, time.monotonic() + 5e-4), watch_port=True)
        self._rx.clear()

    def _write(self, data: bytes, request: str) -> None:
        """Hand ``data`` to the line (the driver paces itself: the device's buffer has room);
        a device that takes none of it for ``timeout`` is a communication timeout."""
        try:
            if self._fd is None:
                self._port.write(data)
                return
            view, deadline = memoryview(data), None
            while view:
                try:
                    n = os.write(self._fd, view)
                except BlockingIOError:
                    n = 0
                view = view[n:]
                if view:
                    now = time.monotonic()
                    deadline = deadline or now + self._timeout
                    if now > deadline:
                        raise self._serial.SerialTimeoutException("write timeout")
                    select.select([], [self._fd], [], deadline - now)
        except self._serial.SerialTimeoutException:
            raise _Fault(f"communication timeout: could not write {request!r} within {self._timeout} s (the "
                         f"device takes no bytes)") from None
        except (self._serial.SerialException, OSError, ValueError) as exc:
            self._dead = True
            raise _Fault(f"port closed: {exc} (writing {request!r})") from None

    def _expect_quiet(self, request: str) -> None:
        """Nothing may be waiting before a bring-up command: bytes nobody asked for are a fault."""
        data = bytes(self._rx) + self._read_available(f"before {request!r}")
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
