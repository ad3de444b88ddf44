"""Stage controllers: from the slip detector's outputs to a stage command.

Both laws read, per tick, ``y`` = the largest ``y_pred`` over the ridges in use and
the L/R asymmetry of the stress rates, and command a stage position ``x`` (m)
and velocity ``v`` (m/s). They run inside the C++ pipeline
(:class:`tactile_mirror.MirrorPipeline`); the classes here hold and validate the
parameters and give a numpy reference of the same arithmetic (:meth:`Controller.run`).

Direction (both laws)
    The shear load on a ridge bends it, so the two strips see opposite stress
    changes: ``rate_L - rate_R`` is the rate of the L/R stress difference. Its leaky
    integral (time constant ``asym_tau``)::

        a <- exp(-dt / asym_tau) a + dt * sum_r (rate_L,r - rate_R,r)

    is the stress difference high-passed at ``1 / (2 pi asym_tau)``: its sign says
    which way the finger pulls. ``dir = direction_sign * sign(a)`` while
    ``|a| > asym_deadband``, else the previous ``dir`` (0 before the first decision).
    ``direction_sign`` maps the strips' orientation to the stage axis (+1 or -1;
    calibrate it once per pad, e.g. with :func:`tactile_mirror.lab.loop.experiment.calibrate_shear`).

Command (both laws)
    What goes to the stage is the law's position ``x``, or, with ``planner_decel`` = ``d`` > 0,
    ``x`` led by the braking distance ``sign(v) max(0, v^2 / (2 d) - |v| dt / 2)``. A stage
    whose move command plans a braking move to each target (a point-to-point trajectory
    generator, as :class:`~tactile_mirror.loop.SimulatedStage`) moves its set point at
    ``sqrt(h^2 + 2 d e) - h`` (``h = d dt / 2``, ``e`` the distance left): a target moving at
    ``v`` is trailed by ``v^2 / (2 d)``, with a small-signal lag of time constant ``|v| / d``
    (20 ms at 20 mm/s and 1 m/s^2). Led by the braking distance, the planner moves at the
    law's speed and the stage is its dead time and servo lag again.

Arming (both laws)
    For ``arm_delay`` seconds after a reset the stage holds while the finger settles;
    then the asymmetry is zeroed (the settled contact's shear is the reference).

:class:`PaperController` (Fujimoto et al., section 4.2.2)
    "the displacement is set in proportion to the amplitude of ``y_pred`` when it
    overpasses the threshold": every tick with ``y >= threshold`` the target moves
    by ``dir * gain * y * dt``. Only the travel limits are enforced; a real stage
    saturates its own speed and acceleration.

:class:`VelocityController`
    A velocity command with a deadband and a linear ramp, plus an optional shear
    feedback on the asymmetry ``a`` (proportional to the L/R stress difference):
    ``v_des = dir * ramp_gain * v_max * s + direction_sign * shear_gain * (1 + pred_boost * s) * a``
    with ``s = clip((y - threshold) / (y_full - threshold), 0, 1)``, clipped to ``+-v_max``,
    bounded so that the stage can always stop before a travel limit
    (``v^2 / (2 a_max) + |v| dt / 2 <= d``, the distance left), slewed by at most ``a_max * dt`` per tick and
    integrated into the target: it respects the stage's speed, acceleration and travel.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from tactile_mirror import _core
from tactile_mirror.checks import real_number

__all__ = ["Controller", "NoController", "PaperController", "VelocityController", "controller_fields",
           "controller_from_dict"]

# The parameters, their defaults and the laws that read them are defined once, in
# C++ (TM_CONTROLLER_FIELDS in controller.hpp); the C ABI (tm_controller_defaults),
# the pipeline and these dataclasses all take them from there.
_FIELDS = tuple(_core.controller_fields())
_DEFAULTS = {kind: _core.controller_defaults(kind) for kind in ("none", "paper", "velocity")}


def controller_fields(kind: str | None = None) -> tuple[str, ...]:
    """Names of the controller parameters: those of ``tm_controller_params`` in its order,
    then those kept in ``tm_config``'s tail (``planner_decel``).

    ``kind=None``: all of them; ``"paper"`` / ``"velocity"``: those the law reads;
    ``"none"``: those every law reads.
    """
    if kind is None:
        return tuple(f[0] for f in _FIELDS)
    if kind == "none":
        return tuple(f[0] for f in _FIELDS if set(f[1]) == {"paper", "velocity"})
    return tuple(f[0] for f in _FIELDS if kind in f[1])


class _LawState:
    """The mutable state of a law between ticks (the C++ StageController's)."""

    __slots__ = ("a", "dir", "hold_left", "slip_run", "ticks", "v", "w", "x")

    def __init__(self, x: float):
        self.x, self.v, self.a, self.dir, self.w = x, 0.0, 0.0, 0.0, 0.0
        self.ticks = 0
        self.hold_left = 0
        self.slip_run = 0

    def snapshot(self) -> tuple:
        """The whole state, for a tick's undo (:meth:`restore`)."""
        return (self.x, self.v, self.a, self.dir, self.w, self.ticks, self.hold_left, self.slip_run)

    def restore(self, s: tuple) -> None:
        self.x, self.v, self.a, self.dir, self.w, self.ticks, self.hold_left, self.slip_run = s


@dataclass(frozen=True)
class Controller:
    """Parameters shared by the laws (see the module docstring).

    Parameters
    ----------
    threshold : float
        ``y_pred`` threshold, in [0, 1).
    x_min, x_max : float
        Travel limits of the command, m; ``x_min <= 0 <= x_max`` (0 is the start).
    direction_sign : {+1, -1}
        Stage direction for a positive L-R asymmetry.
    asym_tau : float
        Time constant of the asymmetry integrator, s (> 0).
    asym_deadband : float
        Asymmetry (rate units x s; Pa for stress-rate features) below which the
        previous direction is kept (>= 0).
    arm_delay : float
        Seconds after a reset during which the stage holds (the finger settles);
        then the asymmetry integrator is zeroed (a tare) and the law starts.
    slip_hold : float
        Slip guard, s (>= 0; 0 = off): while the detector reports gross slip
        (``y_slip`` at the pipeline's slip threshold on any ridge) and for
        ``slip_hold`` after, the law holds as in a fault (the velocity law
        decelerates at ``a_max``), then re-tares the asymmetry. While the contact
        slides the strips' asymmetry no longer measures the relative displacement
        (sliding friction holds it and the release of static friction swings it), so
        a law acting on it can run the stage away.
    slip_confirm : float
        s (>= 0): the guard starts once the detector reported slip on every tick
        for this long (0: at once). A one-tick ``y_slip`` peak while the contact
        still sticks would otherwise stop a stage that follows a moving finger.
    slip_min_asym : float
        (>= 0, asymmetry units; 0 = always): a detected slip starts the guard only
        while the asymmetry integrator's magnitude is at least this: a contact whose
        shear is near its tare cannot slip, so a report there is a false alarm.
    planner_decel : float
        m/s^2 (>= 0; 0 = off, the default): the deceleration with which the stage plans a
        braking move to each target (its ``a_max`` for a point-to-point move command). The
        command then leads the law's position by the braking distance (see the module
        docstring), so that the planned set point moves at the law's speed. 0 for a stage
        that follows streamed set points.
    """

    kind = "none"
    threshold: float = _DEFAULTS["none"]["threshold"]
    x_min: float = _DEFAULTS["none"]["x_min"]
    x_max: float = _DEFAULTS["none"]["x_max"]
    direction_sign: float = _DEFAULTS["none"]["direction_sign"]
    asym_tau: float = _DEFAULTS["none"]["asym_tau"]
    asym_deadband: float = _DEFAULTS["none"]["asym_deadband"]
    arm_delay: float = _DEFAULTS["none"]["arm_delay"]
    slip_hold: float = _DEFAULTS["none"]["slip_hold"]
    slip_confirm: float = _DEFAULTS["none"]["slip_confirm"]
    slip_min_asym: float = _DEFAULTS["none"]["slip_min_asym"]
    planner_decel: float = _DEFAULTS["none"]["planner_decel"]

    def __post_init__(self):
        for name in ("threshold", "x_min", "x_max", "direction_sign", "asym_tau", "asym_deadband", "arm_delay",
                     "slip_hold", "slip_confirm", "slip_min_asym", "planner_decel"):
            object.__setattr__(self, name, real_number(getattr(self, name), name))
        if not 0.0 <= self.threshold < 1.0:
            raise ValueError(f"threshold must lie in [0, 1), got {self.threshold}")
        if not self.x_min < self.x_max:
            raise ValueError(f"x_max must be greater than x_min, got x_min={self.x_min}, x_max={self.x_max}")
        if not (self.x_min <= 0.0 <= self.x_max):
            raise ValueError(f"x_min and x_max must bracket 0 (the start position), got [{self.x_min}, {self.x_max}]")
        if self.direction_sign not in (1.0, -1.0):
            raise ValueError(f"direction_sign must be +1 or -1, got {self.direction_sign}")
        if not self.asym_tau > 0:
            raise ValueError(f"asym_tau must be > 0 s, got {self.asym_tau}")
        if not self.asym_deadband >= 0:
            raise ValueError(f"asym_deadband must be >= 0, got {self.asym_deadband}")
        if not 0 <= self.arm_delay <= 3600:
            raise ValueError(f"arm_delay must lie in [0, 3600] s, got {self.arm_delay}")
        if not 0 <= self.slip_hold <= 3600:
            raise ValueError(f"slip_hold must lie in [0, 3600] s, got {self.slip_hold}")
        if not 0 <= self.slip_confirm <= 3600:
            raise ValueError(f"slip_confirm must lie in [0, 3600] s, got {self.slip_confirm}")
        if not self.slip_min_asym >= 0:
            raise ValueError(f"slip_min_asym must be >= 0, got {self.slip_min_asym}")
        if not self.planner_decel >= 0:
            raise ValueError(f"planner_decel must be >= 0 m/s^2 (0 = off), got {self.planner_decel}")

    def params(self) -> dict:
        """The parameters as the C++ pipeline takes them (``kind`` included)."""
        d = asdict(self)
        d["kind"] = self.kind
        return d

    # -- numpy reference ---------------------------------------------------------------
    def _move(self, x, v, y, dt, dirn, a=0.0):
        return x, v

    def run(self, y_pred, asym, fs, x0: float = 0.0, slip=None):
        """Reference run of the law over a sequence (plain Python, float64).

        Parameters
        ----------
        y_pred : array_like, shape (n,)
            Largest ``y_pred`` over the ridges, per tick.
        asym : array_like, shape (n,)
            ``sum_r (rate_L - rate_R)`` per tick (rate units).
        fs : float
            Tick rate, Hz.
        x0 : float
            Start position, m.
        slip : array_like of bool, shape (n,), optional
            Gross slip reported by the detector per tick (for ``slip_hold``).

        Returns
        -------
        x, v : ndarray, shape (n,)
            The command sent to the stage (m; :meth:`command`) and the commanded
            velocity (m/s) after each tick.
        """
        y = np.asarray(y_pred, dtype=np.float64)
        d = np.asarray(asym, dtype=np.float64)
        if y.ndim != 1 or d.shape != y.shape:
            raise ValueError(f"y_pred and asym must be 1-D of equal length, got {y.shape} and {d.shape}")
        sl = np.zeros(y.shape, dtype=bool) if slip is None else np.asarray(slip, dtype=bool)
        if sl.shape != y.shape:
            raise ValueError(f"slip must have the shape of y_pred {y.shape}, got {sl.shape}")
        fs = real_number(fs, "fs", unit="Hz", positive=True)
        st = self._start(x0)
        xs = np.empty_like(y)
        vs = np.empty_like(y)
        for k in range(y.size):
            self._tick(st, float(y[k]), float(d[k]), False, bool(sl[k]), fs)
            xs[k], vs[k] = self.command(st, fs), st.v
        return xs, vs

    def command(self, st: _LawState, fs: float) -> float:
        """What goes to the stage: the law's position, led by the planner's braking
        distance when ``planner_decel`` > 0 (the C++ ``StageController::command``)."""
        d, v = self.planner_decel, st.v
        if not d > 0 or v == 0.0:
            return st.x
        s = abs(v)
        lead = s * s / (2.0 * d) - 0.5 * s * (1.0 / fs)
        if not lead > 0:
            return st.x
        return self._clamp(st.x + lead if v > 0 else st.x - lead)

    def _start(self, x0: float) -> _LawState:
        return _LawState(self._clamp(float(x0)))

    def _tick(self, st: _LawState, y: float, asym: float, fault: bool, slip: bool, fs: float) -> None:
        """One tick of the law on ``st`` (arming, slip guard, direction, motion): the
        arithmetic of the C++ ``StageController::step``, shared by :meth:`run` and
        :class:`tactile_mirror.ReferencePipeline`."""
        dt = 1.0 / fs
        arm = round(self.arm_delay * fs)
        if st.ticks < arm:  # arming: hold, then tare the asymmetry
            st.ticks += 1
            if st.ticks == arm:
                st.a, st.dir = 0.0, 0.0
            st.v = 0.0
            return
        hold_ticks = round(self.slip_hold * fs)
        hold = False
        if hold_ticks > 0:  # slip guard (and the run-away guard of the type-2 law)
            runaway = getattr(self, "shear_integral", 0.0) > 0 and abs(st.w) >= getattr(self, "v_max", math.inf)
            st.slip_run = st.slip_run + 1 if slip else 0
            loaded = abs(st.a) >= self.slip_min_asym
            if (slip and loaded and st.slip_run > round(self.slip_confirm * fs)) or runaway:
                st.hold_left = hold_ticks
            if st.hold_left > 0:
                hold, y, asym = True, 0.0, 0.0
                st.hold_left -= 1
                if st.hold_left == 0:
                    st.a, st.dir = 0.0, 0.0
        if fault or hold:
            st.w = 0.0
        st.a = math.exp(-dt / self.asym_tau) * st.a + dt * asym
        if abs(st.a) > self.asym_deadband:
            st.dir = self.direction_sign if st.a > 0 else -self.direction_sign
        self._law_step(st, y, asym, dt, fault, hold)

    def _law_step(self, st: _LawState, y: float, asym: float, dt: float, fault: bool, hold: bool) -> None:
        st.x, st.v = self._move(st.x, st.v, y, dt, st.dir, 0.0 if (fault or hold) else st.a)

    def _clamp(self, x):
        return min(max(x, self.x_min), self.x_max)


@dataclass(frozen=True)
class NoController(Controller):
    """No stage motion: the pipeline only detects (open loop)."""

    kind = "none"

    def _move(self, x, v, y, dt, dirn, a=0.0):
        return x, v


@dataclass(frozen=True)
class PaperController(Controller):
    """The paper's law: target displacement proportional to ``y_pred`` above threshold.

    Parameters
    ----------
    gain : float
        Target speed per unit ``y_pred``, m/s (>= 0): each tick with
        ``y_pred >= threshold`` moves the target by ``dir * gain * y_pred / fs``.
    threshold, x_min, x_max, direction_sign, asym_tau, asym_deadband
        See :class:`Controller`.
    """

    kind = "paper"
    threshold: float = _DEFAULTS["paper"]["threshold"]
    gain: float = _DEFAULTS["paper"]["gain"]

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "gain", real_number(self.gain, "gain", unit="m/s", nonnegative=True))

    def _move(self, x, v, y, dt, dirn, a=0.0):
        x0 = x
        if y >= self.threshold:
            x = self._clamp(x + dirn * self.gain * y * dt)
        return x, (x - x0) / dt


