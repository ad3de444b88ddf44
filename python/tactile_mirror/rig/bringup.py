"""Bring-up on the rig: from a connected rig to a law designed for it.

:func:`bring_up` runs, on the rig itself (never on the simulated pad's numbers):

1. **enable and home** the stage (a serial controller's ``enable`` / ``home``, when the
   driver has them and ``stage.home`` asks; an analog servo amplifier is enabled by its own
   enable line);
2. **the slow move to the start** (``stage.start`` at ``stage.approach_speed``);
3. **the command delay**: ``bringup.delay_steps`` small steps each way; each response is
   matched to the stage's model (its planner at ``a_max`` and its servo ``lag``) shifted in
   time, and the shift that fits best is the delay (the median over the steps); then **the
   loop's delay**: a small sine (``bringup.phase_amplitude`` at ``bringup.phase_frequency``)
   commanded once per block as the loop commands (from each block's last sample time, through
   the driver and its pacing, with the planner's braking lead), and its phase lag in the
   encoder's readings, less the servo lag's, as a dead time: everything between the law's
   tick and the stage's motion (the block's hold, the host, the line, the controller) at a
   frequency near the loop's crossover;
4. **the finger on the pad** (the operator places it and keeps it still), then **the
   charge amplifiers' reset** (:meth:`RigSession.reset_amplifiers
   <tactile_mirror.rig.session.RigSession.reset_amplifiers>`: a digital line, the operator,
   or the simulator's reset);
5. **a sensors-only run** (``bringup.sensors_only`` s; the stage is never commanded): the
   channels' noise and offsets, the acquisition's and the host's timing;
6. **the calibration move**: the stage moves the pad under the resting finger in slow
   triangle cycles (``bringup.calibration_amplitudes`` at ``bringup.calibration_speed``, the
   calibration :func:`~tactile_mirror.lab.loop.experiment.calibrate_shear_weights` makes on the
   simulated pad); the encoder gives the relative displacement, and
   :func:`~tactile_mirror.loop.calibration.fit_shear_weights` and
   :func:`~tactile_mirror.loop.calibration.fit_shear_scale` give the shear weights, the shear
   signal's sign and size per metre, and the force sensor's N/m (the contact's tangential
   stiffness). A scale per metre needs a known displacement: on a rig only the stage's
   encoder knows one, so the calibration moves the stage, slowly and by less than the
   contact carries (80 um of about 150 um);
7. **the law**: :func:`~tactile_mirror.loop.design.design_loop` from the soft limits, that
   calibration and the loop's measured delay (``loop.max_error`` bounding its crossover), and
   the loop's pipeline with it.

The acquisition runs throughout; between steps its blocks are read and checked (a loss is
an overrun: the supervisor stops). The supervisor watches every step.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from tactile_mirror.rig.realtime import gc_paused, raised_priority
from tactile_mirror.rig.runner import RigResult, RigRunner
from tactile_mirror.rig.supervisor import RigError, Supervisor

__all__ = ["BringUpResult", "bring_up", "build_pipeline", "fit_delay", "sine_phase"]


@dataclass
class BringUpResult:
    """What bring-up measured and designed (SI units).

    Attributes
    ----------
    start : float
        The start position the stage stands at, m.
    command_delay : float
        The stage's measured command delay (dead time), s; ``delay_steps`` each step's.
    stage_delay : float
        The delay the law was designed for, s: the loop's delay measured by the sine, less the
        tick the design counts itself.
    phase : dict
        The sine's measurement: ``frequency_hz``, ``amplitude_m``, ``phase_lag_deg``, ``gain``,
        ``loop_delay_ms`` (the dead time its phase lag means, the servo lag's taken out) and
        ``steps_estimate_ms`` (the stage delay the step fit, the block's hold and the host's
        latency would have given).
    noise : dict
        The sensors-only run: rms per channel group (``v_out``, ``u_out`` V, ``force_y``,
        ``force_z`` N) and the force channels' offsets.
    calibration : dict
        ``shear_weights`` (n_ridges, 2), ``direction_sign``, ``asym_per_m``, ``force_sign``,
        ``force_n_per_m`` and the fits' r^2.
    design : LoopDesign
    pipeline : MirrorPipeline
        The loop's pipeline with the designed law.
    sensors_only : RigResult
    steps : dict
        Each step's duration, s, and what it said.
    """

    start: float
    command_delay: float
    delay_steps: list
    stage_delay: float
    noise: dict
    calibration: dict
    design: object
    pipeline: object
    sensors_only: RigResult | None = None
    steps: dict = field(default_factory=dict)
    phase: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """The numbers (JSON-friendly)."""
        cal = dict(self.calibration)
        cal["shear_weights"] = np.asarray(cal["shear_weights"]).tolist()
        d = self.design
        return {"start_m": self.start, "command_delay_ms": 1e3 * self.command_delay,
                "delay_steps_ms": [1e3 * v for v in self.delay_steps], "stage_delay_ms": 1e3 * self.stage_delay,
                "phase": dict(self.phase), "noise": self.noise, "calibration": cal, "steps": self.steps,
                "design": {"sensor": d.sensor, "crossover_hz": d.crossover_hz, "phase_margin_deg": d.phase_margin_deg,
                           "gain_margin_db": d.gain_margin_db, "kp_per_s": d.kp, "integral_per_s": d.z, "kv": d.kv,
                           "delays_ms": {k: 1e3 * v for k, v in d.delays.items()}}}


# ---------------------------------------------------------------------- the acquisition between steps
class _Drain:
    """Reads the blocks that have come (a step that is not the loop still keeps the acquisition's
    buffer from overflowing); a loss trips the supervisor (an overrun)."""

    def __init__(self, source, sup: Supervisor):
        self.source, self.sup = source, sup
        self.blocks = 0

    def __call__(self, wait: float = 0.0):
        """Every block ready now; with ``wait`` > 0, the first one waited for up to ``wait`` s.
        The last block read (None if none)."""
        last = None
        timeout = wait
        while True:
            try:
                block = self.source.read_block(timeout)
            except TimeoutError:
                break
            timeout = 0.0
            self.blocks += 1
            last = block
            if block.lost:
                self.sup.check_block(block, time.monotonic_ns())
        self._raise()
        return last

    def _raise(self):
        if self.sup.check_signal() or self.sup.tripped is not None:
            raise RigError(self.sup.tripped)


class _Background(threading.Thread):
    """Drains the acquisition while the loop's thread computes (the law's design)."""

    def __init__(self, drain: _Drain):
        super().__init__(name="tactile-mirror-drain", daemon=True)
        self.drain = drain
        self.halt = threading.Event()
        self.error: BaseException | None = None

    def run(self):
        try:
            while not self.halt.is_set():
                self.drain(wait=0.05)
        except BaseException as exc:  # noqa: BLE001 (the main thread re-raises it)
            self.error = exc

    def stop(self):
        self.halt.set()
        self.join()
        if self.error is not None:
            raise self.error


class _Paced:
    """The stage, its ``move_to`` never called closer than ``interval`` s (the configured command
    rate holds through bring-up too: a call that comes sooner waits the rest)."""

    def __init__(self, stage, interval: float):
        self._stage, self._interval, self._last = stage, float(interval), -math.inf

    def move_to(self, x: float) -> None:
        wait = self._last + self._interval - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        self._stage.move_to(x)
        self._last = time.monotonic()

    def __getattr__(self, name):
        return getattr(self._stage, name)


def _hold(drain: _Drain, stage, sup: Supervisor, seconds: float) -> None:
    """Keep reading blocks (and checking the stage) for ``seconds``."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        drain(wait=min(0.05, max(0.0, end - time.monotonic())))
        if sup.check_stage(stage.position()):
            raise RigError(sup.tripped)


