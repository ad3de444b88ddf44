"""Run scenes: the contact model stepped over a plate trajectory, then the PVDF circuit.

``simulate(scene)`` returns a :class:`SimulationResult`; ``simulate_many(scenes)`` runs
a sweep on any ``concurrent.futures.Executor`` with a progress bar
(:func:`tactile_mirror.engine.run_tasks`). Only what the scene asks for is computed
(:data:`tactile_mirror.scenes.OUTPUTS`).
"""
from __future__ import annotations

import concurrent.futures
import functools
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tactile_mirror.contact.pad import Pad
from tactile_mirror.contact.solver import BACKENDS, STEPPINGS
from tactile_mirror.contact.step import OPEN, SLIP, STICK

if TYPE_CHECKING:  # scenes imports contact.geometry, so import it lazily at run time
    from tactile_mirror.scenes import Scene

__all__ = ["SimulationResult", "calibrate_friction", "simulate", "simulate_many"]


@dataclass
class SimulationResult:
    """What a scene produced. Time is the last axis; ridges the first.

    Attributes
    ----------
    t : (n,) s
    fs : Hz
    plate_y, indent : (n,) m, the plate motion that was simulated
    stress : (n_ridges, 2, 3, n) Pa, strip-averaged normal stresses (s1 along the
        strip length, s2 along its width, s3 through the film) of the L and R strips
    v_out, u_out : (n_ridges, 2, n) V, the PVDF circuit outputs (with sensor noise)
    slip_fraction : (n_ridges, n), share of each ridge's contact length that slips
    slip_time : s, first time the whole pad is in gross slip (every ridge), or None
    ridge_slip_time : (n_ridges,) s, per ridge (NaN where it never slips)
    force_y, force_z : (n,) N, tangential and pressing force of the finger on the pad
    node_state : (n_ridges, n_nodes, n) int8, 0 open / 1 stick / 2 slip ("state" only)
    node_position : (n_ridges, 2, n_nodes, n) m, deformed surface ("state" only)
    fields : dict time -> (stress (4, n_elements) Pa, centroids (2, n_elements) m), per ridge 0
    stepping, backend : how the contact was stepped and by which implementation
    solves : linear solves of the contact pieces (all ridges)
    events : points where node statuses changed (all ridges)
    """

    scene: Scene
    t: np.ndarray
    fs: float
    plate_y: np.ndarray
    indent: np.ndarray
    stress: np.ndarray | None = None
    v_out: np.ndarray | None = None
    u_out: np.ndarray | None = None
    slip_fraction: np.ndarray | None = None
    slip_time: float | None = None
    ridge_slip_time: np.ndarray | None = None
    force_y: np.ndarray | None = None
    force_z: np.ndarray | None = None
    node_state: np.ndarray | None = None
    node_position: np.ndarray | None = None
    fields: dict = field(default_factory=dict)
    newton_iterations: int = 0
    stepping: str = "auto"
    backend: str = "cpp"
    solves: int = 0
    events: int = 0

    @property
    def sigma_diff(self) -> np.ndarray:
        """``sigma_L - sigma_R`` of the through-film stress ``s3`` per ridge, (n_ridges, n) Pa."""
        return self.stress[:, 0, 2] - self.stress[:, 1, 2]


