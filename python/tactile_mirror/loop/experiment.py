"""The closed-loop experiment of the paper's section 4, in simulation.

The finger is the moving plate: a seeded, band-limited random ``y`` trajectory at
constant normal load. The pad sits on a stage; the contact model is stepped with the
relative displacement ``finger - pad`` every tick; its strip stresses go through the
PVDF circuit (streaming sections of :class:`~tactile_mirror.circuit.PVDFCircuit`,
plus sensor noise) into the pipeline, whose command drives the stage. Open loop
(Fig. 12) never commands the stage; closed loop (Fig. 13) does.

Any contact model with ``reset()`` and ``advance(dy) -> state`` plugs in (``state``
with ``stress`` (n_ridges, 2) equivalent loads in Pa [L, R], ``force_y``,
``force_z`` in N, ``slip_fraction`` (n_ridges,) in [0, 1]). :class:`BrushRidges` is
the one used here: a reduced quasi-static model, *not* the FEM of
:mod:`tactile_mirror.contact`. Each ridge is a row of surface points in series with
the finger pad's tangential compliance, each point holding traction up to
``mu p_i`` (Coulomb) and sliding beyond it. Traction concentrates at the ridge
edges (flat-punch-like stiffness) while pressure is highest at the centre, so
local slip starts at the edges and spreads inward as the tangential load grows,
and gross slip is every point sliding. The strips see the bending of the ridge
(opposite signs, L vs R) plus the traction near their own edge.

:func:`run_experiment` trains a detector on open-loop runs of the same model (so
the detector sees the signals it will meet), then runs open and closed loop over a
set of seeded trajectories and the robustness scenes (friction change, compliant
mounting, sensor noise, dropped samples), and reports gross slips and tracking
errors for the paper's law and the velocity law. ``python -m
tactile_mirror.loop.experiment --out DIR`` writes the tables and the Fig. 12/13
reproductions.
"""
from __future__ import annotations

import argparse
import json
import os
from dataclasses import dataclass, field

import numpy as np
import scipy.signal

from ..circuit import PVDFCircuit
from ..estimator import StressRateEstimator
from ..filters import SosFilter
from .controller import Controller, NoController, PaperController, VelocityController
from .runner import LoopRunner
from .stage import SimulatedStage, StageLimits

__all__ = [
    "PLANTS",
    "BrushRidges",
    "ContactState",
    "FemPad",
    "PadSource",
    "Scene",
    "calibrate_direction",
    "calibrate_shear",
    "default_weights",
    "finger_trajectory",
    "gross_slip_events",
    "make_laws",
    "make_plant",
    "open_and_closed",
    "run_experiment",
    "run_scene",
    "scene_finger",
    "train_detector_on_brush",
]


@dataclass
class ContactState:
    stress: np.ndarray          # (n_ridges, 2) equivalent load of the L, R strips, Pa
    force_y: float              # N, on the pad
    force_z: float              # N
    slip_fraction: np.ndarray   # (n_ridges,) fraction of surface points at the friction limit


class BrushRidges:
    """Reduced quasi-static contact of a finger on the ridges (see the module docstring).

    Parameters
    ----------
    n_ridges : int
    mu : float or sequence
        Friction coefficient (per ridge if a sequence).
    normal_load : float
        Normal force per ridge, N.
    k_finger : float
        Tangential stiffness of the finger pad + ridge per ridge, N/m.
    n_points : int
        Surface points per ridge.
    strip_area : float
        Strip area used to turn forces into stresses, m^2 (1 x 10 mm).
    bending, edge, normal : float
        Strip stress per unit of (tangential force, edge traction, normal force) / area.
    """

    def __init__(self, n_ridges: int = 6, mu=1.0, normal_load: float = 0.15, k_finger: float = 150.0,
                 n_points: int = 24, strip_area: float = 1e-5, bending: float = 0.6, edge: float = 0.8,
                 normal: float = 0.3):
        self.n_ridges = int(n_ridges)
        self.mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), (self.n_ridges,)).copy()
        if np.any(self.mu <= 0):
            raise ValueError("mu must be positive")
        self.P = float(normal_load)
        x = np.linspace(-1, 1, int(n_points) + 2)[1:-1]
        kw = 1.0 / np.sqrt(1.0 - x**2 + 0.02)
        self.k = k_finger * kw / kw.sum()                 # (n,) N/m per point
        pw = np.sqrt(1.0 - x**2 + 0.05)
        self.p = self.P * pw / pw.sum()                    # (n,) N per point
        self.gL = np.exp(-((x + 1.0) ** 2) / 0.15)
        self.gR = np.exp(-((x - 1.0) ** 2) / 0.15)
        self.A = float(strip_area)
        self.bending, self.edge, self.normal = float(bending), float(edge), float(normal)
        self.reset()

    def reset(self):
        self.s = np.zeros((self.n_ridges, self.k.size))   # slid offsets of the points, m

    def set_mu(self, mu):
        self.mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), (self.n_ridges,)).copy()

    def advance(self, dy: float) -> ContactState:
        """Relative displacement finger - pad (m) -> contact state."""
        lim = self.mu[:, None] * self.p[None, :]           # (R, n) N
        q = self.k[None, :] * (dy - self.s)
        over = np.abs(q) > lim
        if np.any(over):
            qs = np.sign(q) * lim
            self.s = np.where(over, dy - qs / self.k[None, :], self.s)
            q = np.where(over, qs, q)
        at_limit = np.abs(q) >= lim * (1.0 - 1e-9)
        fy = q.sum(axis=1)                                   # (R,)
        eL = q @ self.gL
        eR = q @ self.gR
        fz = self.P
        sL = (-self.bending * fy + self.edge * eL + self.normal * fz) / self.A
        sR = (self.bending * fy + self.edge * eR + self.normal * fz) / self.A
        return ContactState(stress=np.stack([sL, sR], axis=1), force_y=float(fy.sum()),
                            force_z=float(fz * self.n_ridges), slip_fraction=at_limit.mean(axis=1))


