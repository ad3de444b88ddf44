"""The default closed-loop law, designed from the stage's data sheet, the shear calibration and the sample rate.

Nothing here reads a finger path. :func:`design_loop` takes

* the stage's limits (travel, speed, acceleration: :class:`~tactile_mirror.loop.stage.StageLimits`),
  its command dead time and its servo lag (s);
* the shear calibration of the pad (:func:`tactile_mirror.lab.loop.experiment.calibrate_shear`):
  ``direction_sign`` and the L/R asymmetry per metre of finger-pad displacement ``k_a``;
* the sample rate and the pipeline's stress-rate estimator (its order and bandwidth);

and returns a :class:`LoopDesign`: the :class:`~tactile_mirror.pipeline.controller.VelocityController`
with its gains, the loop transfer function, crossover, margins, and the tracking error
it predicts for any finger motion.

The loop
    While the contact sticks, the asymmetry integrator holds ``a = k_a * e_m``, the
    measured finger-pad relative displacement ``e = x_finger - x_pad`` through the
    estimator, and its input ``sum_r (rate_L - rate_R) = k_a * de_m/dt`` is the relative
    *velocity* (``v_out`` is a stress rate). The velocity law commands (in metres,
    gains ``Kp = shear_gain * k_a``, ``z = shear_integral``, ``Kv = rate_gain * k_a``)::

        v = Kp e_m + w + Kv de_m/dt,      dw/dt = Kp z e_m

    integrated into the position target that the stage follows after its dead time
    and lag. With ``M`` the estimator (circuit, equaliser low-pass, Euler integrator),
    ``G`` the stage (``exp(-s (delay + dt)) / (1 + s lag)``; one extra tick: the
    command reaches the stage the tick after the sample), the loop from the finger to
    the relative displacement is ``e = S x_finger`` with::

        L(s) = [Kp M(s) (1 + z / s) + Kv s M(s)] G(s) / s,     S = 1 / (1 + L)

    Two integrators (the stage integrates the speed command; ``w`` integrates the
    displacement): a *type-2* loop in the finger's band. A finger accelerating at ``A``
    leaves ``e = A / (Kp z)``; a type-1 loop (``z = 0``, the previous law) leaves
    ``v / Kp``, which grows with finger speed while the contact carries only a fraction
    of a millimetre (0.18 mm at mu 0.76, 0.074 mm at sweat's 0.45) before gross slip. Below the shear
    leak's corner ``1 / (2 pi asym_tau)`` (0.16 Hz) the loop is type 1 with the velocity
    constant ``Kp z asym_tau`` (11 900 1/s in the nominal design: 1.7 um at 20 mm/s).

Gains
    The delays (stage dead time, servo lag, estimator group delay, one tick) fix the
    crossover. For each ``Kv`` of a grid and each integral ratio ``z / Kp`` of a grid,
    the largest ``Kp`` keeping phase margin >= ``phase_margin`` (45 deg), gain margin
    >= ``gain_margin`` (6 dB) and the sensitivity peak ``max |S|`` <= ``max_sensitivity``
    (2, i.e. 6 dB) is found; the design keeps the triple with the largest acceleration
    constant ``Kp z``. These robustness targets are the only choices, and they are
    textbook values, not fitted to any finger path.

The stage's planner
    A stage whose move command plans a braking move to each target (a point-to-point
    trajectory generator: :class:`~tactile_mirror.loop.stage.SimulatedStage`, and the move
    commands of most stage controllers) is not the data sheet's dead time and lag when it
    is sent a new target every tick: its set point moves at the speed that still stops on
    the target, so it trails a moving target by ``v^2 / (2 a_max)`` (0.2 mm at 20 mm/s and
    1 m/s^2, more than the contact carries) with a small-signal lag of time constant
    ``|v| / a_max`` (20 ms at 20 mm/s: measured on the simulated stage, 55 degrees more
    phase at 25 Hz than delay and lag, which leaves the loop no phase margin). The law
    therefore leads its command by that braking distance (``planner_decel = a_max``,
    :meth:`~tactile_mirror.pipeline.controller.Controller.command`), which makes the planned set
    point move at the law's speed; then ``G`` above holds at every speed. A stage that follows
    streamed set points (``planner=False``) gets the law's position itself.

Limits and partial slip
    ``v_max``, ``a_max`` and the travel are the stage's own (the law never asks for
    more than the stage can do, and stops before a travel limit). The slip guard
    (``slip_hold``) holds the loop for a few closed-loop time constants after the
    detector reports gross slip (the L/R asymmetry no longer measures the relative
    displacement while the ridges' edges slide: it answers with the wrong sign); during
    the hold the stage decelerates at ``a_max`` with ``w`` cleared, then the shear is
    re-tared and the loop starts again from the re-stuck contact. The strips' law only: a
    load cell's force keeps its sign while the contact slides and needs no re-tare, and a
    re-tare there made the sliding friction the loop's reference (``design_loop``).

What the design cannot hold: a change of friction under load (sweat)
    The shear signal is the strips' stress, calibrated as a displacement in full stick.
    When friction falls, the tractions left at the ridges' edges relax by partial slip and
    the signal moves with no relative motion at all: -69 to -176 um and +137 um at mu 0.45
    (up to -390 um at 0.40) with finger and pad still, as much as the contact carries before
    gross slip (``bench/loop_sweat_sensing.py``). A still finger's contact holds through
    the drop open loop; this law follows the phantom into gross slip. Holding through a
    friction change needs a measurement that tells it from a displacement (a force sensor
    under the pad, the finger's position) or an observer of the partial slip.
A load cell under the pad (``sensor="force"``)
    The pad's total tangential force has no such phantom: the released tractions balance
    inside the contact, and its sensitivity to a displacement stays within 0.94-1.00 of the
    stuck stiffness through the same drops (``bench/loop_sweat_sensing.py --step-probe``).
    ``MirrorPipeline(force_input=True)`` closes the loop on it (the force's change per tick
    is the rate: a backward difference, half a tick of delay instead of the estimator's
    group delay), with gains from the same rules; on the envelope's paths it makes no gross
    slip under sweat (``docs/loop.md``).

The numbers of the nominal design (FEM pad, 1 kHz, 2nd-order 100 Hz estimator, stage
1 ms dead time, 2 ms lag) are given by :meth:`LoopDesign.summary`; the README and
``docs/figures/loop_design.png`` show them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tactile_mirror.checks import real_number
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import equalizer_sos
from tactile_mirror.loop.stage import StageLimits
from tactile_mirror.pipeline.controller import VelocityController

__all__ = ["LoopDesign", "design_loop", "loop_response"]


def _positive(value, name: str, allow_zero: bool = False) -> float:
    return real_number(value, name, positive=not allow_zero, nonnegative=allow_zero)


def loop_response(f, kp: float, z: float, kv: float, fs: float, delay: float, lag: float,
                  estimator_order: int = 2, estimator_bandwidth: float = 100.0, asym_tau: float = 20.0,
                  circuit: PVDFCircuit | None = None, sensor: str = "strips") -> np.ndarray:
    """Open-loop frequency response ``L(j 2 pi f)`` of the shear loop (see the module docstring).

    Parameters
    ----------
    f : array_like
        Frequencies, Hz (> 0, below ``fs / 2``).
    kp, z, kv : float
        Proportional gain (1/s), integral corner (1/s) and relative-velocity gain (-), in metres.
    fs : float
        Tick rate, Hz.
    delay, lag : float
        Stage dead time and servo time constant, s.
    estimator_order, estimator_bandwidth : int, float
        The pipeline's stress-rate estimator (:class:`~tactile_mirror.estimator.StressRateEstimator`).
    asym_tau : float
        Leak of the asymmetry integrator, s.
    sensor : {"strips", "force"}
        What the shear signal is made of: the strips' stress rates through the circuit and
        the estimator (default), or a load cell's force, whose change per tick (a backward
        difference, ``(1 - z^-1) fs``) is the rate; the estimator's settings then play no part.

    Returns
    -------
    ndarray of complex
    """
    import scipy.signal

    f = np.asarray(f, dtype=np.float64)
    circuit = circuit or PVDFCircuit()
    dt = 1.0 / fs
    w = 2 * np.pi * f
    zz = np.exp(1j * w * dt)
    if sensor == "force":
        rate = (1.0 - 1.0 / zz) * fs               # the force's change per tick, ~ j w at low f
    elif sensor == "strips":
        # stress -> v_out (analog circuit) -> rate (equaliser): k_a de/dt through the low-pass
        sos = equalizer_sos(circuit, fs, "v", estimator_order, estimator_bandwidth)
        _, eq = scipy.signal.sosfreqz(sos, worN=f, fs=fs)
        rate = circuit.response(f, "v") * eq          # rate per unit stress, ~ j w at low f
    else:
        raise ValueError(f"sensor must be 'strips' or 'force', got {sensor!r}")
    leak = math.exp(-dt / asym_tau)
    m = rate * dt * zz / (zz - leak)               # a / k_a per unit e
    integ = dt * zz / (zz - 1.0)                   # Euler integrator (w, and the position target)
    c = kp * m * (1.0 + z * integ) + kv * rate
    g = np.exp(-1j * w * (delay + dt)) / (1.0 + 1j * w * lag)
    return c * integ * g


def _margins(f, L):
    """Crossover (Hz), phase margin (deg), gain margin (dB) and max |S| of a loop response."""
    mag = np.abs(L)
    ph = np.unwrap(np.angle(L))
    above = np.flatnonzero(mag >= 1.0)
    if above.size == 0 or above[-1] + 1 >= f.size:
        return math.nan, -math.inf, -math.inf, math.inf
    i = above[-1]
    # interpolate the last crossing of |L| = 1 (log scale)
    t = math.log(mag[i]) / (math.log(mag[i]) - math.log(mag[i + 1]))
    fc = math.exp(math.log(f[i]) + t * (math.log(f[i + 1]) - math.log(f[i])))
    pc = ph[i] + t * (ph[i + 1] - ph[i])
    pm = math.degrees(pc) + 180.0
    # gain margin: |L| where the phase crosses -180 deg beyond the crossover
    k = np.flatnonzero((ph[:-1] > -np.pi) & (ph[1:] <= -np.pi))
    k = k[f[k] >= fc * 0.999]
    gm = math.inf if k.size == 0 else -20 * math.log10(max(mag[k[0]], 1e-300))
    ms = float(np.max(1.0 / np.abs(1.0 + L)))
    return fc, pm, gm, ms


@dataclass(frozen=True)
class LoopDesign:
    """A designed shear loop: the controller, its gains in metres and its predicted behaviour.

    Attributes
    ----------
    controller : VelocityController
        The law, ready for :class:`tactile_mirror.MirrorPipeline`.
    kp, z, kv : float
        Proportional gain (1/s), integral corner (1/s), relative-velocity gain (-).
    crossover_hz, phase_margin_deg, gain_margin_db, max_sensitivity : float
        Of :meth:`loop`.
    delays : dict
        The delays of the loop, s: stage dead time, one tick of command transport, servo
        lag, estimator group delay (at 1 Hz) and their sum.
    fs, stage_delay, stage_lag, estimator_order, estimator_bandwidth, asym_per_m : float
        What it was designed from.
    sensor : str
        ``"strips"`` or ``"force"`` (a load cell): what the shear signal is made of.
    """

    controller: VelocityController
    kp: float
    z: float
    kv: float
    crossover_hz: float
    phase_margin_deg: float
    gain_margin_db: float
    max_sensitivity: float
    delays: dict
    fs: float
    stage_delay: float
    stage_lag: float
    estimator_order: int
    estimator_bandwidth: float
    asym_per_m: float
    limits: StageLimits = field(repr=False, default=StageLimits(-0.02, 0.02, 0.03, 1.0))
    shear_weights: np.ndarray | None = field(repr=False, compare=False, default=None)
    sensor: str = "strips"

    def pipeline_kwargs(self) -> dict:
        """What :class:`~tactile_mirror.MirrorPipeline` takes from the design:
        ``controller``, ``shear_weights`` and ``force_input`` (the signal the gains were designed on)."""
        return {"controller": self.controller, "shear_weights": self.shear_weights,
                "force_input": self.sensor == "force"}

    @property
    def acceleration_constant(self) -> float:
        """``Kp z``, 1/s^2: a finger accelerating at ``A`` leaves ``A / (Kp z)`` of error."""
        return self.kp * self.z

    def loop(self, f) -> np.ndarray:
        """``L(j 2 pi f)`` (see :func:`loop_response`)."""
        return loop_response(f, self.kp, self.z, self.kv, self.fs, self.stage_delay, self.stage_lag,
                             self.estimator_order, self.estimator_bandwidth, self.controller.asym_tau,
                             sensor=self.sensor)

    def sensitivity(self, f) -> np.ndarray:
        """``S = 1 / (1 + L)``: relative displacement per unit of finger motion."""
        return 1.0 / (1.0 + self.loop(f))

    def predict_error(self, finger, fs: float | None = None) -> np.ndarray:
        """Relative displacement ``e = S x_finger`` the linear loop predicts for a finger path, m.

        The path (m, at ``fs``, default the design's rate) is taken as starting at rest
        with the loop settled; computed in the frequency domain (zero-padded FFT).
        """
        fs = self.fs if fs is None else float(fs)
        x = np.asarray(finger, dtype=np.float64)
        if x.ndim != 1 or x.size < 2:
            raise ValueError(f"finger must be a 1-D path of at least 2 samples, got shape {x.shape}")
        n = 1 << math.ceil(math.log2(2 * x.size))
        pad = np.concatenate([x, np.full(n - x.size, x[-1])])
        # remove the end step of the padding: fade it back to the start over the padding
        tail = n - x.size
        pad[x.size:] = x[-1] + (x[0] - x[-1]) * (0.5 - 0.5 * np.cos(np.pi * np.arange(tail) / max(tail - 1, 1)))
        X = np.fft.rfft(pad)
        f = np.fft.rfftfreq(n, 1.0 / fs)
        S = np.ones(f.size, dtype=complex)
        S[1:] = self.sensitivity(f[1:])
        S[0] = 0.0  # type 2: no error at DC
        return np.fft.irfft(S * X, n)[: x.size]

    def sine_error(self, speed: float, acceleration: float) -> float:
        """Peak relative displacement, m, for a sinusoidal finger of peak ``speed`` (m/s)
        and peak ``acceleration`` (m/s^2): frequency ``A / (2 pi v)``, amplitude ``v^2 / A``."""
        w = acceleration / speed
        amp = speed * speed / acceleration
        return float(abs(self.sensitivity(np.array([w / (2 * np.pi)]))[0]) * amp)

    def error_table(self, speeds=(0.002, 0.005, 0.01, 0.02), accelerations=(0.05, 0.1, 0.25, 0.5)) -> dict:
        """Peak tracking error (mm) for sinusoidal finger motions of the given peak speeds (m/s)
        and accelerations (m/s^2): ``{(v, A): mm}``."""
        return {(v, a): 1e3 * self.sine_error(v, a) for v in speeds for a in accelerations}

    def summary(self) -> dict:
        """The design's numbers (JSON-friendly)."""
        return {"kp_per_s": self.kp, "integral_per_s": self.z, "kv": self.kv,
                "acceleration_constant_per_s2": self.acceleration_constant,
                "crossover_hz": self.crossover_hz, "phase_margin_deg": self.phase_margin_deg,
                "gain_margin_db": self.gain_margin_db, "max_sensitivity": self.max_sensitivity,
                "delays_s": dict(self.delays), "fs": self.fs, "asym_per_m": self.asym_per_m,
                "shear_gain": self.controller.shear_gain, "shear_integral": self.controller.shear_integral,
                "rate_gain": self.controller.rate_gain, "slip_hold_s": self.controller.slip_hold,
                "slip_confirm_s": self.controller.slip_confirm, "slip_min_asym": self.controller.slip_min_asym,
                "v_max": self.controller.v_max, "a_max": self.controller.a_max,
                "planner_decel": self.controller.planner_decel,
                "shear_weights": None if self.shear_weights is None else self.shear_weights.tolist(),
                "sensor": self.sensor,
                "error_mm_peak_sine": {f"{v * 1e3:g} mm/s, {a:g} m/s^2": e for (v, a), e in self.error_table().items()}}


#: Relative displacement (m) below which a detected slip does not start the slip guard: a
#: contact carrying so little shear cannot slip (the FEM pad slips at 0.065 mm at mu 0.40 and
#: 0.18 mm at 0.76), so a report there is one of the detector's false alarms at the fastest
#: changes of the shear, and stopping the stage would itself make the slip. Chosen on the
#: tuning paths among 0, 0.02 and 0.04 mm (gross slips: tuning-fast2 at 20 mm/s 125 / 122 / 102
#: on 10 paths, 1 mV noise at 20 mm/s 29 / 28 / 19, sweat mu 0.45 at 5 mm/s 6 / 6 / 6 on 5).
SLIP_MIN_SHEAR = 0.04e-3

#: ``design_loop(max_error=E)`` keeps the crossover ``w_c`` at or below ``sqrt(ACCEL_HEADROOM
#: a_max / E)``: an error oscillating at the crossover with amplitude ``E`` asks the stage for
#: about ``w_c^2 E`` of acceleration, and 1 keeps that within ``a_max``. Beyond it the slewed
#: command lags (the acceleration limit's phase lag), and after a disturbance near the
#: contact's capacity the loop settles into a limit cycle that slides the contact one way and
#: the other. Measured with ``E`` = 0.1 mm and ``a_max`` = 1 m/s^2 on the tuning runs: on the
#: simulated rig's analog path (the example configuration's finger, seed 0; the loop stalled
#: 15 ms every 2 s, ``bench/rig_stalls.py``) the cycle appeared at ``w_c^2 E / a_max`` = 1.55
#: and 2.0 (156 and 339 gross-slip events in 12 and 20 s) and not at 1.0 (0); on the FEM pad
#: with per-tick commands (force law, seeds 7001-7004, a finger jump of 0.1-0.4 mm) it
#: appeared at 4.7 and above and not at 3.4 and below.
ACCEL_HEADROOM = 1.0


def _estimator_group_delay(fs, order, bandwidth, f0=1.0):
    import scipy.signal

    sos = equalizer_sos(PVDFCircuit(), fs, "v", order, bandwidth)
    f = np.array([f0, f0 * 1.01])
    _, h = scipy.signal.sosfreqz(sos, worN=f, fs=fs)
    h = h * PVDFCircuit().response(f, "v") / (1j * 2 * np.pi * f)
    ph = np.unwrap(np.angle(h))
    return float(-(ph[1] - ph[0]) / (2 * np.pi * (f[1] - f[0])))


def design_loop(limits: StageLimits, calibration, fs: float, *, stage_delay: float, stage_lag: float,
                estimator_order: int = 2, estimator_bandwidth: float = 100.0, arm_delay: float = 0.5,
                phase_margin: float = 45.0, gain_margin: float = 6.0, max_sensitivity: float = 2.0,
                asym_tau: float = 1.0, shear_weights=None, planner: bool = True,
                sensor: str = "strips", max_error: float | None = None) -> LoopDesign:
    """Design the default shear loop from the stage's data sheet, the calibration and the rate.

    Parameters
    ----------
    limits : StageLimits
        The stage's travel (m), speed (m/s) and acceleration (m/s^2) limits.
    calibration : tuple (direction_sign, asym_per_m)
        From :func:`tactile_mirror.lab.loop.experiment.calibrate_shear`: the stage direction for
        a positive asymmetry (+1/-1) and the asymmetry per metre of relative displacement (> 0);
        with ``sensor="force"``, ``calibrate_shear(..., load_cell=True)``: the force per metre
        (the contact's tangential stiffness, N/m).
    fs : float
        Tick rate, Hz.
    stage_delay, stage_lag : float
        The stage's command dead time and servo time constant, s (>= 0).
    estimator_order, estimator_bandwidth : int, float
        The pipeline's stress-rate estimator (default: the loop's, 2nd order, 100 Hz).
    arm_delay : float
        Seconds the stage holds after a reset while the finger is placed (then the shear
        is tared), s.
    phase_margin, gain_margin, max_sensitivity : float
        Robustness targets: degrees, dB, and the bound on ``max |S|``.
    asym_tau : float
        Leak of the asymmetry integrator, s: a high-pass at ``1 / (2 pi asym_tau)`` (0.16 Hz
        by default), far below the crossover. The integral of the measured rates drifts
        (sensor noise, and the stress the ridge edges keep when they slide and re-stick);
        the leak bounds that drift. Chosen on the tuning paths (sensor noise: 20 s let the
        drift reach a gross slip, 1 s and 0.3 s did not).

    shear_weights : array_like (n_ridges, 2), optional
        The pipeline's shear signal the calibration was taken with
        (:func:`tactile_mirror.lab.loop.experiment.calibrate_shear_weights`); kept in the
        design for :meth:`LoopDesign.pipeline_kwargs`. None: the plain L - R difference.
    planner : bool
        True (default): the stage's move command plans a braking move to each target at
        ``limits.a_max`` (as :class:`~tactile_mirror.loop.stage.SimulatedStage` and most
        stage controllers' point-to-point moves), so the law leads its command by the
        braking distance (``planner_decel = limits.a_max``; see the module docstring).
        False: the stage follows the command as a streamed set point (``planner_decel = 0``).
    sensor : {"strips", "force"}
        The shear signal the pipeline gives the law: the strips' (default) or a load cell's
        force under the pad (``MirrorPipeline(force_input=True)``, :func:`loop_response`). The
        force has no estimator delay (half a tick of backward difference instead of the
        equaliser's group delay), and it holds through a friction change under load, where the
        strips do not (module docstring).
    max_error : float, optional
        The largest finger-pad displacement (m) the loop must answer without asking the
        stage for more than ``limits.a_max``: the crossover is kept at or below
        ``sqrt(ACCEL_HEADROOM * a_max / max_error)`` (see :data:`ACCEL_HEADROOM`). The contact's
        carrying capacity is the natural choice (about 0.1 mm on the FEM pad). None: no
        such bound (the margins alone).

    Returns
    -------
    LoopDesign

    Raises
    ------
    ValueError
        Naming the argument, for a bad value, or if no gain meets the margins.
    """
    if not isinstance(limits, StageLimits):
        raise TypeError(f"limits must be StageLimits, got {type(limits).__name__}")
    try:
        sign, a_per_m = calibration
    except (TypeError, ValueError):
        raise TypeError("calibration must be a pair (direction_sign, asym_per_m)") from None
    if sign not in (1, -1, 1.0, -1.0) or isinstance(sign, bool):
        raise ValueError(f"calibration direction_sign must be +1 or -1, got {sign!r}")
    a_per_m = _positive(a_per_m, "calibration asym_per_m")
    fs = _positive(fs, "fs")
    stage_delay = _positive(stage_delay, "stage_delay", allow_zero=True)
    stage_lag = _positive(stage_lag, "stage_lag", allow_zero=True)
    asym_tau = _positive(asym_tau, "asym_tau")
    for name, v in (("phase_margin", phase_margin), ("gain_margin", gain_margin)):
        _positive(v, name, allow_zero=True)
    if not max_sensitivity > 1.0:
        raise ValueError(f"max_sensitivity must be > 1, got {max_sensitivity!r}")
    if not (limits.x_min <= 0.0 <= limits.x_max):
        raise ValueError(f"limits must bracket 0 (the start position), got [{limits.x_min}, {limits.x_max}]")
    if not isinstance(planner, (bool, np.bool_)):
        raise TypeError(f"planner must be True or False, got {type(planner).__name__}")
    if sensor not in ("strips", "force"):
        raise ValueError(f"sensor must be 'strips' or 'force', got {sensor!r}")

    fc_max = math.inf
    if max_error is not None:
        max_error = _positive(max_error, "max_error")
        fc_max = math.sqrt(ACCEL_HEADROOM * limits.a_max / max_error) / (2 * math.pi)
    f = np.geomspace(0.05, 0.499 * fs, 1500)
    best = None
    for kv in (0.0, 0.1, 0.2, 0.3, 0.4, 0.5):
        for ratio in (0.1, 0.2, 0.3, 0.4, 0.5):
            lo, hi, ok = 1.0, 2000.0, None
            for _ in range(30):  # bisection on Kp (margins shrink with Kp past the optimum)
                kp = math.sqrt(lo * hi)
                L = loop_response(f, kp, ratio * kp, kv, fs, stage_delay, stage_lag, estimator_order,
                                  estimator_bandwidth, asym_tau, sensor=sensor)
                fc, pm, gm, ms = _margins(f, L)
                if pm >= phase_margin and gm >= gain_margin and ms <= max_sensitivity and fc <= fc_max:
                    lo, ok = kp, (kp, fc, pm, gm, ms)
                else:
                    hi = kp
            if ok is None:
                continue
            kp, fc, pm, gm, ms = ok
            ka = kp * ratio * kp
            if best is None or ka > best[0]:
                best = (ka, kp, ratio * kp, kv, fc, pm, gm, ms)
    if best is None:
        raise ValueError("no gain meets the margins: stage_delay and stage_lag are too long, or max_error too "
                         "large for a_max (the loop needs a crossover of at least 1 rad/s)")
    _, kp, z, kv, fc, pm, gm, ms = best
    # Slip guard: 100 ms, at least four closed-loop time constants (1 / crossover). Chosen on
    # the tuning paths (sweat mu 0.45 / 0.40 at 20 mm/s): 25 ms let the re-engaged loop act on
    # a still-sliding contact and run the stage to its travel limit, 100 ms did not.
    #
    # A load cell needs no guard (slip_hold 0): its force keeps its sign while the contact
    # slides (it is the sliding friction, pointing the way the finger slips), so the loop
    # acting on it brings the pad back under the finger; and it needs no re-tare, being
    # absolute. The guard's re-tare made the sliding friction, near the contact's limit, the
    # new reference: after a disturbance that ended in gross slip, the re-engaged loop held
    # the contact at that limit and it slid again and again (chosen on tuning seeds 7001-7006,
    # 10 and 20 mm/s, a 0.2 / 0.4 mm finger jump: 10 / 21 gross slips with the guard, 0 / 12
    # without; the tuned force left at the end, mean |F| 7.9 N against 3.3 N).
    slip_hold = 0.0 if sensor == "force" else max(0.1, round(4.0 / (2 * math.pi * fc) * fs) / fs)
    # A slip counts after 10 ms of y_slip over its threshold: chosen on the fast tuning paths
    # (20 mm/s, 4 Hz band, up to 0.46 m/s^2), where one-tick peaks of y_slip at the fastest
    # changes of the shear started the guard, and the stopped stage made 4 gross slips (none
    # with 10 ms); under sweat it did not let a slip run longer (14 slips -> 8 on 5 paths).
    slip_confirm = 0.01
    # ... and only while the shear signal is at least SLIP_MIN_SHEAR of relative displacement
    # from its tare (see the constant).
    slip_min_asym = SLIP_MIN_SHEAR * a_per_m
    ctrl = VelocityController(threshold=0.3, y_full=0.7, v_max=limits.v_max, a_max=limits.a_max,
                              x_min=limits.x_min, x_max=limits.x_max, direction_sign=float(sign),
                              asym_tau=asym_tau, asym_deadband=0.0, arm_delay=arm_delay, slip_hold=slip_hold,
                              slip_confirm=slip_confirm, slip_min_asym=slip_min_asym,
                              shear_gain=kp / a_per_m, ramp_gain=0.0, pred_boost=0.0, shear_integral=z,
                              rate_gain=kv / a_per_m, planner_decel=limits.a_max if planner else 0.0)
    gd = _estimator_group_delay(fs, estimator_order, estimator_bandwidth) if sensor == "strips" else 0.5 / fs
    delays = {"stage_dead_time": stage_delay, "command_tick": 1.0 / fs, "stage_lag": stage_lag,
              "estimator_group_delay": gd, "total": stage_delay + 1.0 / fs + stage_lag + gd}
    return LoopDesign(controller=ctrl, kp=kp, z=z, kv=kv, crossover_hz=fc, phase_margin_deg=pm,
                      gain_margin_db=gm, max_sensitivity=ms, delays=delays, fs=fs, stage_delay=stage_delay,
                      stage_lag=stage_lag, estimator_order=int(estimator_order),
                      estimator_bandwidth=float(estimator_bandwidth), asym_per_m=a_per_m, limits=limits,
                      shear_weights=None if shear_weights is None else np.array(shear_weights, dtype=np.float64),
                      sensor=sensor)
