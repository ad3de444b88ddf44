"""The safety supervisor: stop the stage, and say why, on every fault of a rig run.

A :class:`Supervisor` watches one run (bring-up and loop) in the loop's own thread: the loop
hands it each block, each position reading, the pipeline's status and each target before it
is sent. At the first fault it stops the stage at once (``stage.stop()``: the driver's stop,
ahead of anything queued) and remembers the cause (:class:`Trip`); the loop then ends and
raises :class:`RigError`, which keeps the partial run. It never reconnects and never
restarts the stage.

The causes (:data:`CAUSES`):

``"target outside soft limits"``    a target the law gave lies outside them: never sent
``"position outside soft limits"``  the stage reports a position beyond them (plus a margin)
``"controller error"``              the driver latched a fault: an error reply, a malformed
                                    reply, a failed output write or counter read
``"stale position"``                the position reading is older than ``max_position_age``
``"communication timeout"``         no block within ``comm_timeout``, or the driver timed out
``"closed port"``                   the device is gone (its port closed, the DAQ removed)
``"late blocks"``                   ``late_blocks`` blocks in a row handled later than
                                    ``late_block`` after their last sample
``"overrun"``                       samples lost: the acquisition's buffer overflowed
``"pipeline fault"``                the pipeline's fault status (too many rejected samples)
``"SIGINT"``, ``"SIGTERM"``         the process was told to stop (Ctrl-C, ``kill``)
``"error"``                         anything else that raised inside the run

What it cannot do: it runs in the loop's thread, so a loop that stalls (a process frozen,
a machine that hangs) stops nothing; the stage controller's own communication watchdog and
the DAQ's (``safety.watchdog``) and a hardware E-stop in the amplifier's enable chain do
(``docs/rig.md``).
"""
from __future__ import annotations

import math
import signal
import threading
import time
from dataclasses import dataclass

from tactile_mirror.loop.stage import StageLimits

__all__ = ["CAUSES", "RigError", "Supervisor", "Trip", "fault_cause"]

CAUSES = ("target outside soft limits", "position outside soft limits", "controller error", "stale position",
          "communication timeout", "closed port", "late blocks", "overrun", "pipeline fault", "SIGINT", "SIGTERM",
          "error")


@dataclass
class Trip:
    """Why and when a run was stopped.

    Attributes
    ----------
    cause : str
        One of :data:`CAUSES`.
    detail : str
        The cause in words (the driver's own, a position, a count).
    t_fault_ns : int
        ``monotonic_ns`` time of the fault where it is known (a block's sample, a signal's
        arrival, the reading's time), else when it was seen.
    t_detect_ns : int
        When the supervisor saw it.
    t_stop_ns : int
        When ``stage.stop()`` returned (-1: it raised, see ``stop_error``).
    stop_error : str or None
        What ``stage.stop()`` raised (the line is down: the controller's watchdog stops the axis).
    """

    cause: str
    detail: str
    t_fault_ns: int
    t_detect_ns: int
    t_stop_ns: int = -1
    stop_error: str | None = None

    def describe(self) -> str:
        """One line: the cause, its detail, how the stop went."""
        stop = (f"stop sent {(self.t_stop_ns - self.t_fault_ns) / 1e6:.1f} ms after the fault" if self.t_stop_ns >= 0
                else f"stop failed ({self.stop_error}): the controller's watchdog stops the axis")
        return f"{self.cause}: {self.detail}; {stop}"


class RigError(RuntimeError):
    """A rig run stopped on a fault (:class:`Trip`): the stage was stopped first.

    Attributes
    ----------
    trip : Trip
    cause : str
        ``trip.cause``.
    partial : object or None
        What was run before the fault (a :class:`~tactile_mirror.rig.runner.RigResult`, or
        the bring-up's record): nothing recorded is lost.
    """

    def __init__(self, trip: Trip, partial=None):
        super().__init__(trip.describe())
        self.trip = trip
        self.cause = trip.cause
        self.partial = partial