def finger_trajectory(seed, duration: float, fs: float, amplitude: float = 3e-3, bandwidth: float = 1.0,
                      v_max: float = 0.015, a_max: float = 0.3, ramp: float = 0.3) -> np.ndarray:
    """A seeded band-limited random finger path, m, starting at rest at 0.

    White noise low-passed (4th-order Butterworth at ``bandwidth`` Hz, forward-backward),
    scaled to ``amplitude`` rms, faded in over ``ramp`` s, then scaled down if needed so
    that its speed and acceleration stay within ``v_max`` and ``a_max`` (a stage with those
    limits can follow it).
    """
    rng = np.random.default_rng(seed)
    n = round(duration * fs)
    pad = int(fs * 2)
    w = rng.standard_normal(n + 2 * pad)
    sos = scipy.signal.butter(4, bandwidth, fs=fs, output="sos")
    y = scipy.signal.sosfiltfilt(sos, w)[pad:pad + n]
    y = y / np.sqrt(np.mean(y**2)) * amplitude
    t = np.arange(n) / fs
    fade = np.clip(t / ramp, 0, 1)
    fade = fade * fade * (3 - 2 * fade)
    y = (y - y[0]) * fade
    v = np.gradient(y, 1 / fs)
    a = np.gradient(v, 1 / fs)
    s = min(1.0, v_max / max(np.abs(v).max(), 1e-12), a_max / max(np.abs(a).max(), 1e-12))
    return y * s


@dataclass
class Scene:
    """One closed-loop simulation setting."""

    seed: int = 0
    duration: float = 3.0
    fs: float = 1000.0
    mu: float | None = None             # None: the plant's default (brush 1.0, fem DEFAULT_FRICTION)
    mu_change: tuple | None = None      # (time s, new mu[, ramp s]): sweat; mu ramps linearly (default 0.2 s)
    mount_stiffness: float | None = None  # N/m between stage and pad (None: rigid)
    noise: float = 0.0                   # rms sensor noise on v_out and u_out, V
    drop_rate: float = 0.0               # fraction of ticks whose samples are lost (NaN)
    stage_delay: float = 0.001
    stage_lag: float = 0.002
    label: str = "nominal"
    trajectory: dict = field(default_factory=dict)
    plant: str = "brush"                 # "brush" (BrushRidges) or "fem" (tactile_mirror.contact.Pad)
    press: float = 0.5                   # fem: the finger presses in for this long before moving, s


