"""Frictional contact of a ridge with a rigid flat plate, solved on the condensed surface.

Unknowns are the contact forces at the candidate nodes, ``lam = (lt, ln)``: tangential
force on the ridge along ``y`` and normal pressure force (``ln >= 0`` pushes the ridge
down). The surface displacements are ``u = C f`` with ``f = (lt, -ln)`` (see
:mod:`~tactile_mirror.contact.model`). For a plate whose face is at height ``zp`` and
which has moved ``s`` along ``y``:

* gap ``g = zp - (z0 + u_z) >= 0``, ``ln >= 0``, ``ln g = 0`` (Signorini);
* slip increment of the ridge surface relative to the plate over the step
  ``w = (u_y - u_y_prev) - (s - s_prev)``; Coulomb: ``|lt| <= mu ln``, stick (``w = 0``)
  inside the cone, ``lt = -mu ln sign(w)`` on it (history-dependent through ``u_y_prev``).
  Static and kinetic friction, rate-independent: a node that is sliding has the cone
  ``mu_kinetic``, a node that is stuck (or just touched) the cone ``mu`` (static,
  >= kinetic). The drop from the static to the kinetic cone happens at the breakaway
  itself, and the load it sheds is carried at that same load before the path goes on
  (the *breakaway cascade*), so gross slip releases the stored shear (a sharp stress
  drop) where a plate that merely stops does not, and the sample rate does not enter
  the law. A node is reported as slipping when it is on the cone *and* moves relative
  to the plate (``|w| > 1e-11 * ridge height``); on the cone but still (a stopped
  plate) it is reported as stuck.

Event-driven path following (the law both stepping modes and both backends
implement). Between two samples the plate moves linearly, ``L(theta) = L0 + theta
(L1 - L0)`` with ``L = (plate_y, plate_z)``. Every node has a status: OPEN, STICK
(``g = 0``, ``u_y - s`` fixed at its anchor, cone ``mu``), SLIP with a sign
(``g = 0``, ``lt = sign * mu_kinetic * ln``: the friction force opposes the slip).
For a fixed status set the forces are linear in the load (one linear system, the
"piece"), so the path is followed from event to event::

    1. piece: solve the piece at the end of the segment (from the current state).
    2. rates: a SLIP node whose slip over the rest of the segment does not oppose its
       friction force (sign * d(u_y - s) >= -1e-9 * |dL|; a load that does not move
       gives zero rates) becomes STICK here, anchored where it is; back to 1.
    3. events: along the piece (forces and displacements linear in theta between
       the current point and the piece's end), the first theta where one of these functions, >= 0
       at the start and decreasing (by more than a round-off tolerance), reaches 0:
       OPEN node: gap g -> STICK (anchored where it touches);
       touching node: ln -> OPEN (its forces set to 0);
       STICK node: mu ln - lt, mu ln + lt -> SLIP with sign +1 / -1 (breakaway).
       "Decreasing": phi_1 < 0 and phi_c - phi_1 > 1e-16 H (gaps) or 1e-15 r H
       (forces), H the ridge height, r = 1 / mean(diag C); the crossing is at
       frac = max(phi_c, 0) / (phi_c - phi_1) of the rest of the segment.
       Every function reaching 0 within 1e-9 samples of the first one changes at the
       same point (ties resolved together). No event before the segment end: done.
    4. move to the event point (forces and displacements interpolated linearly in
       theta), change the statuses; samples before the event (more than 1e-9 samples
       before it) take the linear interpolation of the piece.
    5. breakaway cascade (only if a breakaway node carries ln > 0 and mu_kinetic <
       mu): solve the load of the event point again with the Alart-Curnier
       equations below (slip measured from the event point, cones: mu_kinetic on
       SLIP nodes, mu elsewhere; active-set iterations go on until the classification
       settles, not only until the residual is within tol), switch every node that
       slides under the static
       cone to the kinetic one and solve again, until none does (all of a round at
       once). New statuses: a node that moved on its cone (|w| > w_tol = 1e-11 H)
       is SLIP with the sign of its friction force; a SLIP node that did not move
       and is still on its kinetic cone (|lt| >= mu_kinetic ln - 1e-12 r H) stays
       SLIP with its sign; a touching node the solve finds open with its gap still
       closed (gap <= 1e-14 H) keeps its status; every other touching node is
       STICK, anchored where it is. Back to 1 from the event point. The cascade
       runs only where a breakaway node sheds a load, (mu - mu_kinetic) ln > 1e-12 r H.
    6. cycle rule: if the statuses at one point come back to a set already met at
       that point (single-node changes cycling, e.g. nodes of zero slip rate on a
       symmetry line), all statuses are decided together by the Alart-Curnier solve
       of the step 1e-6 of a sample ahead along the segment (cones as in 5): its
       classification (OPEN / STICK / SLIP with the sign of the friction force;
       grazing nodes as in 5) becomes the status set, the state stays at the point.
       A second return raises ContactConvergenceError.
    7. friction change: ``mu`` or ``mu_kinetic`` changed since the state was solved (set
       between calls, e.g. sweat) is an event at the current load, before the path goes
       on: the breakaway cascade of 5 at that load, with the new cones (nodes beyond the
       static cone break away, sliding nodes drop to the kinetic one). A plate that
       stands still then still carries only what the new friction holds.

``stepping="every"`` follows each sample interval as its own segment and solves the
piece at every sample (the reference); ``stepping="auto"`` takes the longest run of
samples with equal load increments as one segment, so only events (and changes of
the load's direction) cost a solve, and a load that does not move costs nothing.
Both meet the same events at the same points: the results agree to round-off.
A node is reported SLIP while its status is SLIP; the slip fraction is the weight
of SLIP nodes over the weight of touching nodes.

Both are written as the Alart-Curnier equations ``F(lam) = 0``::

    F_n = ln - max(0, ln - r g)
    F_t = lt - proj_[-b, b](lt - r w),     b = mu max(0, ln - r g)

and solved by a semismooth Newton method. ``F`` is piecewise linear, so a Newton
iterate is the solution of the linear system of the current piece: with the nodes
classified open / stick / slip, it enforces ``lam = 0`` (open), ``g = 0, w = 0``
(stick) and ``g = 0, lt = mu sign(tau) ln`` (slip): a primal-dual active-set step.
The system involves only the active nodes (``2 n_stick + n_slip`` unknowns), its LU
factors are reused while the classification does not change (most steps), and the
iteration starts from the previous step's classification, so a step usually costs
one triangular solve. If the classification cycles, the damped Newton method on
``F`` (backtracking on ``|F|^2``) takes over. ``r`` is ``1 / mean(diag C)`` (a
stiffness, so both terms have the units of force). Convergence: ``max |F| <= tol *
force scale``, with the force scale ``r * max(|g|, indent)``; a step that does not
converge raises :class:`ContactConvergenceError`.

Two backends follow the events, step for step: ``"cpp"`` (the default: the compiled
kernel ``contact_solver.hpp``, whose dense LU, triangular solves and compliance
products run as AVX2+FMA code where the CPU has it, else as x86-64 baseline code,
chosen at run time; it borders the LU of a nearby factored piece instead of
refactoring) and ``"python"`` (numpy/LAPACK, the reference: the path following in
:mod:`~tactile_mirror.contact.reference_path`, the solve of one load in
:mod:`~tactile_mirror.contact.reference_active_set`). The Alart-Curnier solve
serves the breakaway cascades (step 5) and the cycle rule (step 6). They meet the
same events at the same points with the same solves; ``tests/test_contact_cpp.py``
checks identical node states and forces within 1e-10 of their peak. Both leave the
contact history unchanged when a step fails.

This module holds :class:`ContactSolver`, which checks its parameters and every plate
position and hands each call to the backend; the node statuses, the result
:class:`~tactile_mirror.contact.step.ContactStep` and
:class:`~tactile_mirror.contact.step.ContactConvergenceError` are in
:mod:`~tactile_mirror.contact.step`.
"""
from __future__ import annotations