def fault_cause(text: str) -> str:
    """The cause (:data:`CAUSES`) of a driver's latched fault, from its words: a closed port
    (or a device gone), a communication timeout, a position reading outside the soft limits,
    else a controller error (an error reply, a malformed reply, a failed write)."""
    t = text.lower()
    if "port closed" in t or "closed port" in t or "removed" in t or "is gone" in t:
        return "closed port"
    if "communication timeout" in t or "no reply" in t or "timed out" in t:
        return "communication timeout"
    if t.startswith("position out of limits") or "outside the soft limits" in t:
        return "position outside soft limits"
    return "controller error"


class Supervisor:
    """Watches a run and stops the stage at its first fault (see the module notes).

    Parameters
    ----------
    stage : StageDriver
        The stage (``stop()``, ``fault()``, ``position_age()`` where it has them).
    limits : StageLimits
        The soft limits.
    max_position_age, comm_timeout, late_block : float
        s (see :data:`CAUSES`).
    late_blocks : int
        Late blocks in a row that stop the run.
    position_margin : float
        m a position reading may lie beyond the soft limits (a servo's following error).
    signals : bool
        Catch SIGINT and SIGTERM while inside ``with supervisor:`` (handlers installed on
        entry, the previous ones restored on exit; only in the main thread).
    """

    def __init__(self, stage, limits: StageLimits, *, max_position_age: float = 0.02, comm_timeout: float = 0.1,
                 late_block: float = 0.005, late_blocks: int = 3, position_margin: float = 0.0,
                 signals: bool = True):
        if not isinstance(limits, StageLimits):
            raise TypeError(f"limits must be StageLimits, got {type(limits).__name__}")
        self.stage = stage
        self.limits = limits
        self.max_position_age = float(max_position_age)
        self.comm_timeout = float(comm_timeout)
        self.late_block_ns = round(float(late_block) * 1e9)
        self.late_blocks = int(late_blocks)
        self.position_margin = float(position_margin)
        self.signals = bool(signals)
        self.trip_: Trip | None = None
        self._late_run = 0
        self.late_total = 0
        self.overruns = 0
        self.lost = 0
        self.largest_age = 0.0
        self._signal: tuple[int, int] | None = None
        self._previous: dict = {}

    @classmethod
    def from_config(cls, stage, config, signals: bool = True) -> Supervisor:
        """The supervisor of a :class:`~tactile_mirror.rig.config.RigConfig`'s ``[safety]``."""
        s = config.safety
        return cls(stage, config.limits, max_position_age=s["max_position_age"], comm_timeout=s["comm_timeout"],
                   late_block=s["late_block"], late_blocks=s["late_blocks"], position_margin=s["position_margin"],
                   signals=signals)

    # ------------------------------------------------------------------ signals
    def __enter__(self) -> Supervisor:
        if self.signals and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous = {}

    def _on_signal(self, signum, frame) -> None:
        # Only note it: the loop's thread stops the stage at its next check (a driver's call
        # interrupted half-way must not be re-entered from here).
        if self._signal is None:
            self._signal = (signum, time.monotonic_ns())

    # ------------------------------------------------------------------ trip
    @property
    def tripped(self) -> Trip | None:
        """The first fault (None while there is none)."""
        return self.trip_

    def trip(self, cause: str, detail: str, t_fault_ns: int | None = None) -> Trip:
        """Stop the stage now and record why (only the first call counts). Returns the trip."""
        if self.trip_ is not None:
            return self.trip_
        now = time.monotonic_ns()
        t = Trip(cause, detail, now if t_fault_ns is None else int(t_fault_ns), now)
        self.trip_ = t
        stop = getattr(self.stage, "stop", None)
        if stop is not None:
            try:
                stop()
            except Exception as exc:  # noqa: BLE001 (the line is down: the watchdog stops the axis)
                t.stop_error = f"{type(exc).__name__}: {exc}"
            else:
                t.t_stop_ns = time.monotonic_ns()
        return t

    def error(self) -> RigError | None:
        """The :class:`RigError` of the trip (None before one)."""
        return None if self.trip_ is None else RigError(self.trip_)

    # ------------------------------------------------------------------ checks (True: tripped)
    def check_signal(self) -> bool:
        """A SIGINT or SIGTERM has come."""
        if self._signal is not None and self.trip_ is None:
            signum, t = self._signal
            name = "SIGINT" if signum == signal.SIGINT else "SIGTERM"
            self.trip(name, f"{name} received: stopped on request", t)
        return self.trip_ is not None

    def check_block(self, block, t_read_ns: int, late: bool = True) -> bool:
        """A block as the loop got it at ``t_read_ns``: lost samples (an overrun), lateness
        (``late=False``: not judged, for a run that commands nothing)."""
        if block.lost:
            self.overruns += 1
            self.lost += int(block.lost)
            self.trip("overrun", f"{block.lost} samples lost before sample {block.index} (the acquisition's "
                                 f"buffer overflowed: the loop fell behind)", block.t_ns)
            return True
        if late and t_read_ns - block.t_ns > self.late_block_ns:
            self._late_run += 1
            self.late_total += 1
            if self._late_run >= self.late_blocks:
                self.trip("late blocks", f"{self._late_run} blocks in a row handled more than "
                                         f"{self.late_block_ns / 1e6:g} ms after their last sample (the last: "
                                         f"{(t_read_ns - block.t_ns) / 1e6:.1f} ms)", block.t_ns)
                return True
        else:
            self._late_run = 0
        return self.check_signal()

    def check_stage(self, position: float) -> bool:
        """The stage after a position reading: its latched fault, the reading's limits and age."""
        stage = self.stage
        fault = getattr(stage, "fault", None)
        text = fault() if fault is not None else None
        if text:
            self.trip(fault_cause(text), f"the stage driver reports: {text}")
            return True
        lim, m = self.limits, self.position_margin
        if not (isinstance(position, float) and lim.x_min - m <= position <= lim.x_max + m):
            self.trip("position outside soft limits", f"the stage reports {position!r} m, outside the soft limits "
                                                       f"[{lim.x_min:g}, {lim.x_max:g}] m (margin {m:g} m)")
            return True
        age_of = getattr(stage, "position_age", None)
        if age_of is not None:
            age = float(age_of())
            if age > self.largest_age and math.isfinite(age):
                self.largest_age = age
            if not age <= self.max_position_age:
                now = time.monotonic_ns()
                t = now - round(age * 1e9) if math.isfinite(age) else now
                self.trip("stale position", f"the position reading is {age * 1e3:.1f} ms old (bound "
                                            f"{self.max_position_age * 1e3:g} ms): the device has gone silent", t)
                return True
        return False

    def check_target(self, x: float) -> bool:
        """A target before it is sent: outside the soft limits it is never sent."""
        lim = self.limits
        if not (lim.x_min <= x <= lim.x_max):
            self.trip("target outside soft limits", f"the law asked for {x!r} m, outside the soft limits "
                                                    f"[{lim.x_min:g}, {lim.x_max:g}] m: not sent")
            return True
        return False

    def check_pipeline(self, status: dict, t_fault_ns: int | None = None) -> bool:
        """The pipeline's status after a block: its fault."""
        if status.get("fault"):
            self.trip("pipeline fault", f"{status.get('consecutive_rejected', '?')} samples in a row rejected "
                                        f"({status.get('last_reason') or '?'}, channel "
                                        f"{status.get('last_bad_channel', '?')})", t_fault_ns)
            return True
        return False

    def check_timeout(self, waited: float) -> bool:
        """No block came for ``waited`` s."""
        if waited >= self.comm_timeout:
            self.trip("communication timeout", f"no block from the acquisition for {waited * 1e3:.0f} ms (bound "
                                               f"{self.comm_timeout * 1e3:g} ms)")
            return True
        return self.check_signal()