class FemPad:
    """The FEM pad of :mod:`tactile_mirror.contact` behind the plant interface.

    The finger first presses in (``indent`` reached at ``press_speed``, as in the paper's
    Fig. 5b), then holds that indent; :meth:`advance` takes the tangential relative
    displacement. Strip stresses become equivalent loads of the circuit
    (:meth:`PVDFCircuit.equivalent_load`).
    """

    def __init__(self, n_ridges: int = 6, mu: float | None = None, fs: float = 1000.0, indent: float = 30e-6,
                 press_speed: float = 0.06e-3, finger_radius: float = 2.0, circuit: PVDFCircuit | None = None):
        from ..contact import Pad, ridge_model
        from ..scenes import DEFAULT_FRICTION, DEFAULT_KINETIC_RATIO

        self.n_ridges = int(n_ridges)
        mu = DEFAULT_FRICTION if mu is None else float(mu)
        # static above kinetic friction, as in the scenes of tactile_mirror.scenes
        self.pad = Pad(ridge_model(), mu, n_ridges=self.n_ridges, finger_radius=finger_radius,
                       mu_kinetic=mu * DEFAULT_KINETIC_RATIO)
        self.fs, self.indent, self.press_speed = float(fs), float(indent), float(press_speed)
        self.circuit = circuit or PVDFCircuit()
        self.reset()

    def reset(self):
        self.pad.reset()
        self.k = 0

    @property
    def mu(self) -> float:
        return self.pad.mu

    def set_mu(self, mu):
        self.pad.mu = float(np.mean(mu))

    def advance(self, dy: float) -> ContactState:
        self.k += 1
        z = min(self.indent, self.k * self.press_speed / self.fs)
        st = self.pad.advance(dy, z)
        load = self.circuit.equivalent_load(st.strip_stress[..., None])[..., 0]   # (R, 2)
        return ContactState(stress=load, force_y=st.force_y, force_z=st.force_z,
                            slip_fraction=np.asarray(st.slip_fraction, dtype=np.float64))


#: Per-plant settings of the experiment: finger paths, travel, laws' scale, robustness.
PLANTS = {
    "brush": {"trajectory": {}, "mu": 1.0, "sweat": (1.5, 0.6), "mount": 2000.0, "finger_v_max": 0.015},
    "fem": {"trajectory": {"amplitude": 0.5e-3, "bandwidth": 0.5, "v_max": 2e-3, "a_max": 0.02},
            "mu": None, "sweat": (1.75, 0.45), "mount": 5e5, "finger_v_max": 2e-3},
}


def make_plant(scene: Scene, n_ridges: int = 6):
    """The contact model of a scene."""
    if scene.plant == "brush":
        mu = 1.0 if scene.mu is None else scene.mu
        return BrushRidges(n_ridges, mu=mu * (1 + 0.04 * np.linspace(-1, 1, n_ridges)))
    if scene.plant == "fem":
        return FemPad(n_ridges, mu=scene.mu, fs=scene.fs)
    raise ValueError(f"plant must be 'brush' or 'fem', got {scene.plant!r}")


def scene_finger(scene: Scene) -> np.ndarray:
    """The finger path of a scene (with the press phase at rest for the FEM pad)."""
    if scene.plant == "fem":
        n0 = round(scene.press * scene.fs)
        rest = finger_trajectory(scene.seed, scene.duration - scene.press, scene.fs, **scene.trajectory)
        return np.concatenate([np.zeros(n0), rest])
    return finger_trajectory(scene.seed, scene.duration, scene.fs, **scene.trajectory)


class PadSource:
    """Sample source for :class:`LoopRunner`: finger, contact, circuit, noise, drops."""

    def __init__(self, scene: Scene, plant: BrushRidges, circuit: PVDFCircuit, finger: np.ndarray):
        self.scene = scene
        self.plant = plant
        self.finger = finger
        R = plant.n_ridges
        self.cv = SosFilter(circuit.sos(scene.fs, "v"), 2 * R)
        self.cu = SosFilter(circuit.sos(scene.fs, "u"), 2 * R)
        self.rng = np.random.default_rng(10_000 + scene.seed)
        n = finger.size
        self.k = 0
        self.log = {"force_y": np.zeros(n), "force_z": np.zeros(n), "slip_fraction": np.zeros((R, n)),
                    "pad": np.zeros(n), "v_out": np.zeros((R, 2, n)), "u_out": np.zeros((R, 2, n))}
        self._fy = 0.0
        self._stress0 = None
        self._mu0 = None
        self._mu_done = False

    def read(self, stage_position: float, t: float):
        k = self.k
        if k >= self.finger.size:
            return None
        sc = self.scene
        if sc.mu_change is not None and t >= sc.mu_change[0]:
            # Sweat wets the contact over a fraction of a second; a step change of mu would
            # also be a step of every node's friction limit at once, which no finger shows.
            t0, mu1 = sc.mu_change[0], sc.mu_change[1]
            ramp = sc.mu_change[2] if len(sc.mu_change) > 2 else 0.2
            if self._mu0 is None:
                self._mu0 = self.plant.mu
            f = 1.0 if ramp <= 0 else min(1.0, (t - t0) / ramp)
            if f < 1.0 or not self._mu_done:
                self.plant.set_mu(self._mu0 + f * (np.asarray(mu1) - self._mu0))
                self._mu_done = f >= 1.0
        pad = stage_position
        if sc.mount_stiffness:
            pad = stage_position + self._fy / sc.mount_stiffness
        st = self.plant.advance(self.finger[k] - pad)
        self._fy = st.force_y
        load = st.stress.reshape(-1)
        if self._stress0 is None:
            self._stress0 = load.copy()  # the static normal preload is not a change of stress
        load = load - self._stress0
        v = self.cv.step(load)
        u = self.cu.step(load)
        if sc.noise > 0:
            v = v + sc.noise * self.rng.standard_normal(v.size)
            u = u + sc.noise * self.rng.standard_normal(u.size)
        lg = self.log
        lg["force_y"][k] = st.force_y
        lg["force_z"][k] = st.force_z
        lg["slip_fraction"][:, k] = st.slip_fraction
        lg["pad"][k] = pad
        lg["v_out"][:, :, k] = v.reshape(-1, 2)
        lg["u_out"][:, :, k] = u.reshape(-1, 2)
        self.k += 1
        x = np.concatenate([v, u])
        if sc.drop_rate > 0 and self.rng.random() < sc.drop_rate:
            x[:] = np.nan
        return x