def _move(drain: _Drain, stage, sup: Supervisor, targets) -> None:
    """Command ``targets(t)`` (m, ``t`` s since the start; None: done) once per block."""
    t0 = time.monotonic()
    while True:
        drain(wait=0.05)
        p = stage.position()
        if sup.check_stage(p):
            raise RigError(sup.tripped)
        x = targets(time.monotonic() - t0, p)
        if x is None:
            return
        if sup.check_target(x):
            raise RigError(sup.tripped)
        stage.move_to(x)


# ---------------------------------------------------------------------- the command delay
def _model_step(step: float, limits, lag: float, planner: bool, dt: float = 1e-4, span: float = 0.1) -> np.ndarray:
    """The stage's modelled response to a step of ``step`` m at t = 0, every ``dt`` s for ``span`` s."""
    from tactile_mirror.loop.stage import SimulatedStage, StageLimits

    n = round(span / dt)
    if not planner:
        t = np.arange(1, n + 1) * dt
        return step * (1.0 - np.exp(-t / lag)) if lag > 0 else np.full(n, step)
    big = abs(step) * 10 + 1.0
    st = SimulatedStage(StageLimits(-big, big, limits.v_max, limits.a_max), lag=lag)
    st.move_to(step)
    return np.array([st.advance(dt) for _ in range(n)])


