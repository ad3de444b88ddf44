"""The pad: identical ridges under one finger, stepped together.

The finger is a rigid plate with a cylindrical curvature (radius ``finger_radius``) over
the ridges; a ridge at ``y_k`` from the pad centre is pressed ``y_k^2 / (2 R)`` less
than the centre, so inner ridges press deeper. All ridges share one condensed model
(:func:`~tactile_mirror.contact.model.ridge_model`) and each keeps its own contact
history. The plate moves as a whole: tangential displacement ``plate_y`` and indent
``indent`` (depth of the plate face below the undeformed crown of the centre ridges).

Forces are reported in N for ridges ``ridge_length`` long (the strip length by
default): the plane-strain model gives N/m.
"""
from __future__ import annotations

import functools
import numbers
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tactile_mirror._owner import NotCopyable
from tactile_mirror.checks import real_number
from tactile_mirror.contact.model import RidgeModel
from tactile_mirror.contact.solver import MAX_PLATE_POSITION, STEPPINGS, ContactSolver, position_error
from tactile_mirror.contact.step import OPEN, SLIP, STICK
from tactile_mirror.geometry import MAX_RIDGES, too_many_ridges

if TYPE_CHECKING:
    from tactile_mirror.scenes import Scene

__all__ = ["MAX_RIDGES", "Pad", "PadState"]



@dataclass
class PadState:
    """All ridges after one step. Arrays have the ridge on the first axis.

    ``strip_stress`` and ``node_position`` are computed from the contact forces when first
    read (a scene that does not ask for them does not pay for them).
    """

    slip_fraction: np.ndarray  # (n_ridges,)
    gross_slip: np.ndarray  # (n_ridges,) bool
    in_contact: np.ndarray  # (n_ridges,) bool
    force_y: float  # N, on the pad (sum over ridges)
    force_z: float  # N, pressing force (positive)
    node_state: np.ndarray  # (n_ridges, n_nodes) OPEN / STICK / SLIP
    forces: np.ndarray  # (n_ridges, 2n) nodal forces on the ridges, N/m
    displacement: np.ndarray  # (n_ridges, 2n) surface displacements (u_y, u_z), m
    iterations: int
    model: RidgeModel = field(repr=False)

    @functools.cached_property
    def strip_stress(self) -> np.ndarray:
        """(n_ridges, n_strips, 3) Pa, strip-frame normal stresses [s1, s2, s3] of each strip."""
        m = self.model
        return (self.forces @ m.sensor.T).reshape(self.forces.shape[0], m.n_strips, 3)

    @functools.cached_property
    def node_position(self) -> np.ndarray:
        """(n_ridges, 2, n_nodes) m, deformed (y, z) of the surface nodes."""
        m = self.model
        n = m.n_nodes
        return np.stack([m.node_y + self.displacement[:, :n], m.node_z + self.displacement[:, n:]], axis=1)