def gross_slip_events(slip_fraction, level: float = 0.999, min_gap: int = 20) -> int:
    """Number of gross-slip events of the contact: every ridge grossly slipping
    (slip fraction >= ``level``); events closer than ``min_gap`` ticks are merged."""
    g = np.all(np.asarray(slip_fraction) >= level, axis=0)
    starts = np.flatnonzero(g[1:] & ~g[:-1]) + 1
    if g.size and g[0]:
        starts = np.concatenate([[0], starts])
    if starts.size == 0:
        return 0
    ends = np.flatnonzero(g[:-1] & ~g[1:]) + 1
    n = 1
    for s in starts[1:]:
        prev_end = ends[ends < s]
        if prev_end.size == 0 or s - prev_end[-1] >= min_gap:
            n += 1
    return n


@dataclass
class SceneResult:
    scene: Scene
    controller: str
    t: np.ndarray
    finger: np.ndarray
    stage: np.ndarray
    outputs: np.ndarray
    log: dict
    gross_slips: int
    ridge_gross_slips: int
    tracking_rms: float
    tracking_max: float
    status: dict
    run: object = None  # the LoopResult

    def summary(self) -> dict:
        n = self.t.size
        y = self.outputs[:, 2:].reshape(n, -1, 3)
        gross = np.all(self.log["slip_fraction"][:, :n] >= 0.999, axis=0)
        return {"label": self.scene.label, "seed": self.scene.seed, "controller": self.controller,
                "gross_slips": self.gross_slips, "ridge_gross_slips": self.ridge_gross_slips,
                "gross_slip_time_s": float(gross.sum() / self.scene.fs),
                "y_slip_max": float(y[:, :, 0].max()), "y_slip_p99": float(np.percentile(y[:, :, 0].max(axis=1), 99)),
                "tracking_rms_mm": 1e3 * self.tracking_rms, "tracking_max_mm": 1e3 * self.tracking_max,
                "rejected": int(self.status.get("rejected", 0))}


def _pipeline(weights, fs, controller, n_ridges):
    from ..pipeline import MirrorPipeline

    est = StressRateEstimator(PVDFCircuit(), fs, 2 * n_ridges, order=2, bandwidth=100.0)
    return MirrorPipeline(weights, fs, n_ridges, estimator=est, controller=controller, activation="fast",
                          max_hold_ticks=50)


def run_scene(scene: Scene, weights, controller: Controller | None, limits: StageLimits | None = None,
              n_ridges: int = 6) -> SceneResult:
    """Run one scene, open loop (``controller`` None or :class:`NoController`) or closed loop."""
    controller = controller or NoController()
    limits = limits or StageLimits(-0.02, 0.02, 0.03, 1.0)
    finger = scene_finger(scene)
    plant = make_plant(scene, n_ridges)
    source = PadSource(scene, plant, PVDFCircuit(), finger)
    stage = SimulatedStage(limits, delay=scene.stage_delay, lag=scene.stage_lag)
    pipe = _pipeline(weights, scene.fs, controller, n_ridges)
    closed = controller.kind != "none"
    res = LoopRunner(pipe, stage, source, command=closed).run(n_ticks=finger.size, x0=0.0)
    log = source.log
    rel = finger[: len(res.t)] - log["pad"][: len(res.t)]
    sf = log["slip_fraction"][:, : len(res.t)]
    ridge = sum(gross_slip_events(sf[r:r + 1]) for r in range(n_ridges))
    return SceneResult(scene=scene, controller=controller.kind, t=res.t, finger=finger[: len(res.t)],
                       stage=res.stage_position, outputs=res.outputs, log=log, gross_slips=gross_slip_events(sf),
                       ridge_gross_slips=ridge, tracking_rms=float(np.sqrt(np.mean(rel**2))),
                       tracking_max=float(np.abs(rel).max()), status=res.status, run=res)