import numpy as np

from tactile_mirror._owner import NotCopyable
from tactile_mirror.checks import integer, real_number
from tactile_mirror.contact.model import RidgeModel
from tactile_mirror.contact.reference_path import ReferencePath
from tactile_mirror.contact.step import ContactConvergenceError, ContactStep

try:
    from tactile_mirror import _core
except ImportError:  # pragma: no cover - the compiled core is part of every install
    _core = None

__all__ = ["BACKENDS", "MAX_PLATE_POSITION", "STEPPINGS", "ContactSolver", "position_error"]

#: Implementations of the condensed solver: the compiled kernel and the Python reference.
BACKENDS = ("cpp", "python")

#: Stepping modes: "auto" solves at events only, "every" at every sample (the reference).
STEPPINGS = ("auto", "every")

#: The largest plate coordinate (y, z) a step takes, m, a ridge being millimetres: farther
#: is refused as a NaN is (``ValueError``, history unchanged). A finite 1e308 had
#: overflowed the solve into NaN forces that then stayed in the history.
MAX_PLATE_POSITION = 1.0

#: The largest iteration limit (0: fail at once, or skip the active-set phase): a C int.
MAX_ITERATIONS = 1_000_000


def position_error(y, z, zname: str = "z") -> ValueError:
    """The ValueError for a plate position ``(y, z)`` that is not finite or lies beyond
    :data:`MAX_PLATE_POSITION` (``zname``: what the caller calls ``z``)."""
    return ValueError(f"plate position must be finite and within {MAX_PLATE_POSITION:g} m, got y={float(y)!r}, "
                      f"{zname}={float(z)!r}")


