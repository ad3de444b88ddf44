"""One closed-loop scene: its setting, its plant and finger, the sample source, the run.

The finger is the moving plate: a seeded, band-limited random ``y`` trajectory
(:mod:`~tactile_mirror.loop.finger`) at constant normal load. The pad sits on a stage;
the contact plant (:mod:`tactile_mirror.contact.plants`) is stepped with the relative
displacement ``finger - pad`` every tick; its strip loads go through the PVDF circuit
in streaming form (:class:`~tactile_mirror.circuit.CircuitStream`, with sensor noise)
into the pipeline, whose command drives the stage. Open loop (Fig. 12) never commands
the stage; closed loop (Fig. 13) does.

:func:`run_scene` runs one :class:`LoopScene` and returns a :class:`SceneResult`;
:mod:`~tactile_mirror.lab.loop.experiment` composes many of them.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactile_mirror.checks import real_number
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.contact.brush import BrushRidges
from tactile_mirror.contact.plants import ContactPlant, FemPad
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.loop.finger import pressed_finger_path
from tactile_mirror.loop.runner import LoopRunner
from tactile_mirror.loop.stage import SimulatedStage, StageLimits
from tactile_mirror.pipeline.controller import Controller, NoController

__all__ = ["MIN_MOUNT_STIFFNESS", "PLANT_KINDS", "LoopScene", "PlantSource", "SceneResult", "gross_slip_events", "gross_slip_starts", "make_plant",
           "run_scene", "scene_finger"]

#: The plants a scene can name: ``"brush"`` (:class:`~tactile_mirror.contact.brush.BrushRidges`)
#: and ``"fem"`` (:class:`~tactile_mirror.contact.plants.FemPad`).
PLANT_KINDS = ("brush", "fem")

#: Softest mount a scene may have, N/m. The pads carry up to about 10 N of friction (the FEM
#: pad at its 30 um indent: 9 N; the brush model: 0.9 N), and the mount's give is
#: ``F_y / mount_stiffness`` (no pad mass): at 1 kN/m that is up to 9 mm, half the default
#: stage's travel; much softer mounts carried the pad beyond any travel, and at 1e-3 N/m
#: beyond the contact models' 1 m, where the run failed mid-way with an error about the
#: plant's ``dy``.
MIN_MOUNT_STIFFNESS = 1e3


@dataclass
class LoopScene:
    """One closed-loop simulation setting: finger, plant, robustness conditions, stage.

    Not :class:`tactile_mirror.Scene` (a contact scene of :func:`tactile_mirror.simulate`,
    plate motion prescribed): here the finger moves and the pad rides on a stage that
    the pipeline may command. Times in s, rates in Hz, stiffness in N/m, noise in V rms.
    """

    seed: int = 0
    duration: float = 3.0
    fs: float = 1000.0
    mu: float | None = None             # None: the plant's default (brush 1.0, fem DEFAULT_FRICTION)
    mu_change: tuple | None = None      # (time s, new mu[, ramp s]): sweat; mu ramps linearly (default 0.2 s)
    mount_stiffness: float | None = None  # N/m between stage and pad, >= MIN_MOUNT_STIFFNESS (None: rigid)
    noise: float = 0.0                   # rms sensor noise on v_out and u_out, V
    drop_rate: float = 0.0               # fraction of ticks whose samples are lost (NaN)
    stage_delay: float = 0.001
    stage_lag: float = 0.002
    label: str = "nominal"
    trajectory: dict = field(default_factory=dict)
    plant: str = "brush"                 # "brush" (BrushRidges) or "fem" (tactile_mirror.contact.Pad)
    press: float = 0.5                   # fem: the finger presses in for this long before moving, s
    # A load cell between stage and pad: its reading, the pad's tangential force (N), is one more
    # sample after the voltages (MirrorPipeline(force_input=True)): the finger's force on the pad
    # minus the pad's inertia (pad_mass times its acceleration), plus white noise (N rms; 2 mN:
    # a 10 N miniature cell on a 24-bit bridge ADC at 1 kHz).
    load_cell: bool = False
    load_cell_noise: float = 2e-3
    pad_mass: float = 0.02               # kg: pad and ridges on the cell

    def __post_init__(self) -> None:
        # (a negative friction or stiffness, or a drop rate above 1, ran and gave numbers)
        if isinstance(self.seed, bool) or not isinstance(self.seed, numbers.Integral) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        real_number(self.duration, "duration", unit="s", positive=True)
        real_number(self.fs, "fs", unit="Hz", positive=True)
        for name in ("noise", "stage_delay", "stage_lag", "press", "load_cell_noise", "pad_mass"):
            real_number(getattr(self, name), name, nonnegative=True)
        if not isinstance(self.load_cell, (bool, np.bool_)):
            raise TypeError(f"load_cell must be True or False, got {type(self.load_cell).__name__}")
        if not 0 <= real_number(self.drop_rate, "drop_rate") < 1:
            raise ValueError(f"drop_rate must lie in [0, 1), got {self.drop_rate!r}")
        if self.mu is not None:
            real_number(self.mu, "mu", positive=True)
        if self.mount_stiffness is not None:
            real_number(self.mount_stiffness, "mount_stiffness", unit="N/m", positive=True)
            if not self.mount_stiffness >= MIN_MOUNT_STIFFNESS:
                raise ValueError(f"mount_stiffness must be at least {MIN_MOUNT_STIFFNESS:g} N/m (MIN_MOUNT_STIFFNESS: "
                                 f"a softer mount lets the pad's friction carry it centimetres off the stage), "
                                 f"got {self.mount_stiffness!r}")
        if self.mu_change is not None:
            mc = tuple(self.mu_change) if isinstance(self.mu_change, (tuple, list)) else ()
            if len(mc) not in (2, 3):
                raise ValueError(f"mu_change must be (time s, new mu) or (time s, new mu, ramp s), "
                                 f"got {self.mu_change!r}")
            mc = (real_number(mc[0], "mu_change time", unit="s", nonnegative=True),
                  real_number(mc[1], "mu_change mu", positive=True)) + \
                ((real_number(mc[2], "mu_change ramp", unit="s", nonnegative=True),) if len(mc) == 3 else ())
            self.mu_change = mc
        if self.plant not in PLANT_KINDS:
            raise ValueError(f"plant must be one of {PLANT_KINDS}, got {self.plant!r}")


def make_plant(scene: LoopScene, n_ridges: int = 6) -> ContactPlant:
    """The contact plant of a scene."""
    if scene.plant == "brush":
        mu = 1.0 if scene.mu is None else scene.mu
        return BrushRidges(n_ridges, mu=mu * (1 + 0.04 * np.linspace(-1, 1, n_ridges)))
    if scene.plant == "fem":
        return FemPad(n_ridges, mu=scene.mu, fs=scene.fs)
    raise ValueError(f"plant must be 'brush' or 'fem', got {scene.plant!r}")


def scene_finger(scene: LoopScene) -> np.ndarray:
    """The finger path of a scene, m (with the press phase at rest for the FEM pad)."""
    press = scene.press if scene.plant == "fem" else 0.0
    return pressed_finger_path(scene.seed, scene.duration, scene.fs, press, **scene.trajectory)


class PlantSource:
    """Sample source for :class:`LoopRunner`: finger, contact plant, circuit, noise, drops.

    Each :meth:`read` steps the plant with ``finger - pad`` (the pad is the stage, plus
    the mount's give under ``force_y`` for a compliant mounting), feeds the strips'
    change of load since the first tick (the static normal preload is no change of
    stress) through the circuit's streaming form and returns ``[v_out, u_out]`` (V,
    2 n_ridges each; NaN for a dropped tick), and with ``scene.load_cell`` the load
    cell's force (N) after them. Everything is logged in :attr:`log`.
    """

    def __init__(self, scene: LoopScene, plant: ContactPlant, circuit: PVDFCircuit, finger: np.ndarray):
        self.scene = scene
        self.plant = plant
        self.finger = finger
        R = plant.n_ridges
        # one generator for the sensor noise and the drops, in this order per tick
        self.rng = np.random.default_rng(10_000 + scene.seed)
        self.circuit = circuit.stream(scene.fs, 2 * R, noise=scene.noise, seed=self.rng)
        n = finger.size
        self.k = 0
        self.log = {"force_y": np.zeros(n), "force_z": np.zeros(n), "slip_fraction": np.zeros((R, n)),
                    "pad": np.zeros(n), "v_out": np.zeros((R, 2, n)), "u_out": np.zeros((R, 2, n))}
        self._fy = 0.0
        self._stress0: np.ndarray | None = None
        self._mu0: float | np.ndarray | None = None
        self._mu_done = False
        # the load cell's noise has its own generator: the other draws stay as without it
        self._cell_rng = np.random.default_rng(20_000 + scene.seed) if scene.load_cell else None
        self._pads = [0.0, 0.0]  # the pad's last two positions (its acceleration for the cell)
        if scene.load_cell:
            self.log["load_cell"] = np.zeros(n)

    def read(self, stage_position: float, t: float):
        k = self.k
        if k >= self.finger.size:
            return None
        # (a NaN reached the plant as its internal "dy must be finite"; nothing is stepped here)
        stage_position = real_number(stage_position, "stage_position (the stage's position)", unit="m")
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
        v, u = self.circuit.step_load(load)
        lg = self.log
        lg["force_y"][k] = st.force_y
        lg["force_z"][k] = st.force_z
        lg["slip_fraction"][:, k] = st.slip_fraction
        lg["pad"][k] = pad
        lg["v_out"][:, :, k] = v.reshape(-1, 2)
        lg["u_out"][:, :, k] = u.reshape(-1, 2)
        self.k += 1
        x = np.concatenate([v, u])
        if sc.load_cell:
            # the cell carries the pad: it reads the finger's force minus the pad's inertia
            acc = (pad - 2.0 * self._pads[1] + self._pads[0]) * sc.fs ** 2 if k >= 2 else 0.0
            self._pads = [self._pads[1], pad]
            f = st.force_y - sc.pad_mass * acc + sc.load_cell_noise * self._cell_rng.standard_normal()
            lg["load_cell"][k] = f
            x = np.append(x, f)
        if sc.drop_rate > 0 and self.rng.random() < sc.drop_rate:
            x[:] = np.nan
        return x


def gross_slip_starts(slip_fraction, level: float = 0.999, min_gap: int = 20) -> np.ndarray:
    """Ticks where gross-slip events of the contact start: every ridge grossly slipping
    (slip fraction >= ``level``, shape ``(n_ridges, n)``); an event starting fewer than
    ``min_gap`` ticks after the previous one ended is merged into it."""
    g = np.all(np.asarray(slip_fraction) >= level, axis=0)
    starts = np.flatnonzero(g[1:] & ~g[:-1]) + 1
    if g.size and g[0]:
        starts = np.concatenate([[0], starts])
    ends = np.flatnonzero(g[:-1] & ~g[1:]) + 1
    kept = []
    for s in starts:
        prev_end = ends[ends < s]
        if not kept or prev_end.size == 0 or s - prev_end[-1] >= min_gap:
            kept.append(int(s))
    return np.asarray(kept, dtype=np.int64)


def gross_slip_events(slip_fraction, level: float = 0.999, min_gap: int = 20) -> int:
    """Number of gross-slip events of the contact (:func:`gross_slip_starts`)."""
    return int(gross_slip_starts(slip_fraction, level, min_gap).size)


@dataclass
class SceneResult:
    """One run of a :class:`LoopScene`: time (s), finger and stage (m), pipeline outputs,
    the source's log, gross-slip counts and tracking errors (m)."""

    scene: LoopScene
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
    run: Any = None  # the LoopResult
    config: Any = None  # the pipeline's config (LoopResult.to_recording)

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