def calibrate_shear(weights, fs: float = 1000.0, n_ridges: int = 6, plant: str = "brush"):
    """Push the finger slowly to +y (after the press for the FEM pad) and read the
    pipeline's L/R asymmetry: returns ``(direction_sign, asymmetry per metre)``, the sign
    that makes the stage move to +y and the size of the shear signal per metre of
    relative displacement (to scale ``shear_gain``)."""
    push = 20e-6 if plant == "fem" else 2e-4
    n = int(0.2 * fs)
    scene = Scene(duration=0.7 if plant == "fem" else 0.2, fs=fs, label="calibration", plant=plant)
    n0 = round(scene.press * fs) if plant == "fem" else 0
    finger = np.concatenate([np.zeros(n0), np.linspace(0, push, n)])
    source = PadSource(scene, make_plant(scene, n_ridges), PVDFCircuit(), finger)
    ctrl = PaperController(threshold=0.99, gain=0.0, asym_tau=100.0)
    pipe = _pipeline(weights, fs, ctrl, n_ridges)
    runner = LoopRunner(pipe, SimulatedStage(), source, command=False)
    if n0:
        runner.run(n_ticks=n0)
        a0 = pipe.controller_state["asymmetry"]
        runner.run(n_ticks=n, reset=False)
    else:
        a0 = 0.0
        runner.run(n_ticks=n)
    a = pipe.controller_state["asymmetry"] - a0
    return (1.0 if a > 0 else -1.0), abs(a) / push


def calibrate_direction(weights, fs: float = 1000.0, n_ridges: int = 6, plant: str = "brush") -> float:
    """``direction_sign`` for the pad (see :func:`calibrate_shear`)."""
    return calibrate_shear(weights, fs, n_ridges, plant)[0]


class _Result:
    """Result-like record of an open-loop run for the detector's training functions."""

    def __init__(self, fs, t, v_out, u_out, slip_fraction, force_y=None, force_z=None, friction=None,
                 kinetic_ratio=1.0):
        self.fs, self.t, self.v_out, self.u_out, self.slip_fraction = fs, t, v_out, u_out, slip_fraction
        self.slip_time = None
        # what the load-ratio target of the detector reads (see detector.targets_from_result)
        self.force_y, self.force_z = force_y, force_z
        self.scene = None if friction is None else _Friction(float(friction), float(kinetic_ratio))


@dataclass(frozen=True)
class _Friction:
    friction: float
    kinetic_ratio: float


def train_detector_on_brush(seeds=range(100, 106), fs: float = 1000.0, duration: float = 3.0, n_hidden: int = 8,
                            maxiter: int = 150, noise: float = 0.0, plant: str = "brush"):
    """Train a Jordan detector on open-loop runs of the plant (:class:`BrushRidges` or
    :class:`FemPad`; seeds apart from the evaluation ones); targets as in
    :func:`tactile_mirror.detector.targets_from_result`."""
    from ..detector import train_detector

    placeholder = {"w1": np.zeros((n_hidden, 5)), "b1": np.zeros(n_hidden), "w2": np.zeros((2, n_hidden)),
                   "b2": np.zeros(2), "input_mean": np.zeros(4), "input_gain": np.ones(4), "fs": fs}
    results = []
    for s in seeds:
        # open-loop runs at a range of trajectory amplitudes: stick, incipient and gross slip
        base = PLANTS[plant]["trajectory"]
        amp = base.get("amplitude", 3e-3) * (1 / 6 + ((s * 7919) % 10) / 10)
        sc = Scene(seed=int(s), duration=duration, fs=fs, noise=noise, trajectory=dict(base, amplitude=amp),
                   plant=plant, mu=PLANTS[plant]["mu"])
        r = run_scene(sc, placeholder, None)
        if plant == "fem":
            from ..scenes import DEFAULT_FRICTION, DEFAULT_KINETIC_RATIO

            mu, kr = DEFAULT_FRICTION, DEFAULT_KINETIC_RATIO
        else:
            mu, kr = PLANTS[plant]["mu"], 1.0
        n = r.t.size
        results.append(_Result(fs, r.t, r.log["v_out"], r.log["u_out"], r.log["slip_fraction"],
                               r.log["force_y"][:n], r.log["force_z"][:n], mu, kr))
    return train_detector(results, n_hidden=n_hidden, maxiter=maxiter, progress=False,
                          metadata={"data": f"{plant} open-loop runs", "seeds": [int(s) for s in seeds]})


