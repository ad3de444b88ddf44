"""What the rig needs from a stage driver, and the soft-limit checks every driver shares.

:class:`StageDriver` extends :class:`tactile_mirror.loop.Stage` (what the loop runner uses)
with what a real driver must say about itself: how old its last position reading is,
whether it has latched a fault, how often it can send a command and how long a query takes.
A driver's ``move_to`` never blocks the loop: the target goes into a one-slot mailbox (the
latest wins) that the driver's own I/O thread sends when the line allows.

:func:`check_target` is the soft-limit check a driver applies to every target before it
accepts it (a target outside the limits raises and is never sent); :func:`check_reading`
is the check of every position the controller reports.
"""
from __future__ import annotations

import math
import numbers
from typing import Protocol, runtime_checkable

from tactile_mirror.loop.stage import Stage, StageLimits

__all__ = ["COMMAND_MODES", "StageDriver", "check_reading", "check_target"]

#: How a driver takes its targets: ``"per_tick"`` (one ``move_to`` per loop tick is sent as
#: it comes) or ``"per_block"`` (the runner commands once per acquisition block; targets
#: given faster than the driver's ``command_interval`` are coalesced, the latest wins).
COMMAND_MODES = ("per_tick", "per_block")


@runtime_checkable
class StageDriver(Stage, Protocol):
    """A stage driver of the rig (SI units: m, s).

    Besides :class:`~tactile_mirror.loop.Stage` (``limits``, ``move_to``, ``position``,
    ``velocity``, ``stop``, ``status``):

    - ``move_to(x)`` never blocks: it checks ``x`` against the soft limits
      (:func:`check_target`: outside raises ``ValueError`` and nothing is sent) and puts it
      into a one-slot mailbox read by the driver's I/O thread (the latest target wins);
    - ``position()`` is the last reading (a float, never blocks), ``position_age()`` how old
      it is, s (``inf`` before the first);
    - ``command_mode`` is one of :data:`COMMAND_MODES`, ``command_interval`` the measured
      shortest interval between two commands the driver sustains, s (it never sends faster);
    - ``fault()`` is the latched fault in words (controller error reply, malformed reply,
      communication timeout, closed port, position out of limits), None while there is none;
      after a fault the driver sends nothing but the stop;
    - ``stop()`` stops the axis at once (ahead of any queued target) and ends the I/O thread;
      ``close()`` stops and releases the port; a driver never reconnects;
    - ``round_trip()`` is the measured round trip of a position query, s.
    """

    command_mode: str

    @property
    def command_interval(self) -> float: ...

    def position_age(self) -> float:
        """Age of the last position reading, s (``inf`` before the first)."""

    def fault(self) -> str | None:
        """The latched fault with its cause in words, or None."""

    def round_trip(self) -> float:
        """Measured round trip of a position query, s."""

    def close(self) -> None:
        """Stop the axis and release the port."""


def check_target(x, limits: StageLimits) -> float:
    """``x`` (m) as a float if it is a finite real number within ``[limits.x_min, limits.x_max]``.

    Raises TypeError for what is not a real number (a bool is not) and ValueError for NaN,
    infinity or a target outside the soft limits, naming the target and the limits; a driver
    sends nothing then.
    """
    if type(x) is not float:
        if isinstance(x, bool) or not isinstance(x, numbers.Real):
            raise TypeError(f"a stage target must be a real number (m), got {type(x).__name__}")
        x = float(x)
    if not limits.x_min <= x <= limits.x_max:  # (NaN fails here too)
        if not math.isfinite(x):
            raise ValueError(f"stage target {x!r} is not a finite number (m); not sent")
        raise ValueError(f"stage target {x!r} m lies outside the soft limits [{limits.x_min!r}, {limits.x_max!r}] m; "
                         "not sent")
    return x


def check_reading(x: float, limits: StageLimits, margin: float = 0.0) -> str | None:
    """None if the reported position ``x`` (m) is finite and within the soft limits widened by
    ``margin`` (m, for the servo's following error at a limit), else the fault in words."""
    if not math.isfinite(x):
        return f"position reading {x!r} is not a finite number"
    if not limits.x_min - margin <= x <= limits.x_max + margin:
        return (f"position out of limits: the controller reports {x!r} m, outside the soft limits "
                f"[{limits.x_min!r}, {limits.x_max!r}] m (margin {margin!r} m)")
    return None