def simulate(scene: Scene, progress: bool = False, backend: str = "cpp", stepping: str = "auto") -> SimulationResult:
    """Simulate one scene (see :class:`tactile_mirror.Scene`).

    Parameters
    ----------
    scene : Scene
    progress : bool
        Show a progress bar over the time steps.
    backend : {"cpp", "python"}
        Contact solver implementation (:class:`~tactile_mirror.contact.ContactSolver`):
        the compiled kernel (default) or the Python reference; same results to round-off.
        The plate trajectory is followed in blocks of samples (:meth:`Pad.follow`; with
        ``"cpp"`` one compiled call per block without the GIL), and the strip stresses,
        forces and slip times of a block are derived with array operations: no Python
        runs per time step.
    stepping : {"auto", "every"}
        ``"auto"`` (default): event-driven, the contact is solved only where a node
        changes its status (touches, lifts off, breaks away, stops sliding) and the
        samples between come from the linear response; a stop costs nothing.
        ``"every"``: solved at every sample (the reference). Both resolve each event
        at its own point (:mod:`~tactile_mirror.contact.solver`) and agree to
        round-off, with either backend.
    """
    from tactile_mirror.scenes import Scene

    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a tactile_mirror.Scene, got {type(scene).__name__}")
    if stepping not in STEPPINGS:
        raise ValueError(f"stepping must be one of {STEPPINGS}, got {stepping!r}")
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    pad = Pad.from_scene(scene, backend=backend, stepping=stepping)
    model = pad.model
    plate_y, indent = scene.plate_motion()
    n_total = plate_y.size
    outs = scene.outputs
    want_stress = bool(outs & {"stress", "signals"})
    want_state = "state" in outs
    R, N = pad.n_ridges, model.n_nodes
    stress = np.empty((R, model.n_strips, 3, n_total)) if want_stress else None
    frac = np.empty((R, n_total))
    fy = np.empty(n_total)
    fz = np.empty(n_total)
    node_state = np.empty((R, N, n_total), dtype=np.int8) if want_state else None
    node_pos = np.empty((R, 2, N, n_total)) if want_state else None
    # (the nearest sample; a time after the last sample, before the end of the run, is the last one)
    field_idx = ({min(round(tf * scene.fs), scene.n_samples - 1): tf for tf in scene.field_times}
                 if "fields" in outs else {})
    fields = {}
    ridge_slip = np.full(R, np.nan)
    slip_time = None
    end = n_total
    its = 0
    end, slip_time = _run_events(pad, plate_y, indent, scene, want_stress, want_state, field_idx, stress,
                                 frac, fy, fz, node_state, node_pos, fields, ridge_slip, progress)
    solves, events = pad.solves, pad.events
    n = min(end, n_total)
    t = np.arange(n) / scene.fs
    res = SimulationResult(scene=scene, t=t, fs=scene.fs, plate_y=np.asarray(plate_y[:n]),
                           indent=np.asarray(indent[:n]), slip_time=slip_time, ridge_slip_time=ridge_slip,
                           newton_iterations=its, fields=fields, stepping=stepping, backend=pad.backend,
                           solves=solves, events=events)
    if "stress" in outs or "signals" in outs:
        res.stress = stress[..., :n]
    if "slip" in outs:
        res.slip_fraction = frac[:, :n]
    if "forces" in outs:
        res.force_y, res.force_z = fy[:n], fz[:n]
    if want_state:
        res.node_state, res.node_position = node_state[..., :n], node_pos[..., :n]
    if "signals" in outs:
        stream = scene.circuit.stream(scene.fs, res.stress.shape[:-2], noise=scene.noise, seed=scene.seed)
        res.v_out, res.u_out = stream.process(res.stress)
        if scene.noise_model is not None:
            res.v_out, res.u_out = scene.noise_model.apply(res.v_out, res.u_out, scene.fs, seed=[1, scene.seed])
    return res


#: Samples per call of the event stepping (bounds the memory of its outputs).
_EVENT_BLOCK = 8192


def _run_events(pad, plate_y, indent, scene, want_stress, want_state, field_idx, stress, frac, fy, fz,
                node_state, node_pos, fields, ridge_slip, progress):
    """The trajectory loop of :func:`simulate`: blocks of samples followed by
    :meth:`Pad.follow` (either backend), outputs derived with array operations."""
    model = pad.model
    R, n = pad.n_ridges, model.n_nodes
    n_total = plate_y.size
    w = model.weights
    sensor_t = model.sensor.T
    slip_time = None
    end = n_total
    start = 0
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n_total, desc="contact", unit="step", leave=False)
    # without node states or stress fields, only P lam is read: the strip stresses
    # (f @ sensor.T with f = (lt, -ln)) and the sums of lt and ln
    projected = not want_state and not field_idx
    if projected:
        ns = model.n_strips * 3 if want_stress else 0
        proj = np.zeros((ns + 2, 2 * n))
        if want_stress:
            proj[:ns, :n] = model.sensor[:, :n]
            proj[:ns, n:] = -model.sensor[:, n:]
        proj[ns, :n] = 1.0
        proj[ns + 1, n:] = 1.0
    while start < end:
        m = min(_EVENT_BLOCK, end - start)
        sl = slice(start, start + m)
        if projected:
            out, fr, flags = pad.follow_projected(plate_y[sl], indent[sl], proj)
            if want_stress:
                stress[..., sl] = np.moveaxis(out[:, :, :ns].reshape(m, R, model.n_strips, 3), 0, -1)
            frac[:, sl] = fr.T
            fy[sl] = out[:, :, ns].sum(axis=1) * pad.ridge_length
            fz[sl] = out[:, :, ns + 1].sum(axis=1) * pad.ridge_length
            gross = (flags & 2) != 0  # (m, R)
        else:
            lam, d, st = pad.follow(plate_y[sl], indent[sl], want_displacement=want_state)
            f = np.concatenate([lam[:, :, :n], -lam[:, :, n:]], axis=2)  # (m, R, 2n)
            if want_stress:
                stress[..., sl] = np.moveaxis((f @ sensor_t).reshape(m, R, model.n_strips, 3), 0, -1)
            touching = st != OPEN
            total = touching @ w
            slipping = (st == SLIP) @ w
            frac[:, sl] = np.divide(slipping, total, out=np.zeros_like(total), where=total > 0).T
            fy[sl] = f[:, :, :n].sum(axis=(1, 2)) * pad.ridge_length
            fz[sl] = -f[:, :, n:].sum(axis=(1, 2)) * pad.ridge_length
            if want_state:
                node_state[..., sl] = np.moveaxis(st, 0, -1)
                node_pos[:, 0, :, sl] = np.moveaxis(model.node_y + d[:, :, :n], 0, -1)
                node_pos[:, 1, :, sl] = np.moveaxis(model.node_z + d[:, :, n:], 0, -1)
            gross = touching.any(axis=2) & ~np.any(st == STICK, axis=2)  # (m, R)
        if slip_time is None:
            all_gross = gross.all(axis=1)
            if all_gross.any():
                i = start + int(np.argmax(all_gross))
                slip_time = i / scene.fs
                if scene.stop_after_slip is not None:
                    end = min(n_total, i + 1 + round(scene.stop_after_slip * scene.fs))
        valid = min(m, end - start)
        for i, tf in field_idx.items():
            if start <= i < start + valid:
                fields[tf] = model.stress_field(f[i - start, 0])
        for k in range(R):
            if np.isnan(ridge_slip[k]) and gross[:valid, k].any():
                ridge_slip[k] = (start + int(np.argmax(gross[:valid, k]))) / scene.fs
        if bar is not None:
            bar.update(m)
        start += m
    if bar is not None:
        bar.close()
    return end, slip_time