def _weights_dict(w):
    p = w.params
    return {"w1": p.w1, "b1": p.b1, "w2": p.w2, "b2": p.b2, "input_mean": w.input_mean,
            "input_gain": 1.0 / w.input_scale, "fs": w.fs, "features": w.features}


def default_weights(plant: str = "fem", fs: float = 1000.0):
    """The detector of the experiment: the bundled one for the FEM pad (it was trained on
    randomized FEM scenes); for the reduced brush model, one trained on its own open-loop runs."""
    if plant == "fem":
        from ..detector import SlipDetector

        return SlipDetector.default().weights
    return train_detector_on_brush(fs=fs, plant=plant)


def make_laws(weights, fs: float = 1000.0, plant: str = "fem", n_ridges: int = 6):
    """The controllers compared by the experiment, scaled to the plant.

    ``"velocity"`` (the law of this library): the proportional shear loop, its gain
    raised up to 2.5x by ``y_pred`` (``ramp_gain`` 0, ``pred_boost`` 1.5); base gain
    60 rad/s of the calibrated shear signal; a 0.1 s slip guard (``slip_hold``). ``"paper"``: the paper's law (threshold
    0.5, above the detector's resting ``y_pred``). Two ablations: ``"velocity, y_pred
    ramp"`` (the ramp term of the velocity law, no shear feedback: the relay that
    limit-cycles) and ``"velocity, shear only"`` (no ``y_pred``).

    Returns ``(laws, direction_sign, asymmetry_per_m, shear_gain)``.
    """
    w = _weights_dict(weights) if not isinstance(weights, dict) else weights
    cfg = PLANTS[plant]
    sign, a_per_m = calibrate_shear(w, fs, n_ridges, plant=plant)
    vf = cfg["finger_v_max"]
    # 60 rad/s of the shear signal, 150 rad/s at full y_pred: the stage (1 ms delay, 2 ms lag)
    # and the estimator (2nd order, 100 Hz) leave ~40 degrees of phase margin at 150 rad/s.
    shear_gain = 60.0 / a_per_m
    # The asymmetry integrator leaks slowly (20 s): the shear feedback must not drift over a
    # steady finger motion.
    arm = 0.5 if plant == "fem" else 0.0  # the FEM finger presses in first: hold, then tare
    common = {"direction_sign": sign, "asym_tau": 20.0, "x_min": -0.02, "x_max": 0.02, "arm_delay": arm}
    laws = {"velocity": VelocityController(threshold=0.2, y_full=0.7, v_max=2 * vf, a_max=1.0, ramp_gain=0.0,
                                           pred_boost=1.5, shear_gain=shear_gain, slip_hold=0.1, **common),
            "paper": PaperController(threshold=0.5, gain=7 * vf, **common),
            "velocity, y_pred ramp": VelocityController(threshold=0.3, y_full=0.7, v_max=2 * vf, a_max=1.0,
                                                        **common),
            "velocity, shear only": VelocityController(threshold=0.99, y_full=1.0, v_max=2 * vf, a_max=1.0,
                                                       shear_gain=shear_gain, **common)}
    return laws, sign, a_per_m, shear_gain


def open_and_closed(seed: int = 0, weights=None, law: str = "velocity", duration: float = 3.0,
                    fs: float = 1000.0, plant: str = "fem"):
    """One finger path, open loop and closed loop (Figs. 12 and 13): two :class:`SceneResult`."""
    weights = default_weights(plant, fs) if weights is None else weights
    w = _weights_dict(weights) if not isinstance(weights, dict) else weights
    laws = make_laws(w, fs, plant)[0]
    if law not in laws:
        raise ValueError(f"law must be one of {sorted(laws)}, got {law!r}")
    sc = Scene(seed=int(seed), duration=duration, fs=fs, plant=plant, trajectory=PLANTS[plant]["trajectory"])
    return run_scene(sc, w, None), run_scene(sc, w, laws[law])