def fit_delay(t, x, step: float, limits, lag: float, planner: bool = True, max_delay: float = 0.05) -> float:
    """The dead time (s) that best matches a measured step response to the stage's model.

    ``t`` (s since the command was sent, the readings' own times) and ``x`` (m, from the
    position before the step) are the readings; the model is a planning stage (``a_max``,
    ``v_max`` of ``limits``) behind a servo lag ``lag`` (``planner=False``: the lag alone).
    The delay is the shift of the model, in 0.1 ms steps up to ``max_delay``, with the least
    squared error."""
    t = np.asarray(t, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    dt = 1e-4
    model = np.concatenate([[0.0], _model_step(step, limits, lag, planner, dt, t.max() + 0.01 if t.size else 0.1)])
    best, best_d = math.inf, 0.0
    for d in np.arange(0.0, max_delay + dt / 2, dt):
        k = np.clip(np.round((t - d) / dt).astype(int), 0, model.size - 1)
        m = np.where(t - d > 0, model[k], 0.0)
        err = float(np.sum((x - m) ** 2))
        if err < best:
            best, best_d = err, float(d)
    return best_d


def _measure_delay(drain, stage, sup, config, log) -> list[float]:
    b, lim = config.bringup, config.limits
    step, lag, planner = b["delay_step"], config.stage["lag"], config.loop["planner"]
    per_tick = getattr(stage, "command_mode", "per_tick") == "per_tick"
    out = []
    for i in range(b["delay_steps"]):
        for sign in (1.0, -1.0):
            _hold(drain, stage, sup, 0.08)
            x0 = stage.position()
            target = x0 + sign * step
            if sup.check_target(target):
                raise RigError(sup.tripped)
            t_cmd = time.monotonic_ns()
            stage.move_to(target)
            ts, xs = [], []
            next_send = time.monotonic() + config.block_period
            while time.monotonic_ns() - t_cmd < 80e6:
                drain()
                p = stage.position()
                if sup.check_stage(p):
                    raise RigError(sup.tripped)
                age = stage.position_age() if hasattr(stage, "position_age") else 0.0
                ts.append((time.monotonic_ns() - t_cmd) / 1e9 - age)
                xs.append(sign * (p - x0))
                if per_tick and time.monotonic() >= next_send:   # a stage commanded every tick hears it again
                    stage.move_to(target)
                    next_send += config.block_period
                time.sleep(2e-4)
            out.append(fit_delay(ts, xs, step, lim, lag, planner))
    log(f"command delay: {', '.join(f'{1e3 * d:.1f}' for d in out)} ms (steps of {step * 1e6:g} um)")
    return out


def _measure_phase(drain, stage, sup, config, log) -> dict:
    """The loop's delay: a sine commanded once per block, from each block's last sample time,
    and its phase lag in the stage's position readings (at their own times)."""
    b, lim = config.bringup, config.limits
    f0 = b["phase_frequency"]
    w = 2 * math.pi * f0
    amp = min(b["phase_amplitude"], 0.25 * lim.a_max / (w * w))   # (a quarter of a_max at most)
    decel = lim.a_max if config.loop["planner"] else 0.0
    x0 = stage.position()
    t_first = None
    rows = []   # (command time, command, reading time, reading)
    waited_since = time.monotonic()
    while True:
        block = drain(wait=0.05)
        if block is None:   # (an acquisition that stopped sending is the supervisor's timeout)
            if sup.check_timeout(time.monotonic() - waited_since):
                raise RigError(sup.tripped)
            continue
        waited_since = time.monotonic()
        t = block.t_ns / 1e9
        if t_first is None:
            t_first = t
        tt = t - t_first
        if tt > b["phase_duration"]:
            break
        v = amp * w * math.cos(w * tt)
        x = amp * math.sin(w * tt)
        target = x0 + x + (v * abs(v) / (2 * decel) if decel > 0 else 0.0)   # (the law's braking lead)
        if sup.check_target(target):
            raise RigError(sup.tripped)
        stage.move_to(target)
        p = stage.position()
        if sup.check_stage(p):
            raise RigError(sup.tripped)
        age = stage.position_age() if hasattr(stage, "position_age") else 0.0
        rows.append((tt, x, time.monotonic() - age - t_first, p - x0))
    r = np.array(rows)
    keep = r[:, 0] >= min(0.25, 0.3 * b["phase_duration"])   # (past the start's transient)
    out = sine_phase(r[keep, 0], r[keep, 1], r[keep, 2], r[keep, 3], f0, config.stage["lag"])
    out["amplitude_m"] = amp
    log(f"loop delay: {out['loop_delay_ms']:.2f} ms (a {amp * 1e6:.3g} um sine at {f0:g} Hz: phase lag "
        f"{out['phase_lag_deg']:.1f} deg, gain {out['gain']:.2f})")
    return out


def sine_phase(t_cmd, x_cmd, t_pos, x_pos, frequency: float, lag: float) -> dict:
    """Phase lag and gain of the readings ``x_pos`` (at times ``t_pos``, s) behind the commanded
    sine ``x_cmd`` (at ``t_cmd``) at ``frequency`` (Hz), each fitted by least squares with a
    constant; and the dead time that lag means once a servo lag ``lag`` (s) is taken out:
    ``loop_delay_ms = (phase - atan(w lag)) / w``, 0 at least (the phase read in [-90, 270) deg)."""
    w = 2 * math.pi * frequency

    def fit(t, y):
        t, y = np.asarray(t, dtype=np.float64), np.asarray(y, dtype=np.float64)
        a = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
        (s_, c_, _), *_ = np.linalg.lstsq(a, y, rcond=None)
        return math.atan2(c_, s_), math.hypot(s_, c_)

    pc, ac = fit(t_cmd, x_cmd)
    pp, ap = fit(t_pos, x_pos)
    # (read in [-90, 270) deg: a reading a hair ahead is 0, not a period behind; 270 deg at 20 Hz
    # is a 37 ms delay, far beyond any loop's)
    lag_phase = (pc - pp + math.pi / 2) % (2 * math.pi) - math.pi / 2
    delay = max((lag_phase - math.atan(w * lag)) / w, 0.0)
    return {"frequency_hz": float(frequency), "phase_lag_deg": math.degrees(lag_phase),
            "gain": ap / ac if ac > 0 else math.nan, "loop_delay_ms": 1e3 * delay}


# ---------------------------------------------------------------------- pipelines
def build_pipeline(config, detector, controller=None, shear_weights=None, force_input: bool = False):
    """The rig's pipeline: the configured estimator on the front end's circuit (its notch),
    ``detector``, ``controller`` (None: detection only)."""
    from tactile_mirror.estimator import StressRateEstimator
    from tactile_mirror.pipeline import MirrorPipeline
    from tactile_mirror.pipeline.controller import NoController

    lp, R = config.loop, config.n_ridges
    est = StressRateEstimator(config.circuit(), config.fs, 2 * R, order=lp["estimator_order"],
                              bandwidth=lp["estimator_bandwidth"], notch=list(lp["notch"]) or None)
    return MirrorPipeline(detector, config.fs, R, estimator=est, controller=controller or NoController(),
                          activation="fast", max_hold_ticks=lp["max_hold_ticks"], shear_weights=shear_weights,
                          force_input=force_input)


def _noise(res: RigResult, R: int) -> dict:
    s, aux = res.samples, res.aux
    out = {"v_out_rms_V": float(np.sqrt(np.mean(np.var(s[:, :2 * R], axis=0)))) if s.size else math.nan,
           "u_out_rms_V": float(np.sqrt(np.mean(np.var(s[:, 2 * R:4 * R], axis=0)))) if s.size else math.nan,
           "nonfinite": int(np.count_nonzero(~np.isfinite(s)))}
    for j, name in enumerate(res.aux_names):
        out[f"{name}_rms_N"] = float(np.std(aux[:, j])) if aux.size else math.nan
        out[f"{name}_offset_N"] = float(np.mean(aux[:, j])) if aux.size else math.nan
    lat = (res.block_read_ns - res.block_t_ns) / 1e6
    out["block_read_latency_ms"] = {"p50": float(np.median(lat)) if lat.size else math.nan,
                                    "max": float(lat.max()) if lat.size else math.nan}
    return out


# ---------------------------------------------------------------------- the calibration move
def _calibration_moves(stage, sup, source, config, probe, path, settle, total, cols, out, x_start) -> None:
    """The calibration's moves, a target per block, and what it records (``out``: the lists of
    the features, the force, the samples' times, the readings' times and positions)."""
    feats, force, t_s, tx, xx = out
    R, fs = config.n_ridges, config.fs
    ticks = 0
    while ticks < total:
        try:
            block = source.read_block(sup.comm_timeout)
        except TimeoutError:
            sup.check_timeout(sup.comm_timeout)
            raise RigError(sup.tripped) from None
        if sup.check_block(block, time.monotonic_ns()):
            raise RigError(sup.tripped)
        p = stage.position()
        if sup.check_stage(p):
            raise RigError(sup.tripped)
        age = stage.position_age() if hasattr(stage, "position_age") else 0.0
        tx.append(time.monotonic_ns() - round(age * 1e9))
        xx.append(p)
        x = np.ascontiguousarray(block.samples[:, cols])
        feats.append(probe.process_block(x, features=True)[1])
        force.append(block.samples[:, 4 * R].copy())
        t_s.append(block.t_ns - np.round((np.arange(x.shape[0])[::-1]) * 1e9 / fs).astype(np.int64))
        ticks += x.shape[0]
        k = min(max(ticks - settle, 0), path.size - 1)
        target = x_start + float(path[k])
        if sup.check_target(target):
            raise RigError(sup.tripped)
        stage.move_to(target)


def _calibrate(drain, stage, sup, source, config, detector, log) -> dict:
    from tactile_mirror.loop.calibration import fit_shear_scale, fit_shear_weights, triangle_path

    b, R, fs = config.bringup, config.n_ridges, config.fs
    probe = build_pipeline(config, detector)
    one = triangle_path(b["calibration_amplitudes"], b["calibration_speed"] / fs)
    path = np.concatenate([one] + [one[1:]] * (b["calibration_cycles"] - 1))
    settle = round(0.3 * fs)
    x_start = stage.position()
    total = settle + path.size + round(0.2 * fs)
    cols = list(range(4 * R))
    feats, force, t_s, tx, xx = [], [], [], [], []
    probe.reset(0.0)
    drain()
    with raised_priority(rt_priority=config.loop["rt_priority"]):
        _calibration_moves(stage, sup, source, config, probe, path, settle, total, cols, (feats, force, t_s, tx, xx),
                           x_start)
    feats = np.concatenate(feats).reshape(-1, R, 4)
    force = np.concatenate(force)
    t_s = np.concatenate(t_s).astype(np.float64)
    pad = np.interp(t_s, np.asarray(tx, dtype=np.float64), np.asarray(xx))
    e = -(pad - pad[settle])                       # the finger rests: finger - pad
    band = b["calibration_band"]
    w = fit_shear_weights(feats, e, fs, start=settle, band=band, symmetric=b["symmetric"])
    sig = np.cumsum((feats[:, :, 0] * w[:, 0] + feats[:, :, 1] * w[:, 1]).sum(axis=1)) / fs
    sign, per_m = fit_shear_scale(sig[settle:], e[settle:], band=band, fs=fs)
    fsign, n_per_m = fit_shear_scale(force[settle:], e[settle:], band=band, fs=fs)

    def r2(y, k):   # of the fit, in the fit's band
        from tactile_mirror.loop.calibration import band_pass

        y, d = band_pass(y, band, fs)[settle:], band_pass(e, band, fs)[settle:]
        y, d = y - y[0], d - d[0]
        return float(1.0 - np.sum((y - k * d) ** 2) / max(np.sum(y * y), 1e-300))

    cal = {"shear_weights": w, "direction_sign": sign, "asym_per_m": per_m, "force_sign": fsign,
           "force_n_per_m": n_per_m, "shear_r2": r2(sig, sign * per_m), "force_r2": r2(force, fsign * n_per_m),
           "travel_m": float(np.ptp(e[settle:]))}
    log(f"calibration: shear signal {per_m:.4g} per m (sign {sign:+g}, r^2 {cal['shear_r2']:.3f}), force "
        f"{n_per_m / 1e3:.4g} N/mm (sign {fsign:+g}, r^2 {cal['force_r2']:.3f}), over {cal['travel_m'] * 1e6:.0f} um")
    return cal


# ---------------------------------------------------------------------- bring-up
def bring_up(session, supervisor: Supervisor, detector, log=print) -> BringUpResult:
    """Bring the rig of ``session`` (:class:`~tactile_mirror.rig.session.RigSession`, open) up
    to a designed law (see the module notes), watched by ``supervisor``; ``detector`` is the
    pipeline's slip detector. Raises :class:`~tactile_mirror.rig.supervisor.RigError` (the
    stage stopped) at a fault."""
    from tactile_mirror.loop.design import design_loop

    config, source, sup = session.config, session.source, supervisor
    stage = _Paced(session.stage, config.command_interval)
    steps = {}
    t = time.monotonic()
    session.start_acquisition()
    drain = _Drain(source, sup)
    drain(wait=0.2)
    homed = False
    for name in ("enable", "home"):
        fn = getattr(stage, name, None)
        if fn is not None and (name == "enable" or config.stage["home"]):
            fn()
            homed = homed or name == "home"
            drain()
    session.start_stage()
    _hold(drain, stage, sup, 0.05)
    steps["enable_home_s"] = time.monotonic() - t
    # the slow move to the start
    t = time.monotonic()
    p0, start, v = stage.position(), config.stage["start"], config.stage["approach_speed"]
    dist = start - p0
    settle = {"since": None}

    def approach(dt, p):
        if dt * v < abs(dist):
            return p0 + math.copysign(dt * v, dist)
        if abs(p - start) < 2e-6 or dt * v > abs(dist) + v * 1.0:
            settle["since"] = settle["since"] or time.monotonic()
            if time.monotonic() - settle["since"] > 0.05:
                return None
        return start

    _move(drain, stage, sup, approach)
    log(f"stage: at the start {start * 1e3:.3f} mm (from {p0 * 1e3:.3f} mm, {time.monotonic() - t:.1f} s)")
    steps["approach_s"] = time.monotonic() - t
    t = time.monotonic()
    rt = config.loop["rt_priority"]   # (real time for the steps that wait on the rig, not for those that compute)
    with gc_paused(), raised_priority(rt_priority=rt):
        delays = _measure_delay(drain, stage, sup, config, log)
        _move(drain, stage, sup, lambda dt, p: start if dt < 0.1 else None)
        phase = _measure_phase(drain, stage, sup, config, log)
    _move(drain, stage, sup, lambda dt, p: start if dt < 0.1 else None)
    steps["delay_s"] = time.monotonic() - t
    t = time.monotonic()
    session.place_finger(log)
    _hold(drain, stage, sup, 0.1)
    steps["amplifier_reset"] = session.reset_amplifiers(log)
    _hold(drain, stage, sup, config.amplifier_reset["settle"])
    steps["reset_s"] = time.monotonic() - t
    # the sensors-only run: the stage is never commanded
    t = time.monotonic()
    R = config.n_ridges
    runner = RigRunner(build_pipeline(config, detector), session.stage, source, sup, columns=list(range(4 * R)),
                       aux_columns=(4 * R, 4 * R + 1), aux_names=("force_y", "force_z"), command=False,
                       rt_priority=rt)
    sensors = runner.run(config.bringup["sensors_only"], x0=stage.position())
    noise = _noise(sensors, R)
    log(f"sensors only ({sensors.n_ticks} samples, stage never commanded): v_out {noise['v_out_rms_V'] * 1e3:.3g} mV "
        f"rms, u_out {noise['u_out_rms_V'] * 1e3:.3g} mV rms, force_y {noise.get('force_y_rms_N', math.nan) * 1e3:.3g}"
        f" mN rms; lost samples {sensors.lost_samples}")
    steps["sensors_only_s"] = time.monotonic() - t
    t = time.monotonic()
    with gc_paused():
        cal = _calibrate(drain, stage, sup, source, config, detector, log)   # (real time inside, for its moves)
    _move(drain, stage, sup, lambda dt, p: start if dt < 0.1 else None)
    steps["calibration_s"] = time.monotonic() - t
    # the law, from the rig's numbers; the acquisition is drained while it is designed
    t = time.monotonic()
    delay = float(np.median(delays))
    t_cmd = max(config.block_period, config.command_interval, float(getattr(stage, "command_interval", 0.0) or 0.0))
    host = noise["block_read_latency_ms"]["p50"] / 1e3
    steps_estimate = delay + max(t_cmd - 1.0 / config.fs, 0.0) / 2 + (host if math.isfinite(host) else 0.0)
    phase["steps_estimate_ms"] = 1e3 * steps_estimate
    # the sine measured the loop's whole delay; the design adds one tick of its own
    stage_delay = max(phase["loop_delay_ms"] / 1e3 - 1.0 / config.fs, 0.0)
    lp = config.loop
    kw = {"stage_delay": stage_delay, "stage_lag": config.stage["lag"], "estimator_order": lp["estimator_order"],
          "estimator_bandwidth": lp["estimator_bandwidth"], "arm_delay": lp["arm_delay"],
          "phase_margin": lp["phase_margin"], "gain_margin": lp["gain_margin"],
          "max_sensitivity": lp["max_sensitivity"], "planner": lp["planner"], "max_error": lp["max_error"]}
    background = _Background(drain)
    background.start()
    try:
        if lp["sensor"] == "force":
            design = design_loop(config.limits, (cal["force_sign"], cal["force_n_per_m"]), config.fs, sensor="force",
                                 **kw)
        else:
            design = design_loop(config.limits, (cal["direction_sign"], cal["asym_per_m"]), config.fs,
                                 shear_weights=cal["shear_weights"], **kw)
        pipeline = build_pipeline(config, detector, design.controller,
                                  shear_weights=None if design.sensor == "force" else design.shear_weights,
                                  force_input=design.sensor == "force")
    finally:
        background.stop()
    steps["design_s"] = time.monotonic() - t
    log(f"law ({design.sensor}): stage delay {stage_delay * 1e3:.2f} ms (the steps' estimate {steps_estimate * 1e3:.2f} "
        f"ms), crossover "
        f"{design.crossover_hz:.1f} Hz, phase margin {design.phase_margin_deg:.1f} deg, gain margin "
        f"{design.gain_margin_db:.1f} dB")
    return BringUpResult(start=start, command_delay=delay, delay_steps=delays, stage_delay=stage_delay, noise=noise,
                         calibration=cal, design=design, pipeline=pipeline, sensors_only=sensors, steps=steps,
                         phase=phase)
