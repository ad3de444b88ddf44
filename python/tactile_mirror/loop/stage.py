"""The stage the pad sits on: a protocol for real drivers and a simulated stage.

A lab wraps its stage driver in an object with the methods of :class:`Stage`;
:class:`tactile_mirror.loop.LoopRunner` uses nothing else. :class:`SimulatedStage`
is a stage with a command dead time, speed and acceleration limits, travel limits
and a first-order servo lag, advanced in simulated time by :meth:`SimulatedStage.advance`.
"""
from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from tactile_mirror.checks import real_number

__all__ = ["SimulatedStage", "Stage", "StageLimits"]


@dataclass(frozen=True)
class StageLimits:
    """Travel (m), speed (m/s) and acceleration (m/s^2) limits of a stage."""

    x_min: float
    x_max: float
    v_max: float
    a_max: float

    def __post_init__(self):
        for name in ("x_min", "x_max", "v_max", "a_max"):
            object.__setattr__(self, name, real_number(getattr(self, name), name))
        if not self.x_min < self.x_max:
            raise ValueError(f"x_max must be greater than x_min, got [{self.x_min}, {self.x_max}]")
        if not self.v_max > 0:
            raise ValueError(f"v_max must be > 0 m/s, got {self.v_max}")
        if not self.a_max > 0:
            raise ValueError(f"a_max must be > 0 m/s^2, got {self.a_max}")


@runtime_checkable
class Stage(Protocol):
    """What the loop needs from a y-axis stage (SI units).

    ``move_to`` must return quickly (it is called once per tick from the real-time
    loop): it sets the target, the stage's own controller moves there.
    """

    @property
    def limits(self) -> StageLimits: ...

    def move_to(self, x: float) -> None:
        """Set the target position, m (clipped to the travel limits)."""

    def position(self) -> float:
        """Measured position, m."""

    def velocity(self) -> float:
        """Measured velocity, m/s."""

    def stop(self) -> None:
        """Decelerate to rest and hold."""

    def status(self) -> dict:
        """Driver status (at least ``position``, ``velocity``, ``target``, ``fault``)."""


class SimulatedStage:
    """A stage with dead time, speed/acceleration limits and a servo lag.

    Model, per :meth:`advance` of ``dt``: a target given by :meth:`move_to` takes
    effect ``delay`` seconds later; a trajectory generator moves the set point
    towards it at most at ``v_max`` and ``a_max`` (braking in time to stop on the
    target); the carriage follows the set point through a first-order lag of time
    constant ``lag`` (servo following error). Targets are clipped to the travel.

    Parameters
    ----------
    limits : StageLimits, optional
        Default: +-50 mm, 50 mm/s, 2 m/s^2.
    delay : float
        Command dead time, s (>= 0).
    lag : float
        Servo time constant, s (>= 0; 0 = the carriage is on the set point).
    x0 : float
        Start position, m.
    """

    def __init__(self, limits: StageLimits | None = None, delay: float = 0.0, lag: float = 0.0, x0: float = 0.0):
        self._limits = limits if limits is not None else StageLimits(-0.05, 0.05, 0.05, 2.0)
        if not isinstance(self._limits, StageLimits):
            raise TypeError(f"limits must be StageLimits, got {type(limits).__name__}")
        delay = real_number(delay, "delay", unit="s", nonnegative=True)
        lag = real_number(lag, "lag", unit="s", nonnegative=True)
        self.delay = delay
        self.lag = lag
        self.reset(x0)  # (checks x0)

    def reset(self, x0: float = 0.0) -> None:
        """Back to rest at ``x0`` (m, within the travel), at time 0, nothing pending."""
        x0 = real_number(x0, "x0", unit="m")
        if not self._limits.x_min <= x0 <= self._limits.x_max:
            raise ValueError(f"x0={x0} lies outside the travel [{self._limits.x_min}, {self._limits.x_max}]")
        self.t = 0.0
        self._sp = x0          # trajectory set point
        self._sv = 0.0         # set point velocity
        self._x = x0           # carriage
        self._v = 0.0
        self._target = x0      # active target
        self._pending = collections.deque()  # (time it takes effect, target)
        self.n_moves = 0
        self.n_clipped = 0

    @property
    def limits(self) -> StageLimits:
        return self._limits

    def move_to(self, x: float) -> None:
        x = float(x)
        if not math.isfinite(x):
            raise ValueError(f"x must be finite, got {x}")
        lim = self._limits
        xc = min(max(x, lim.x_min), lim.x_max)
        self.n_clipped += xc != x
        self.n_moves += 1
        if self.delay == 0.0:
            self._target = xc
        else:
            self._pending.append((self.t + self.delay, xc))

    def stop(self) -> None:
        """Target the position where the set point can stop."""
        self._pending.clear()
        a = self._limits.a_max
        self._target = self._sp + self._sv * abs(self._sv) / (2 * a)

    def position(self) -> float:
        return self._x

    def velocity(self) -> float:
        return self._v

    def status(self) -> dict:
        return {"position": self._x, "velocity": self._v, "target": self._target, "set_point": self._sp,
                "fault": False, "moves": self.n_moves, "clipped": self.n_clipped, "time": self.t}

    def advance(self, dt: float) -> float:
        """Move the simulated time on by ``dt`` seconds; returns the position, m."""
        dt = real_number(dt, "dt", unit="s", positive=True)
        # A target takes effect at the first interval that starts at or after its due time
        # (sent at t with a dead time of one dt, it moves the carriage from t + dt on, not
        # over [t, t + dt]); dead times are thus whole ticks, rounded up.
        while self._pending and self._pending[0][0] <= self.t + 1e-12:
            self._target = self._pending.popleft()[1]
        self.t += dt
        lim = self._limits
        e = self._target - self._sp
        # Speed that still allows stopping on the target (decelerating by a_max dt
        # per step: v^2 / (2 a) + v dt / 2 <= |e|), then the limits.
        h = 0.5 * lim.a_max * dt
        vd = math.copysign(min(lim.v_max, math.sqrt(h * h + 2.0 * lim.a_max * abs(e)) - h), e)
        dv = min(max(vd - self._sv, -lim.a_max * dt), lim.a_max * dt)
        sv = self._sv + dv
        if abs(e) <= abs(sv) * dt and abs(sv) <= lim.a_max * dt + 1e-15:
            self._sp, self._sv = self._target, 0.0  # arrived
        else:
            self._sp += sv * dt
            self._sv = sv
        self._sp = min(max(self._sp, lim.x_min), lim.x_max)
        x_old = self._x
        if self.lag > 0:
            self._x += (self._sp - self._x) * (1.0 - math.exp(-dt / self.lag))
        else:
            self._x = self._sp
        self._v = (self._x - x_old) / dt
        return self._x

    def __repr__(self) -> str:
        return f"SimulatedStage(limits={self._limits}, delay={self.delay}, lag={self.lag})"