def run_experiment(seeds=range(5), duration: float = 3.0, fs: float = 1000.0, weights=None, out_dir=None,
                   robustness: bool = True, progress: bool = False, plant: str = "brush",
                   robustness_seeds: int = 2) -> dict:
    """Open vs closed loop over seeded trajectories, both laws, and the robustness scenes.

    Parameters
    ----------
    plant : {"brush", "fem"}
        The contact model: :class:`BrushRidges` or the FEM pad (:class:`FemPad`).

    Returns a dict with ``rows`` (one summary per run), ``totals`` and the trained
    weights' metadata; with ``out_dir``, writes ``experiment.json``, the figures
    ``fig12_open_loop.png``, ``fig13_closed_loop.png``, ``fig13_paper_law.png``, the
    detector and a recording of one closed-loop run.
    """
    if plant not in PLANTS:
        raise ValueError(f"plant must be one of {sorted(PLANTS)}, got {plant!r}")
    cfg = PLANTS[plant]
    if weights is None:
        weights = default_weights(plant, fs)
    w = _weights_dict(weights) if not isinstance(weights, dict) else weights
    laws, sign, a_per_m, shear_gain = make_laws(w, fs, plant)
    base = {"duration": duration, "fs": fs, "plant": plant, "trajectory": cfg["trajectory"]}
    rows = []
    keep = {}
    for s in seeds:
        sc = Scene(seed=int(s), **base)
        r_open = run_scene(sc, w, None)
        rows.append(dict(r_open.summary(), controller="open loop"))
        keep.setdefault("open", r_open)
        for name, law in laws.items():
            r = run_scene(sc, w, law)
            rows.append(dict(r.summary(), controller=name))
            keep.setdefault(name, r)
        if progress:
            print(f"seed {s}: " + ", ".join(f"{x['controller']} {x['gross_slips']}" for x in rows[-5:]), flush=True)
    if robustness:
        ts, mu2 = cfg["sweat"]
        variants = [Scene(label=f"sweat (mu -> {mu2:g} at {ts:g} s)", mu_change=(ts, mu2)),
                    Scene(label=f"compliant mounting ({cfg['mount'] / 1e3:g} kN/m)", mount_stiffness=cfg["mount"]),
                    Scene(label="sensor noise (1 mV rms)", noise=1e-3),
                    Scene(label="dropped samples (5 %)", drop_rate=0.05)]
        for v in variants:
            for s in list(seeds)[:robustness_seeds]:
                sc = Scene(**{**v.__dict__, **base, "seed": int(s)})
                for name, law in [("open loop", None), *laws.items()]:
                    rows.append(dict(run_scene(sc, w, law).summary(), controller=name))
    totals = {}
    for row in rows:
        key = (row["label"], row["controller"])
        t = totals.setdefault(key, {"runs": 0, "gross_slips": 0, "runs_with_slip": 0, "gross_slip_time_s": 0.0,
                                    "tracking_rms_mm": [], "y_slip_max": 0.0})
        t["runs"] += 1
        t["gross_slips"] += row["gross_slips"]
        t["runs_with_slip"] += row["gross_slips"] > 0
        t["gross_slip_time_s"] += row["gross_slip_time_s"]
        t["tracking_rms_mm"].append(row["tracking_rms_mm"])
        t["y_slip_max"] = max(t["y_slip_max"], row["y_slip_max"])
    for t in totals.values():
        t["tracking_rms_mm"] = float(np.mean(t["tracking_rms_mm"]))
    result = {"rows": rows, "totals": [{"label": k[0], "controller": k[1], **v} for k, v in totals.items()],
              "plant": plant, "direction_sign": sign, "asymmetry_per_m": a_per_m, "shear_gain": shear_gain,
              "detector": weights.metadata.get("training", {}) if hasattr(weights, "metadata") else {}}
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        with open(os.path.join(out_dir, "experiment.json"), "w") as f:
            json.dump(result, f, indent=1)
        if hasattr(weights, "save"):
            weights.save(os.path.join(out_dir, "detector.npz"))
        if "velocity" in keep:
            r = keep["velocity"]
            pcfg = _pipeline(w, fs, laws["velocity"], r.log["v_out"].shape[0]).config
            rec = r.run.to_recording(pcfg, {"scene": r.scene.label, "seed": r.scene.seed, "plant": plant})
            path = os.path.join(out_dir, "closed_loop_recording.npz")
            rec.save(path)
            from .recording import Recording

            result["recording"] = {"path": "closed_loop_recording.npz",
                                   "replay_bit_identical": Recording.load(path).verify()}
            with open(os.path.join(out_dir, "experiment.json"), "w") as f:
                json.dump(result, f, indent=1)
        if "open" in keep:
            figure(keep["open"], os.path.join(out_dir, "fig12_open_loop.png"), closed=False)
        names = {"velocity": "fig13_closed_loop.png", "paper": "fig13_paper_law.png",
                 "velocity, y_pred ramp": "fig13_ypred_ramp.png", "velocity, shear only": "fig13_shear_only.png"}
        for name, fname in names.items():
            if name in keep:
                figure(keep[name], os.path.join(out_dir, fname), closed=True, law=name)
    return result