def _check_params(p: dict, changed) -> None:
    """The solver's parameters ``p`` as a whole; the message names what was changed."""
    if not (np.isfinite(p["mu"]) and p["mu"] > 0):
        raise ValueError(f"mu must be a positive number, got {p['mu']!r}")
    if not (np.isfinite(p["mu_kinetic"]) and 0 < p["mu_kinetic"] <= p["mu"]):
        which = "mu" if "mu" in changed and "mu_kinetic" not in changed else "mu_kinetic"
        raise ValueError(f"{which} must keep 0 < mu_kinetic <= mu, got mu = {p['mu']!r}, mu_kinetic = "
                         f"{p['mu_kinetic']!r} (set_friction changes both at once)")
    if not (0 < p["tol"] < 1e-2):
        raise ValueError(f"tol must be in (0, 1e-2), got {p['tol']!r}")


class ContactSolver(ReferencePath, NotCopyable):
    """History-dependent quasi-static contact of one ridge with the plate.

    Parameters
    ----------
    model : RidgeModel
    mu : float
        Static Coulomb friction coefficient (> 0).
    mu_kinetic : float or None
        Kinetic coefficient, ``0 < mu_kinetic <= mu`` (default: ``mu``, plain Coulomb).
    tol : float
        Relative tolerance of the Alart-Curnier residual (default 1e-10).
    max_iter : int
        Newton iterations per step before :class:`ContactConvergenceError`.
    reduced : bool
        True (default): surface displacements from the condensed compliance. False:
        from a sparse solve with the full stiffness at every evaluation (the unreduced
        reference, same answers, much slower; always run by the Python backend).
    backend : {"cpp", "python"}
        Implementation of the condensed solver (see the module docstring): the
        compiled kernel (default) or the Python reference. ``mu``, ``mu_kinetic``,
        ``tol``, ``max_iter`` and ``max_active_set_iter`` may be changed between steps
        with either.
    """

    _copy_hint = "make a new one from the same arguments and carry the history with set_state(get_state())"

    def __init__(self, model: RidgeModel, mu: float, tol: float = 1e-10, max_iter: int = 60,
                 reduced: bool = True, mu_kinetic: float | None = None, backend: str = "cpp") -> None:
        mu = real_number(mu, "mu")
        mu_k = mu if mu_kinetic is None else real_number(mu_kinetic, "mu_kinetic")
        params = {"mu": mu, "mu_kinetic": mu_k, "tol": real_number(tol, "tol"),
                  "max_iter": integer(max_iter, "max_iter", 0, MAX_ITERATIONS), "max_active_set_iter": 25}
        _check_params(params, ("mu_kinetic",) if mu_kinetic is not None else ("mu",))
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self._kernel = None
        self.model = model
        self.reduced = bool(reduced)
        n = model.n_nodes
        self._n = n
        C = model.compliance
        # u = C f = C P lam with P = diag(1, -1): columns of the normal block flip sign
        self._CP = np.concatenate([C[:, :n], -C[:, n:]], axis=1)
        self._r = 1.0 / float(np.mean(np.diag(C)))
        # slip increments below this count as no motion (round-off is ~1e-19 m)
        self._w_tol = 1e-11 * model.geometry.height
        # event tolerances: gaps (m) and forces (N/m) this close to zero are zero
        self._g_tol = 1e-14 * model.geometry.height
        self._f_tol = 1e-12 * self._r * model.geometry.height
        # an event function must fall by more than this over a piece (round-off of a
        # constant one is ~1e-16 of the forces; a coarser bound would delay slow
        # crossings by a sample in the per-sample stepping only)
        self._evt_tol = np.array([1e-16, 1e-15 * self._r, 1e-15 * self._r, 1e-15 * self._r])[:, None] \
            * model.geometry.height
        self._params = params
        self.backend = backend if self.reduced else "python"
        if self.backend == "cpp":
            if _core is None:  # pragma: no cover
                raise ImportError("backend='cpp' needs the compiled core (tactile_mirror._core)")
            self._kernel = _core._ContactSolver(np.ascontiguousarray(C, dtype=np.float64), model.node_z,
                                                model.weights, self._r, self._w_tol)
            self._kernel.set_params(**self._params)
            self._kernel.set_event_tolerances(self._g_tol, self._f_tol, float(self._evt_tol[0, 0]),
                                              float(self._evt_tol[1, 0]))
        self.reset()

    # Parameters: plain attributes for the user, pushed to the kernel when set. All are
    # checked together and kept only once the kernel took them: a refused value (or a
    # kernel busy in another thread) leaves every parameter as it was.
    def _set_params(self, **changes) -> None:
        new = {**self._params, **changes}
        _check_params(new, changes)
        if self._kernel is not None:
            self._kernel.set_params(**new)
        self._params = new

    def set_friction(self, mu: float, mu_kinetic: float | None = None) -> None:
        """Change both friction coefficients at once (``0 < mu_kinetic <= mu``; default
        ``mu_kinetic = mu``), checked together: setting ``mu`` and ``mu_kinetic`` one
        after the other can pass through a pair that is not allowed."""
        mu = real_number(mu, "mu")
        self._set_params(mu=mu, mu_kinetic=mu if mu_kinetic is None else real_number(mu_kinetic, "mu_kinetic"))

    mu = property(lambda self: self._params["mu"], lambda self, v: self._set_params(mu=real_number(v, "mu")),
                  doc="Static Coulomb friction coefficient (>= mu_kinetic; see set_friction).")
    mu_kinetic = property(lambda self: self._params["mu_kinetic"],
                          lambda self, v: self._set_params(mu_kinetic=real_number(v, "mu_kinetic")),
                          doc="Kinetic Coulomb friction coefficient (<= mu).")
    tol = property(lambda self: self._params["tol"], lambda self, v: self._set_params(tol=real_number(v, "tol")),
                   doc="Relative tolerance of the Alart-Curnier residual, in (0, 1e-2).")
    max_iter = property(lambda self: self._params["max_iter"],
                        lambda self, v: self._set_params(max_iter=integer(v, "max_iter", 0, MAX_ITERATIONS)),
                        doc="Damped-Newton iterations per step before ContactConvergenceError.")
    max_active_set_iter = property(lambda self: self._params["max_active_set_iter"],
                                   lambda self, v: self._set_params(
                                       max_active_set_iter=integer(v, "max_active_set_iter", 0, MAX_ITERATIONS)),
                                   doc="Active-set iterations per step before the damped-Newton fallback (25).")

    # Solves and events so far: the compiled kernel's counts, read when asked (so a
    # step need not copy them), or the Python backend's own.
    @property
    def solves(self) -> int:
        """Piece solves so far (since the last reset)."""
        return self._kernel.solves if self._kernel is not None else self._solves

    @solves.setter
    def solves(self, value: int) -> None:
        self._solves = value

    @property
    def events(self) -> int:
        """Status changes so far (since the last reset)."""
        return self._kernel.events if self._kernel is not None else self._events

    @events.setter
    def events(self, value: int) -> None:
        self._events = value

    def get_state(self) -> dict:
        """The contact history (copies): forces ``lam`` (2n), ``uy_prev`` (n, m),
        ``s_prev`` (m), the classification ``state`` and slip ``sign`` the next step
        starts from, and ``sliding`` (the nodes on the kinetic cone)."""
        if self._kernel is not None:
            return self._kernel.get_history()
        return self._reference_history()

    def set_state(self, state: dict) -> None:
        """Restore a history from :meth:`get_state` (of either backend)."""
        n = self._n
        lam = np.array(state["lam"], dtype=np.float64)
        uy = np.array(state["uy_prev"], dtype=np.float64)
        cls = np.array(state["state"], dtype=np.int8)
        sign = np.array(state["sign"], dtype=np.float64)
        sliding = np.array(state["sliding"], dtype=bool)
        for name, a, size in (("lam", lam, 2 * n), ("uy_prev", uy, n), ("state", cls, n), ("sign", sign, n),
                              ("sliding", sliding, n)):
            if a.shape != (size,):
                raise ValueError(f"state[{name!r}] must have shape ({size},), got {a.shape}")
        s_prev = float(state["s_prev"])
        if self._kernel is not None:
            self._kernel.set_history(lam, uy, s_prev, cls, sign, sliding, state.get("z_prev"))
            return
        self._set_reference_history(lam, s_prev, cls, sign, state.get("z_prev"))

    def reset(self) -> None:
        """Back to the undeformed, unloaded state."""
        self.solves = 0
        self.events = 0
        if self._kernel is not None:
            self._kernel.reset()
            return
        self._reset_reference()

    def step(self, plate_y: float, plate_z: float) -> ContactStep:
        """Advance to the plate position (``plate_y``: tangential displacement, m;
        ``plate_z``: height of the plate face in ridge coordinates, m).

        The solver state (forces, surface position) is updated only when the step
        converges.
        """
        y, z = float(plate_y), float(plate_z)
        # plain float comparisons: np.isfinite costs about 1 us a call, a tenth of
        # the compiled step
        if not (abs(y) <= MAX_PLATE_POSITION and abs(z) <= MAX_PLATE_POSITION):  # (NaN fails too)
            raise position_error(plate_y, plate_z)
        if self._kernel is not None:
            status, f, u, state, frac, it = self._kernel.step(y, z)
            if status:
                self._raise_status(status, plate_y, plate_z)
            return ContactStep(forces=f, displacement=u, state=state, slip_fraction=frac, iterations=it)
        return self._step_reference(y, z)

    def follow(self, plate_y: np.ndarray, plate_z: np.ndarray, stepping: str = "auto",
               lam_out: np.ndarray | None = None, u_out: np.ndarray | None = None,
               state_out: np.ndarray | None = None) -> tuple[int, int]:
        """Follow the plate through the samples ``(plate_y[k], plate_z[k])`` (m), the
        load moving linearly from each sample to the next, starting from the current
        state (see "Event-driven path following" in the module docstring; the compiled
        backend runs the same steps in one call without the GIL).

        ``stepping="every"`` solves the piece at every sample; ``"auto"`` solves only
        where the status of a node changes (and where the direction of the load
        changes) and fills the samples between from the linear response. Both resolve
        every event at its own point. The contact forces ``lam = (lt, ln)`` (N/m),
        surface displacements (m) and node states of each sample go to the rows of
        ``lam_out``, ``u_out`` and ``state_out`` (each optional, ``(len(plate_y), 2n)``
        / ``(len(plate_y), n)``). Returns ``(solves, events)`` of this call (also
        accumulated in :attr:`solves` and :attr:`events`). On an error the history is
        what it was before the call.
        """
        if stepping not in STEPPINGS:
            raise ValueError(f"stepping must be one of {STEPPINGS}, got {stepping!r}")
        ys = np.asarray(plate_y, dtype=np.float64).ravel()
        zs = np.asarray(plate_z, dtype=np.float64).ravel()
        if ys.shape != zs.shape:
            raise ValueError(f"plate_y and plate_z must have the same length, got {ys.size} and {zs.size}")
        ok = (np.abs(ys) <= MAX_PLATE_POSITION) & (np.abs(zs) <= MAX_PLATE_POSITION)  # (NaN fails too)
        if not np.all(ok):
            k = int(np.flatnonzero(~ok)[0])
            raise position_error(ys[k], zs[k])
        N, n = ys.size, self._n
        lam_out = np.empty((N, 2 * n)) if lam_out is None else lam_out
        if self._kernel is not None:
            status, solves, events = self._kernel.follow(ys, zs, stepping == "every", lam_out, u_out, state_out)
            if status:
                self._raise_status(status, *self._kernel.error_point())
            return solves, events
        return self._follow_reference(ys, zs, stepping == "every", lam_out, u_out, state_out)

    def _raise_status(self, status: int, plate_y: float, plate_z: float):
        """The exception of the reference implementation for a kernel status."""
        info, residual, atol = self._kernel.error()
        if status == 1:
            raise position_error(plate_y, plate_z)
        if status == 2:
            raise ContactConvergenceError(f"singular contact system (LU getrf info={info})")
        if status == 3:
            raise ContactConvergenceError(f"singular contact Jacobian at iteration {info}")
        if status == 4:
            raise ContactConvergenceError(
                f"contact did not converge in {self.max_iter} iterations (residual {residual:.3e} N/m, "
                f"tolerance {atol:.3e}); plate at y={plate_y:.6g} m, z={plate_z:.6g} m, mu={self.mu}"
            )
        if status == 5:
            raise ContactConvergenceError(
                f"node statuses cycle at the plate position y={plate_y:.6g} m, z={plate_z:.6g} m")
        raise RuntimeError(f"contact kernel returned unknown status {status}")  # pragma: no cover