class Pad(NotCopyable):
    """``n_ridges`` identical ridges at ``pitch`` under a curved rigid finger.

    Parameters
    ----------
    model : RidgeModel
    mu : float
        Static friction coefficient between finger and ridges.
    mu_kinetic : float or None
        Kinetic coefficient (default: ``mu``; see :class:`ContactSolver`).
    n_ridges : int
        Number of ridges (1 for the paper's single-ridge analysis, 6 for the pad), at most
        :data:`MAX_RIDGES`.
    pitch : float
        Centre distance of neighbouring ridges, m (default: ridge width + 1 mm gap).
    finger_radius : float
        Curvature radius of the finger over the ridges, m (``inf``: flat plate).
    ridge_length : float
        Length of the ridges along ``x``, m (forces in N are per this length).
    tol : float
        Contact solver tolerance.
    backend : {"cpp", "python"}
        Contact solver implementation (see :class:`ContactSolver`). With ``"cpp"``
        (default) :meth:`advance` and :meth:`follow` step every ridge in one compiled
        call without the GIL, and keep the new state only if all ridges succeeded.
    stepping : {"auto", "every"}
        How :meth:`advance` and :meth:`follow` step (see
        :mod:`~tactile_mirror.contact.solver`). Both follow the load exactly from one
        call's plate position to the next, events resolved at their own points;
        ``"every"`` solves at every call, ``"auto"`` (default) only where a node's
        status changes (otherwise the state comes from the piece's response to a unit
        load, a few vector operations), and a position that does not move costs
        nothing.
    threads : int
        Threads of the compiled :meth:`follow` and :meth:`advance` (1 or 2): the ridges are
        independent, so with 2 they are shared with a second thread the pad keeps, one ridge
        at a time (same results, bit for bit; on a failure the ridge reported is the first
        failing one in ridge order, as with 1). The calling thread never waits for the second
        one to wake up, and after a call the second thread polls for the next for 2 ms before
        it sleeps: a pad stepped tick by tick at 500 Hz or more keeps the second core busy.
        On the 6-ridge FEM pad's open-loop paths the p99 of a tick is 13-25 % shorter with 2
        (a tick is as long as its slowest ridge's breakaway cascade). More than 2 count as 2.
        A plain attribute; the Python backend ignores it.
    """

    _copy_hint = ("make a new one from the same arguments and carry each ridge's history with "
                  "new.solvers[i].set_state(pad.solvers[i].get_state())")

    def __init__(self, model: RidgeModel, mu: float, n_ridges: int = 1, pitch: float | None = None,
                 finger_radius: float = np.inf, ridge_length: float = 10e-3, tol: float = 1e-10,
                 mu_kinetic: float | None = None, backend: str = "cpp", stepping: str = "auto",
                 threads: int = 1) -> None:
        if int(n_ridges) != n_ridges or n_ridges < 1:
            raise ValueError(f"n_ridges must be a positive integer, got {n_ridges!r}")
        if n_ridges > MAX_RIDGES:
            raise ValueError(too_many_ridges(n_ridges))
        if isinstance(finger_radius, bool) or not isinstance(finger_radius, numbers.Real) or not finger_radius > 0:
            raise ValueError(f"finger_radius must be positive (m; inf for a flat finger), got {finger_radius!r}")
        # (an inf length made an infinite force; a NaN or inf pitch put the ridges at NaN)
        ridge_length = real_number(ridge_length, "ridge_length", unit="m", positive=True)
        if pitch is not None:
            pitch = real_number(pitch, "pitch", unit="m", positive=True)
        if stepping not in STEPPINGS:
            raise ValueError(f"stepping must be one of {STEPPINGS}, got {stepping!r}")
        self.stepping = stepping
        if int(threads) != threads or threads < 1:
            raise ValueError(f"threads must be a positive integer, got {threads!r}")
        self.threads = int(threads)
        self._last = None  # (plate_y, indent, PadState) of the last advance, for "auto"
        self.model = model
        self.n_ridges = int(n_ridges)
        self.pitch = float(model.geometry.width + 1e-3 if pitch is None else pitch)
        if self.pitch < model.geometry.width:
            raise ValueError(f"pitch must be at least the ridge width, got {pitch!r}")
        self.finger_radius = float(finger_radius)
        self.ridge_length = float(ridge_length)
        self.ridge_y = (np.arange(self.n_ridges) - (self.n_ridges - 1) / 2) * self.pitch
        self.indent_offset = (self.ridge_y ** 2 / (2 * self.finger_radius)
                              if np.isfinite(self.finger_radius) else np.zeros(self.n_ridges))
        self.solvers = [ContactSolver(model, mu, tol=tol, mu_kinetic=mu_kinetic, backend=backend)
                        for _ in range(self.n_ridges)]
        self.backend = self.solvers[0].backend
        self._stepper = None
        if self.backend == "cpp":
            from tactile_mirror import _core

            self._stepper = _core._ContactPad([s._kernel for s in self.solvers])

    @classmethod
    def from_scene(cls, scene: Scene, backend: str = "cpp", stepping: str = "auto") -> Pad:
        """The pad a :class:`~tactile_mirror.Scene` describes: its ridge geometry,
        static and kinetic friction, number of ridges and finger radius."""
        from tactile_mirror.contact.model import ridge_model

        return cls(ridge_model(scene.geometry), scene.friction, n_ridges=scene.n_ridges,
                   finger_radius=scene.finger_radius, mu_kinetic=scene.friction * scene.kinetic_ratio,
                   backend=backend, stepping=stepping)

    @property
    def mu(self) -> float:
        return self.solvers[0].mu

    @mu.setter
    def mu(self, value: float) -> None:
        """Change the friction mid-run (e.g. sweat); the contact history is kept."""
        value = real_number(value, "mu", positive=True)
        # the kinetic coefficient keeps its ratio to the static one; every ridge or none
        # (a ridge busy in another thread raises before any is changed, and a failure
        # part way puts the changed ones back)
        old = [(s.mu, s.mu_kinetic) for s in self.solvers]
        done = 0
        try:
            for s, (mu, mu_k) in zip(self.solvers, old):
                s.set_friction(value, mu_k * value / mu)
                done += 1
        except BaseException:
            for s, (mu, mu_k) in list(zip(self.solvers, old))[:done]:
                s.set_friction(mu, mu_k)
            raise

    def reset(self) -> None:
        # last ridge first: a compiled ridge shadowing an earlier one (its mirror image,
        # see _core._ContactPad) then drops the link without copying the earlier one's state
        for s in reversed(self.solvers):
            s.reset()
        self._last = None

    @property
    def solves(self) -> int:
        """Linear solves of the event stepping so far (all ridges)."""
        return sum(getattr(s, "solves", 0) for s in self.solvers)

    @property
    def events(self) -> int:
        """Points where node statuses changed so far (all ridges)."""
        return sum(getattr(s, "events", 0) for s in self.solvers)

    def _plate_path(self, plate_y, indent, stepping):
        """The checked stepping, plate path ``y`` (N,) and the ridges' plate heights
        ``z`` (N, n_ridges), C-contiguous float64."""
        stepping = self.stepping if stepping is None else stepping
        if stepping not in STEPPINGS:
            raise ValueError(f"stepping must be one of {STEPPINGS}, got {stepping!r}")
        m = self.model
        y = np.ascontiguousarray(plate_y, dtype=np.float64).ravel()
        ind = np.asarray(indent, dtype=np.float64).ravel()
        if ind.shape != y.shape:
            raise ValueError(f"plate_y and indent must have the same length, got {y.size} and {ind.size}")
        z = np.ascontiguousarray(m.geometry.height - (ind[:, None] - self.indent_offset[None, :]))
        ok = (np.abs(y) <= MAX_PLATE_POSITION) & np.all(np.abs(z) <= MAX_PLATE_POSITION, axis=1)
        if not np.all(ok):  # (NaN fails the comparison too)
            k = int(np.flatnonzero(~ok)[0])
            raise position_error(y[k], ind[k], "indent")
        return stepping, y, z

    def follow(self, plate_y: np.ndarray, indent: np.ndarray, stepping: str | None = None,
               want_displacement: bool = False):
        """Follow a whole trajectory: ``plate_y`` and ``indent`` (m) per sample (with the
        compiled backend in one call without the GIL, on :attr:`threads` threads). Returns ``(lam, displacement, state)``: arrays ``(N, n_ridges, 2n)``
        of contact forces ``(lt, ln)`` (N/m), of surface displacements (m, or None) and
        ``(N, n_ridges, n)`` node states. ``stepping`` defaults to the pad's."""
        stepping, y, z = self._plate_path(plate_y, indent, stepping)
        if self._stepper is not None:
            return self._follow_compiled(y, z, stepping, want_displacement)
        n, R = self.model.n_nodes, self.n_ridges
        N = y.size
        lam = np.empty((R, N, 2 * n))
        disp = np.empty((R, N, 2 * n)) if want_displacement else None
        state = np.empty((R, N, n), dtype=np.int8)
        snaps = [s._snapshot() for s in self.solvers]
        try:
            for k, s in enumerate(self.solvers):
                s.follow(y, z[:, k], stepping, lam[k], None if disp is None else disp[k], state[k])
        except BaseException:
            for s, snap in zip(self.solvers, snaps):
                s._restore(snap)
            raise
        self._last = None
        return (np.moveaxis(lam, 0, 1), None if disp is None else np.moveaxis(disp, 0, 1),
                np.moveaxis(state, 0, 1))

    def follow_projected(self, plate_y: np.ndarray, indent: np.ndarray, proj: np.ndarray,
                         stepping: str | None = None):
        """:meth:`follow` reduced to what a scene reads: ``proj`` (q, 2n) linear functionals
        of the forces ``lam = (lt, ln)`` (strip stresses, force sums). Returns ``(out,
        slip_fraction, flags)``: ``out`` (N, n_ridges, q) = ``proj @ lam`` per sample and
        ridge, the slip fraction (N, n_ridges) and flags (N, n_ridges) int8 (bit 0: some
        node touches; bit 1: gross slip, touching and no node stuck). The compiled backend
        computes ``proj @ lam`` once per piece (it is affine along a piece), so a sample
        between events costs O(q), not O(n)."""
        stepping, y, z = self._plate_path(plate_y, indent, stepping)
        n, R = self.model.n_nodes, self.n_ridges
        proj = np.ascontiguousarray(proj, dtype=np.float64)
        if proj.ndim != 2 or proj.shape[1] != 2 * n or proj.shape[0] < 1:
            raise ValueError(f"proj must have shape (q, {2 * n}), got {proj.shape}")
        N = y.size
        if self._stepper is None:
            lam, _, st = self.follow(plate_y, indent, stepping)
            out = lam @ proj.T
            touching = st != OPEN
            w = self.model.weights
            total = touching @ w
            frac = np.divide((st == SLIP) @ w, total, out=np.zeros_like(total), where=total > 0)
            touch = touching.any(axis=2)
            gross = touch & ~np.any(st == STICK, axis=2)
            flags = (touch.astype(np.int8) | (gross.astype(np.int8) << 1)).astype(np.int8)
            return out, frac, flags
        out = np.empty((N, R, proj.shape[0]))
        frac = np.empty((N, R))
        flags = np.empty((N, R), dtype=np.int8)
        status, bad, _, _ = self._stepper.follow(y, z, stepping == "every", None, None, None, frac,
                                                 min(self.threads, 2), proj, out, flags)
        self._after_compiled(status, bad)
        return out, frac, flags

    def _after_compiled(self, status, bad):
        if status:
            s = self.solvers[bad]
            s._raise_status(status, *s._kernel.error_point())
        self._last = None

    def _follow_compiled(self, y, z, stepping, want_displacement):
        """:meth:`follow` on the compiled pad: ``y`` (N,) and the ridges' plate heights
        ``z`` (N, n_ridges), checked and C-contiguous."""
        n, R = self.model.n_nodes, self.n_ridges
        N = y.size
        lam = np.empty((N, R, 2 * n))
        disp = np.empty((N, R, 2 * n)) if want_displacement else None
        state = np.empty((N, R, n), dtype=np.int8)
        status, bad, _, _ = self._stepper.follow(y, z, stepping == "every", lam, disp, state, None,
                                                 min(self.threads, 2))
        self._after_compiled(status, bad)
        return lam, disp, state

    def advance(self, plate_y: float, indent: float) -> PadState:
        """Move the finger to ``plate_y`` (m, along the sliding direction) and ``indent``
        (m, depth of its face below the undeformed crowns at the pad centre) and solve
        the contact of every ridge; returns the new :class:`PadState`."""
        for name, v in (("plate_y", plate_y), ("indent", indent)):  # (a string was taken as a number)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
                raise TypeError(f"{name} must be a real number (m), got {type(v).__name__}")
        m = self.model
        n = m.n_nodes
        # friction is part of the load: a change of it (Pad.mu, or a solver's own mu) is an
        # event at the current load that the solvers settle, even with the plate still
        key = (float(plate_y), float(indent), tuple((s.mu, s.mu_kinetic) for s in self.solvers))
        if self.stepping == "auto" and self._last is not None and self._last[0] == key and self._last[2]:
            # the plate stands still (and its first repeat has stopped the sliding
            # nodes): the quasi-static state does not change
            return self._last[1]
        if self._stepper is not None:
            st = self._advance_compiled(plate_y, indent)
        else:
            lam, disp, states = self.follow(np.array([plate_y], dtype=np.float64),
                                            np.array([indent], dtype=np.float64), want_displacement=True)
            lam, disp, states = lam[0], disp[0], states[0]
            forces = np.concatenate([lam[:, :n], -lam[:, n:]], axis=1)
            w = m.weights
            touch = np.any(states != OPEN, axis=1)
            gross = touch & ~np.any(states == STICK, axis=1)
            total = (w * (states != OPEN)).sum(axis=1)
            frac = np.divide((w * (states == SLIP)).sum(axis=1), total, out=np.zeros(self.n_ridges),
                             where=total > 0)
            fy = float(forces[:, :n].sum()) * self.ridge_length
            fz = float(-forces[:, n:].sum()) * self.ridge_length
            st = PadState(frac, gross, touch, fy, fz, states, forces, disp, 0, m)
        self._last = (key, st, self._last is not None and self._last[0] == key)
        return st

    def _advance_compiled(self, plate_y: float, indent: float) -> PadState:
        m = self.model
        plate_y, indent = float(plate_y), float(indent)
        plate_z = m.geometry.height - (indent - self.indent_offset)
        # (the ridges' offsets are finite; NaN fails the comparison too)
        if not (abs(plate_y) <= MAX_PLATE_POSITION and np.all(np.abs(plate_z) <= MAX_PLATE_POSITION)):
            raise position_error(plate_y, indent, "indent")
        (status, bad, its, forces, disp, states, frac, touch, gross, sum_t,
         sum_n) = self._stepper.step(plate_y, plate_z, self.stepping == "every", min(self.threads, 2))
        if status:
            self.solvers[bad]._raise_status(status, *self.solvers[bad]._kernel.error_point())
        L = self.ridge_length
        return PadState(frac, gross, touch, sum_t * L, -sum_n * L, states, forces, disp, its, m)