def figure(r: SceneResult, path, closed: bool, ridge: int = 0, law: str | None = None):
    """The paper's Fig. 12 (open loop) / Fig. 13 (closed loop) layout for one run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = r.t
    n = t.size
    R = r.log["v_out"].shape[0]
    y = r.outputs[:, 2:].reshape(n, R, 3)
    rows = 7 if closed else 6
    fig, ax = plt.subplots(rows, 1, figsize=(7, 1.45 * rows + 0.6), sharex=True)
    ax[0].plot(t, 1e3 * r.log["v_out"][ridge, 0, :n], lw=0.7, label="L")
    ax[0].plot(t, 1e3 * r.log["v_out"][ridge, 1, :n], lw=0.7, label="R")
    ax[0].set_ylabel("v_out\n(mV)")
    ax[0].legend(loc="upper right", fontsize=7, ncol=2)
    ax[1].plot(t, 1e3 * r.log["u_out"][ridge, 0, :n], lw=0.7)
    ax[1].plot(t, 1e3 * r.log["u_out"][ridge, 1, :n], lw=0.7)
    ax[1].set_ylabel("u_out\n(mV)")
    ax[2].plot(t, r.log["force_y"][:n], "k", lw=0.8)
    ax[2].set_ylabel("F_y (N)")
    ax[3].plot(t, r.log["force_z"][:n], "k", lw=0.8)
    ax[3].set_ylabel("F_z (N)")
    ax[3].set_ylim(0, 1.5 * max(r.log["force_z"].max(), 1e-6))
    ax[4].plot(t, y[:, :, 0].max(axis=1), "r", lw=0.8)
    ax[4].axhline(0.8, color="gray", ls="--", lw=0.6)
    ax[4].set_ylabel("y_slip")
    ax[4].set_ylim(-0.05, 1.05)
    gross = np.all(r.log["slip_fraction"][:, :n] >= 0.999, axis=0)
    for a in ax[4:6]:
        a.fill_between(t, 0, 1, where=gross, color="orange", alpha=0.25, lw=0, transform=a.get_xaxis_transform())
    ax[5].plot(t, y[:, :, 2].max(axis=1), "b", lw=0.8)
    ax[5].set_ylabel("y_pred")
    ax[5].set_ylim(-0.05, 1.05)
    if closed:
        ax[6].plot(t, 1e3 * r.finger, "k", lw=0.8, label="finger")
        ax[6].plot(t, 1e3 * r.stage, "g", lw=0.9, label="stage")
        ax[6].set_ylabel("y (mm)")
        ax[6].legend(loc="upper right", fontsize=7, ncol=2)
    ax[-1].set_xlabel("t (s)")
    law = {"paper": "paper's law", "velocity": "shear loop with y_pred gain scheduling",
           "velocity, y_pred ramp": "velocity law, y_pred ramp only",
           "velocity, shear only": "shear loop without y_pred"}.get(law or r.controller, law or r.controller)
    title = f"Fig. 13 (simulated): with feedback, {law}" if closed else "Fig. 12 (simulated): without feedback"
    fig.suptitle(f"{title}; seed {r.scene.seed}; gross slips: {r.gross_slips} (shaded)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description="Closed-loop tactile-mirror experiment (simulation)")
    ap.add_argument("--out", default="tactile-mirror-output/experiment")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=3.0)
    ap.add_argument("--no-robustness", action="store_true")
    ap.add_argument("--weights", default=None, help="detector weights (.npz) instead of training them")
    ap.add_argument("--plant", default="brush", choices=sorted(PLANTS))
    ap.add_argument("--robustness-seeds", type=int, default=2)
    args = ap.parse_args(argv)
    weights = None
    if args.weights:
        from ..detector import DetectorWeights

        weights = DetectorWeights.load(args.weights)
    res = run_experiment(range(args.seeds), args.duration, weights=weights, out_dir=args.out,
                         robustness=not args.no_robustness, progress=True, plant=args.plant,
                         robustness_seeds=args.robustness_seeds)
    print(f"plant {res['plant']}; direction_sign {res['direction_sign']:+g}; asymmetry {res['asymmetry_per_m']:.3g} "
          f"per m; shear_gain {res['shear_gain']:.3g}; detector: {res['detector']}")
    if "recording" in res:
        print(f"closed-loop recording replayed bit-identical: {res['recording']['replay_bit_identical']}")
    print(f"{'scene':<34} {'controller':<22} {'runs':>4} {'slips':>6} {'runs w/ slip':>12} {'slip s':>7} "
          f"{'max y_slip':>10} {'track rms mm':>12}")
    for t in res["totals"]:
        print(f"{t['label']:<34} {t['controller']:<22} {t['runs']:>4} {t['gross_slips']:>6} "
              f"{t['runs_with_slip']:>12} {t['gross_slip_time_s']:>7.2f} {t['y_slip_max']:>10.2f} "
              f"{t['tracking_rms_mm']:>12.3f}")
    return res


if __name__ == "__main__":
    main()