@dataclass(frozen=True)
class VelocityController(Controller):
    """Velocity ramp with a deadband, within the stage's speed, acceleration and travel.

    Parameters
    ----------
    threshold : float
        ``y_pred`` where the ramp starts (the deadband is ``y_pred < threshold``).
    y_full : float
        ``y_pred`` giving full speed, in ``(threshold, 1]``.
    v_max : float
        Speed limit, m/s (> 0).
    a_max : float
        Acceleration limit, m/s^2 (> 0).
    shear_gain : float
        Shear feedback, m/s per unit of asymmetry (>= 0; 0 = off): adds
        ``direction_sign * shear_gain * a`` to the speed, so the stage also moves to
        null the shear the finger puts on the pad before any slip is predicted.
    ramp_gain : float
        Share of ``v_max`` the ``y_pred`` ramp commands (>= 0; default 1). The ramp
        term ``dir * v_max * s`` switches with the sign of ``a``: a relay, which
        with the stage's lag and the filters' delay limit-cycles (measured: a
        ~25 Hz, +-2 N oscillation on the FEM pad). 0 removes it.
    pred_boost : float
        Gain scheduling of the shear feedback by the prediction (>= 0; default 0):
        the shear gain is ``shear_gain * (1 + pred_boost * s)``, so the stage
        follows the finger more tightly as the contact nears slip while staying
        a proportional (smooth) loop.
    shear_integral : float
        Integral action of the shear feedback, 1/s (>= 0; 0 = off): a velocity state
        ``w`` integrates ``direction_sign * shear_gain * shear_integral * a`` (clipped
        to ``+-v_max``, its rate to ``+-a_max``: the stage cannot change its speed faster)
        and is added to the speed. The loop on the relative
        displacement becomes type 2: ``w`` converges to the finger's speed and a
        steady finger motion leaves no tracking error (a type-1 loop leaves
        ``v / K``). A slip (the guard's hold) or a fault sets ``w`` to 0 and the
        stage decelerates: while the ridges' edges slide the L/R asymmetry answers
        with the wrong sign and a steady slide leaves the rates quiet, so no speed
        learnt around a slip can be trusted. With the slip guard on, ``w`` reaching
        ``v_max`` starts the guard's hold as a detected slip does: it is a run-away
        (the loop acting on a sliding contact's inverted asymmetry) or a finger the
        stage cannot follow.
    rate_gain : float
        Relative-velocity feedback, m/s per unit of ``sum_r (rate_L - rate_R)``
        (>= 0; 0 = off). While the contact sticks the stress rate is the shear
        stiffness times the finger-pad relative velocity: this term is a damping
        (derivative) action measured directly, with no numerical differentiation.
    x_min, x_max, direction_sign, asym_tau, asym_deadband
        See :class:`Controller`.

    :func:`tactile_mirror.loop.design.design_loop` (or :meth:`design`) chooses every
    gain from the stage's data sheet, the shear calibration and the sample rate.
    """

    kind = "velocity"
    threshold: float = _DEFAULTS["velocity"]["threshold"]
    y_full: float = _DEFAULTS["velocity"]["y_full"]
    v_max: float = _DEFAULTS["velocity"]["v_max"]
    a_max: float = _DEFAULTS["velocity"]["a_max"]
    shear_gain: float = _DEFAULTS["velocity"]["shear_gain"]
    ramp_gain: float = _DEFAULTS["velocity"]["ramp_gain"]
    pred_boost: float = _DEFAULTS["velocity"]["pred_boost"]
    shear_integral: float = _DEFAULTS["velocity"]["shear_integral"]
    rate_gain: float = _DEFAULTS["velocity"]["rate_gain"]

    def __post_init__(self):
        super().__post_init__()
        for name in ("y_full", "v_max", "a_max", "shear_gain", "ramp_gain", "pred_boost", "shear_integral",
                     "rate_gain"):
            object.__setattr__(self, name, real_number(getattr(self, name), name))
        if not self.threshold < self.y_full <= 1.0:
            raise ValueError(f"y_full must lie in (threshold, 1] = ({self.threshold}, 1], got {self.y_full}")
        if not self.v_max > 0:
            raise ValueError(f"v_max must be > 0 m/s, got {self.v_max}")
        if not self.a_max > 0:
            raise ValueError(f"a_max must be > 0 m/s^2, got {self.a_max}")
        if not self.shear_gain >= 0:
            raise ValueError(f"shear_gain must be >= 0 m/s per unit of asymmetry, got {self.shear_gain}")
        if not self.ramp_gain >= 0:
            raise ValueError(f"ramp_gain must be >= 0 (share of v_max), got {self.ramp_gain}")
        if not self.pred_boost >= 0:
            raise ValueError(f"pred_boost must be >= 0, got {self.pred_boost}")
        if not self.shear_integral >= 0:
            raise ValueError(f"shear_integral must be >= 0 1/s, got {self.shear_integral}")
        if not self.rate_gain >= 0:
            raise ValueError(f"rate_gain must be >= 0 m/s per unit of stress rate, got {self.rate_gain}")

    def _law_step(self, st: _LawState, y: float, asym: float, dt: float, fault: bool, hold: bool) -> None:
        if not fault and not hold:
            dw = self.direction_sign * self.shear_gain * self.shear_integral * st.a
            st.w += dt * min(max(dw, -self.a_max), self.a_max)
            st.w = min(max(st.w, -self.v_max), self.v_max)
        if fault or hold:
            vd = 0.0
        else:
            s = min(max((y - self.threshold) / (self.y_full - self.threshold), 0.0), 1.0)
            g = self.shear_gain * (1.0 + self.pred_boost * s)
            vd = (st.dir * self.ramp_gain * self.v_max * s + st.w
                  + self.direction_sign * (g * st.a + self.rate_gain * asym))
        st.x, st.v = self._limit(st.x, st.v, vd, dt)

    def _move(self, x, v, y, dt, dirn, a=0.0):
        s = min(max((y - self.threshold) / (self.y_full - self.threshold), 0.0), 1.0)
        g = self.shear_gain * (1.0 + self.pred_boost * s)
        vd = dirn * self.ramp_gain * self.v_max * s + self.direction_sign * g * a
        return self._limit(x, v, vd, dt)

    def _limit(self, x, v, vd, dt):
        """Speed, stopping distance, acceleration and travel limits on a desired speed ``vd``."""
        vd = min(max(vd, -self.v_max), self.v_max)
        h = 0.5 * self.a_max * dt
        if vd > 0:
            d = max(0.0, self.x_max - x)
            if vd * (vd + 2.0 * h) > 2.0 * self.a_max * d:
                vd = math.sqrt(h * h + 2.0 * self.a_max * d) - h
        elif vd < 0:
            d = max(0.0, x - self.x_min)
            if vd * (vd - 2.0 * h) > 2.0 * self.a_max * d:
                vd = h - math.sqrt(h * h + 2.0 * self.a_max * d)
        dv_max = self.a_max * dt
        v = v + min(max(vd - v, -dv_max), dv_max)
        x0, xn = x, x + v * dt
        x = self._clamp(xn)
        if x != xn:
            v = (x - x0) / dt
        return x, v


_KINDS = {"none": NoController, "paper": PaperController, "velocity": VelocityController}


def controller_from_dict(d) -> Controller:
    """Rebuild a controller from :meth:`Controller.params` (``None``: no controller)."""
    if d is None:
        return NoController()
    if isinstance(d, Controller):
        return d
    if not isinstance(d, dict):
        raise TypeError(f"controller must be a Controller, a dict or None, got {type(d).__name__}")
    d = dict(d)
    kind = d.pop("kind", "none")
    if kind not in _KINDS:
        raise ValueError(f"controller kind must be one of {sorted(_KINDS)}, got {kind!r}")
    cls = _KINDS[kind]
    names = set(cls.__dataclass_fields__)
    unknown = sorted(set(d) - names)
    # The C++ side reports every parameter; the ones a law does not use are dropped.
    known = {k: v for k, v in d.items() if k in names}
    unused = set(controller_fields())
    bad = [k for k in unknown if k not in unused]
    if bad:
        raise ValueError(f"controller {kind!r} has no parameter {bad[0]!r}")
    return cls(**known)