def loop_pipeline(weights, fs: float, controller: Controller, n_ridges: int, shear_weights=None,
                  force_input: bool = False):
    """The pipeline of the experiment: 2nd-order 100 Hz estimator, fast activation, 50-tick hold;
    ``shear_weights`` (n_ridges, 2) for the controller's shear signal (default: L - R);
    ``force_input``: a load cell's force drives it instead (``LoopScene.load_cell``)."""
    from tactile_mirror.pipeline import MirrorPipeline

    est = StressRateEstimator(PVDFCircuit(), fs, 2 * n_ridges, order=2, bandwidth=100.0)
    return MirrorPipeline(weights, fs, n_ridges, estimator=est, controller=controller, activation="fast",
                          max_hold_ticks=50, shear_weights=shear_weights, force_input=force_input)


def run_scene(scene: LoopScene, weights, controller: Controller | None, limits: StageLimits | None = None,
              n_ridges: int = 6, shear_weights=None, finger=None, plant: ContactPlant | None = None,
              realtime: bool = False) -> SceneResult:
    """Run one scene, open loop (``controller`` None or :class:`NoController`) or closed loop;
    ``shear_weights`` go to the pipeline (:func:`loop_pipeline`). ``finger`` (m, one value
    per tick; for the FEM pad at rest during the press) replaces the scene's generated path,
    e.g. a recorded one or a finger held still; the run lasts as many ticks. ``plant``
    replaces the scene's own (:func:`make_plant`), e.g. :meth:`FemPad.realtime
    <tactile_mirror.contact.plants.FemPad.realtime>`; ``realtime`` paces the ticks by the
    wall clock (:class:`LoopRunner`; ``result.run`` has the tick times and overruns)."""
    controller = controller or NoController()
    limits = limits or StageLimits(-0.02, 0.02, 0.03, 1.0)
    if finger is None:
        finger = scene_finger(scene)
    else:
        finger = np.array(finger, dtype=np.float64)
        if finger.ndim != 1 or finger.size == 0 or not np.all(np.isfinite(finger)):
            raise ValueError(f"finger must be a non-empty 1-D array of finite positions (m), got shape "
                             f"{finger.shape}")
    if plant is None:
        plant = make_plant(scene, n_ridges)
    elif plant.n_ridges != n_ridges:
        raise ValueError(f"plant must have n_ridges = {n_ridges} ridges, got {plant.n_ridges}")
    source = PlantSource(scene, plant, PVDFCircuit(), finger)
    stage = SimulatedStage(limits, delay=scene.stage_delay, lag=scene.stage_lag)
    pipe = loop_pipeline(weights, scene.fs, controller, n_ridges, shear_weights, force_input=scene.load_cell)
    closed = controller.kind != "none"
    res = LoopRunner(pipe, stage, source, realtime=realtime, command=closed).run(n_ticks=finger.size, x0=0.0)
    log = source.log
    rel = finger[: len(res.t)] - log["pad"][: len(res.t)]
    sf = log["slip_fraction"][:, : len(res.t)]
    ridge = sum(gross_slip_events(sf[r:r + 1]) for r in range(n_ridges))
    return SceneResult(scene=scene, controller=controller.kind, t=res.t, finger=finger[: len(res.t)],
                       stage=res.stage_position, outputs=res.outputs, log=log, gross_slips=gross_slip_events(sf),
                       ridge_gross_slips=ridge, tracking_rms=float(np.sqrt(np.mean(rel**2))),
                       tracking_max=float(np.abs(rel).max()), status=res.status, run=res, config=pipe.config)