def simulate_many(scenes: Iterable[Scene], executor: concurrent.futures.Executor | None = None, progress: bool = True,
                  max_workers: int | None = None, stepping: str = "auto", backend: str = "cpp", *,
                  portable: bool = False) -> list[SimulationResult]:
    """Simulate many scenes, in order, on ``executor`` (default: a local process pool).

    ``stepping`` and ``backend`` are passed to :func:`simulate` for every scene.

    Any :class:`concurrent.futures.Executor` works, e.g. ``dask.distributed.Client(...)
    .get_executor()`` to spread a sweep over a cluster. Without one, a pool of
    ``max_workers`` spawned processes (default: one per core, at most one per scene; 1:
    in this process) is started and shut down at the end. The sweep runs through
    :func:`tactile_mirror.engine.run_tasks`: every scene with its BLAS/OpenMP pools pinned
    to one thread, so that every executor gives the same bits; a worker of an outside
    process or cluster executor runs only if its build is this one's
    (:class:`~tactile_mirror.engine.BuildMismatch` names both); ``portable`` runs the
    baseline kernels in every task, for workers whose CPUs differ. A failed scene raises
    :class:`~tactile_mirror.engine.TaskError` naming it. Shows a progress bar.

    A lost worker: the pool of our own is started again and the unfinished scenes sent
    again (twice at most); dask's scheduler sends a lost worker's scenes to others (up to
    its ``allowed-failures``, then a ``KilledWorker`` error names the scene); an outside
    ``ProcessPoolExecutor`` is broken for good by a lost worker (``TaskError`` naming the
    first unfinished scene); a thread pool has no worker to lose.
    """
    from tactile_mirror.engine import run_tasks
    from tactile_mirror.scenes import Scene

    if stepping not in STEPPINGS:
        raise ValueError(f"stepping must be one of {STEPPINGS}, got {stepping!r}")
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    scenes = list(scenes)
    for k, s in enumerate(scenes):
        if not isinstance(s, Scene):
            raise TypeError(f"scenes[{k}] must be a Scene, got {type(s).__name__}")
    if executor is not None and not callable(getattr(executor, "submit", None)):
        raise TypeError(f"executor must be a concurrent.futures.Executor (with submit), got {type(executor).__name__}")
    if max_workers is not None and (isinstance(max_workers, bool) or not isinstance(max_workers, int)
                                    or max_workers < 1):  # (0 meant every core)
        raise ValueError(f"max_workers must be a positive integer or None, got {max_workers!r}")
    if not isinstance(portable, (bool, np.bool_)):
        raise TypeError(f"portable must be a bool, got {type(portable).__name__}")
    if not scenes:
        return []
    workers = None
    if executor is None:
        workers = max_workers or min(len(scenes), os.cpu_count() or 1)
    task = functools.partial(simulate, progress=False, stepping=stepping, backend=backend)
    return list(run_tasks(task, scenes, executor=executor, workers=workers, progress=progress, desc="scenes",
                          chunk="auto", portable=bool(portable)))


def calibrate_friction(target_slip_time: float, scene: Scene | None = None,
                       bracket: tuple[float, float] = (0.3, 1.2),
                       tol: float = 2e-3) -> float:
    """Friction coefficient at which ``scene`` (default: the paper's fig6) reaches gross
    slip at ``target_slip_time`` s (bisection; slip time grows with friction)."""
    from dataclasses import replace

    from tactile_mirror.scenes import paper

    base = scene if scene is not None else paper("fig6")
    base = replace(base, outputs=frozenset({"slip"}), stop_after_slip=0.0)

    def slip_at(mu):
        st = simulate(replace(base, friction=mu)).slip_time
        return np.inf if st is None else st

    lo, hi = bracket
    if not (slip_at(lo) < target_slip_time < slip_at(hi)):
        raise ValueError(f"target_slip_time {target_slip_time} s is not bracketed by friction {bracket}")
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if slip_at(mid) < target_slip_time:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
