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
refactoring) and ``"python"`` (numpy/LAPACK, the reference). The Alart-Curnier solve
serves the breakaway cascades (step 5) and the cycle rule (step 6). They meet the
same events at the same points with the same solves; ``tests/test_contact_cpp.py``
checks identical node states and forces within 1e-10 of their peak. Both leave the
contact history unchanged when a step fails.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgetrf, dgetrs

from tactile_mirror._checks import integer, real_number
from tactile_mirror._owner import NotCopyable
from tactile_mirror.contact.model import RidgeModel

try:
    from tactile_mirror import _core
except ImportError:  # pragma: no cover - the compiled core is part of every install
    _core = None

__all__ = ["BACKENDS", "OPEN", "SLIP", "STEPPINGS", "STICK", "ContactConvergenceError", "ContactSolver", "ContactStep"]

#: Implementations of the condensed solver: the compiled kernel and the Python reference.
BACKENDS = ("cpp", "python")

#: Stepping modes: "auto" solves at events only, "every" at every sample (the reference).
STEPPINGS = ("auto", "every")

OPEN, STICK, SLIP = 0, 1, 2

#: The largest plate coordinate (y, z) a step takes, m, a ridge being millimetres: farther
#: is refused as a NaN is (``ValueError``, history unchanged). A finite 1e308 had
#: overflowed the solve into NaN forces that then stayed in the history.
MAX_PLATE_POSITION = 1.0


def position_error(y, z, zname: str = "z") -> ValueError:
    return ValueError(f"plate position must be finite and within {MAX_PLATE_POSITION:g} m, got y={float(y)!r}, "
                      f"{zname}={float(z)!r}")


class ContactConvergenceError(RuntimeError):
    """The semismooth Newton iteration did not reach its tolerance."""


@dataclass
class ContactStep:
    """Result of one quasi-static step of one ridge."""

    forces: np.ndarray  # (2n,) nodal forces on the ridge f = (f_y, f_z), N/m
    displacement: np.ndarray  # (2n,) surface displacements (u_y, u_z), m
    state: np.ndarray  # (n,) OPEN / STICK / SLIP
    slip_fraction: float  # share of the contact length that slips, 0..1
    iterations: int

    @property
    def in_contact(self) -> bool:
        return bool(np.any(self.state != OPEN))

    @property
    def gross_slip(self) -> bool:
        """Every node in contact slips."""
        return self.in_contact and not np.any(self.state == STICK)


SEEN_CAP = 256  # status sets kept per point by the cycle rule (the kernel's kSeenCap)
MAX_ITERATIONS = 1_000_000  # iteration limits (0: fail at once, or skip the active-set phase): a C int


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


class _SeenSets(set):
    """The cycle rule's status sets met at one point. As the kernel's (kSeenCap), at most
    SEEN_CAP additions per point, repeats counted: a resolve can lead back into a cycle
    through a set that was not its result, and the loop would never end."""

    added = 0

    def add(self, entry) -> None:
        if self.added >= SEEN_CAP:
            raise _SeenFull
        self.added += 1
        super().add(entry)

    def clear(self) -> None:
        self.added = 0
        super().clear()


class _SeenFull(Exception):
    pass


class ContactSolver(NotCopyable):
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
        return self._kernel.solves if self._kernel is not None else self._solves

    @solves.setter
    def solves(self, value: int) -> None:
        self._solves = value

    @property
    def events(self) -> int:
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
        return {"lam": self._lam.copy(), "uy_prev": self._uy_prev.copy(), "s_prev": self._s_prev,
                "state": self._state.copy(), "sign": self._sign.copy(), "sliding": self._state == SLIP,
                "z_prev": self._z_prev}

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
        self._lam, self._s_prev = lam, s_prev
        self._state, self._sign, self._sliding = cls, sign, sliding
        self._u = self._displacement(lam)
        self._uy_prev = self._u[:n].copy()
        z_prev = state.get("z_prev")
        if z_prev is None and np.any(cls != OPEN):
            # the plate face is where the touching nodes are
            k = int(np.argmax(lam[n:]))
            z_prev = float(self.model.node_z[k] + self._u[n + k])
        self._z_prev = None if z_prev is None else float(z_prev)
        self._lu_key = None
        self._unit_key = None
        self._friction_applied = (self.mu, self.mu_kinetic)  # a given history holds under the current friction

    def reset(self) -> None:
        """Back to the undeformed, unloaded state."""
        self.solves = 0
        self.events = 0
        if self._kernel is not None:
            self._kernel.reset()
            return
        n = self._n
        self._lam = np.zeros(2 * n)
        self._uy_prev = np.zeros(n)
        self._s_prev = 0.0
        self._state = np.zeros(n, dtype=np.int8)
        self._sign = np.zeros(n)
        self._sliding = np.zeros(n, dtype=bool)
        self._u = np.zeros(2 * n)
        self._z_prev = None  # plate height of the current state (None: not placed yet)
        self._friction_applied = (self.mu, self.mu_kinetic)  # the cones the state was solved with
        self._lu_key = None
        self._lu = None
        self._unit_key = None
        self._G = None
        self._base = None
        self._cap_rows = None
        self.solves = 0
        self.events = 0
        self.factorizations = 0
        self.updates = 0

    def _displacement(self, lam: np.ndarray) -> np.ndarray:
        if self.reduced:
            return self._CP @ lam
        n = self._n
        f = np.concatenate([lam[:n], -lam[n:]])
        return self.model.contact_displacement_full(f)

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
        lam = np.empty((1, 2 * self._n))
        u = np.empty((1, 2 * self._n))
        state = np.empty((1, self._n), dtype=np.int8)
        solves0 = self.solves
        self.follow(np.array([y], dtype=np.float64), np.array([z], dtype=np.float64), "every",
                    lam, u, state)
        return self._report(lam[0], u[0], state[0], self.solves - solves0)

    def _solve_load(self, state, sign, plate_y, plate_z, ds, atol, exact=False):
        """Solve the step to ``(plate_y, plate_z)`` with the cones ``self._mu_node``,
        starting from the classification ``(state, sign)``: active-set iterations,
        then the damped Newton method if they cycle. Returns ``(lam, u, state, sign, its)``.

        ``exact``: go on while the classification still changes, even once the residual
        is within ``atol``, so the answer is the exact solution of its piece (not one of
        the pieces within the tolerance: the event stepping's two modes must agree to
        round-off); if the pieces cycle, the first answer within the tolerance."""
        it = 0
        first = None
        for it in range(1, self.max_active_set_iter + 1):
            lam, u = self._solve_piece(state, sign, plate_z, ds)
            F, new_state, new_sign = self._classify(lam, u, plate_z, ds)
            same = np.array_equal(new_state, state) and np.array_equal(new_sign[state == SLIP], sign[state == SLIP])
            if np.max(np.abs(F)) <= atol:
                if not exact or same:
                    return lam, u, new_state, new_sign, it
                if first is None:
                    first = (lam, u, new_state, new_sign)
            elif same:
                break  # same piece but not converged: round-off trouble, use Newton
            state, sign = new_state, new_sign
        if first is not None:
            return (*first, it)
        start = self._lam.copy()
        lam, u, it2 = self._damped_newton(start, plate_y, plate_z, ds, atol)
        _, new_state, new_sign = self._classify(lam, u, plate_z, ds)
        return lam, u, new_state, new_sign, it + it2

    # ------------------------------------------------------------ path following
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
        snapshot = self._snapshot()
        solves0, events0 = self.solves, self.events
        try:
            if N and self._z_prev is None:
                # first placement: the plate arrives from above, at the first sample's
                # y, no lower than the crown (nothing touches before)
                self._s_prev = float(ys[0])
                self._z_prev = max(float(zs[0]), float(np.max(self.model.node_z)))
            if N:
                self._settle_friction()
            k = 0
            while k < N:
                if stepping == "every":
                    end = k + 1
                else:
                    end = self._segment_end(ys, zs, k)
                L = end - k
                thetas = np.arange(1, L + 1) / L
                self._follow_segment(float(ys[end - 1]), float(zs[end - 1]), thetas, 1e-9 / L,
                                     stepping == "every" or L > 1, lam_out[k:end],
                                     None if u_out is None else u_out[k:end],
                                     None if state_out is None else state_out[k:end])
                k = end
        except BaseException:
            self._restore(snapshot)
            raise
        return self.solves - solves0, self.events - events0

    def _segment_end(self, ys, zs, k):
        """End (exclusive) of the longest run of samples from ``k`` whose load
        increments equal the first one (to 1e-9 of its size): one straight segment."""
        N = ys.size
        y0, z0 = (self._s_prev, self._z_prev) if k == 0 else (ys[k - 1], zs[k - 1])
        dy, dz = ys[k] - y0, zs[k] - z0
        tol = 1e-9 * max(abs(dy), abs(dz))
        end, chunk = k + 1, 64
        while end < N:
            hi = min(N, end + chunk)
            ok = ((np.abs(np.diff(ys[end - 1:hi]) - dy) <= tol)
                  & (np.abs(np.diff(zs[end - 1:hi]) - dz) <= tol))
            if not ok.all():
                return end + int(np.argmin(ok))
            end, chunk = hi, 2 * chunk
        return N

    def _settle_friction(self):
        """A change of ``mu`` / ``mu_kinetic`` since the state was solved is an event at the
        current load: the nodes beyond their new static cone break away, the sliding ones
        drop to the new kinetic cone, and what they shed is carried at that load (the
        breakaway cascade), before the path goes on. Without it a load standing still (or
        moving so as to unload those nodes) would keep tractions the new friction cannot
        carry."""
        friction = (self.mu, self.mu_kinetic)
        if self._friction_applied == friction:
            return
        if self._z_prev is not None and np.any(self._state != OPEN):
            if self._cascade():
                self.events += 1
            self._unit_key = None
        self._friction_applied = friction

    def _snapshot(self):
        return (self._lam.copy(), self._u.copy(), self._uy_prev.copy(), self._s_prev, self._z_prev,
                self._state.copy(), self._sign.copy(), self.solves, self.events, self._friction_applied)

    def _restore(self, snap):
        (self._lam, self._u, self._uy_prev, self._s_prev, self._z_prev, self._state, self._sign,
         self.solves, self.events, self._friction_applied) = snap
        self._sliding = self._state == SLIP
        self._lu_key = None

    def _unit_response(self):
        """Response of ``(lam, u)`` to a unit plate displacement along y and a unit rise
        of the plate, for the current node statuses (cached with the factorisation)."""
        key = (self._state.tobytes(), self._sign.tobytes(), self.mu, self.mu_kinetic)
        if self._unit_key != key:
            self._mu_node = np.where(self._state == SLIP, self.mu_kinetic, self.mu)
            A = np.count_nonzero(self._state != OPEN)
            T = np.count_nonzero(self._state == STICK)
            rs = self._solve_rhs(self._state, self._sign, np.concatenate([np.zeros(A), np.ones(T)]))
            rz = self._solve_rhs(self._state, self._sign, np.concatenate([np.ones(A), np.zeros(T)]))
            self._unit = (rs, rz, self._displacement(rs), self._displacement(rz))
            self._unit_key = key
            self.solves += 1
        return self._unit

    def _follow_segment(self, s1, z1, thetas, eps, direct, lam_out, u_out, state_out):
        """Move the load linearly from the current ``(s, z)`` to ``(s1, z1)``, resolving
        every event at its point; fill the samples at ``thetas`` (in (0, 1]).

        ``direct``: the end of each piece by a solve with the piece's factors (the
        per-sample reference) instead of from the unit responses."""
        n = self._n
        s0, z0p = self._s_prev, self._z_prev
        th, j, ns = 0.0, 0, thetas.size
        seen = _SeenSets()  # status sets met at the current point (a cycle guard)
        # 1e-6 of a sample along the segment: the step of the cycle rule (the same in
        # both steppings, whatever the segment's length)
        tiny = (1e3 * eps * (s1 - s0), 1e3 * eps * (z1 - z0p))
        if s1 == s0 and z1 == z0p:
            # the load does not move: nothing slides (a sliding node's rate is zero)
            if np.any(self._state == SLIP):
                self._state = np.where(self._state == SLIP, STICK, self._state).astype(np.int8)
                self._sign = np.where(self._state == SLIP, self._sign, 0.0)
                self.events += 1
            self._fill(lam_out, u_out, state_out, slice(0, ns), self._lam, self._u, None, None, 0.0)
            return
        while True:
            if th >= 1.0:
                self._fill(lam_out, u_out, state_out, slice(j, ns), self._lam, self._u, None, None, 0.0)
                return
            sc, zc = self._s_prev, self._z_prev
            lam_c, u_c = self._lam, self._u
            state, sign = self._state, self._sign
            if not np.any(state != OPEN) and not np.any(lam_c):
                lam1, u1 = lam_c, u_c  # nothing touches: the ridge stays at rest
            elif direct:
                self._mu_node = np.where(state == SLIP, self.mu_kinetic, self.mu)
                lam1, u1 = self._solve_piece(state, sign, z1, s1 - sc)
                self.solves += 1
            else:
                rs, rz, us, uz = self._unit_response()
                lam1 = lam_c + (s1 - sc) * rs + (z1 - zc) * rz
                u1 = u_c + (s1 - sc) * us + (z1 - zc) * uz
            # a sliding node's slip rate over the rest of the segment must oppose its
            # friction force; where it does not (it stops or would reverse), it sticks here
            slide = state == SLIP
            if np.any(slide):
                rate = (u1[:n] - u_c[:n]) - (s1 - sc)
                bad = slide & (sign * rate >= -1e-9 * (abs(s1 - sc) + abs(z1 - zc)))
                if np.any(bad):
                    self._state = np.where(bad, STICK, state).astype(np.int8)
                    self._sign = np.where(bad, 0.0, sign)
                    self._changed(seen, tiny)
                    continue
            frac, kinds = self._first_event(lam_c, u_c, lam1, u1, zc, z1, eps / (1.0 - th))
            th_e = np.inf if frac is None else th + frac * (1.0 - th)
            # samples before the event come from this piece (an event within eps of a
            # sample is resolved before that sample)
            j2 = j + int(np.searchsorted(thetas[j:], th_e - eps, side="left"))
            if j2 > j:
                self._fill(lam_out, u_out, state_out, slice(j, j2), lam_c, u_c, lam1, u1,
                           (thetas[j:j2] - th) / (1.0 - th))
            j = j2
            if frac is None:
                self._lam, self._u = lam1, u1
                self._uy_prev = u1[:n].copy()
                self._s_prev, self._z_prev = s1, z1
                if j < ns:  # pragma: no cover - every sample is at or before theta = 1
                    self._fill(lam_out, u_out, state_out, slice(j, ns), lam1, u1, None, None, 0.0)
                return
            # move to the event point (not past the end of the segment)
            th_e = min(th_e, 1.0)
            f = (th_e - th) / (1.0 - th)
            self._lam = lam_c + f * (lam1 - lam_c)
            self._u = u_c + f * (u1 - u_c)
            self._uy_prev = self._u[:n].copy()
            self._s_prev = s0 + th_e * (s1 - s0) if th_e < 1.0 else s1
            self._z_prev = z0p + th_e * (z1 - z0p) if th_e < 1.0 else z1
            if th_e > th:
                seen.clear()
            th = th_e
            self._apply_events(kinds)
            self._changed(seen, tiny)

    def _changed(self, seen, tiny):
        """Count a status change at the current point. If the statuses return to a set
        already met at this point (single-node changes cycling, e.g. nodes whose slip
        rate is about zero), the statuses of all nodes are decided together: by the
        Alart-Curnier solve of a short step (1e-6 of a sample) ahead."""
        self.events += 1
        key = self._state.tobytes() + self._sign.tobytes()
        cycle = ContactConvergenceError(
            f"node statuses cycle at the plate position y={self._s_prev:.6g} m, z={self._z_prev:.6g} m")
        try:
            if key not in seen:
                seen.add(key)
                return
            if ("resolved", key) in seen:
                raise cycle
            self._resolve_point(tiny)
            seen.add(("resolved", self._state.tobytes() + self._sign.tobytes()))
            seen.add(self._state.tobytes() + self._sign.tobytes())
        except _SeenFull:
            raise cycle from None

    def _resolve_point(self, tiny):
        """Statuses at the current point from the Alart-Curnier solve of the step
        ``tiny = (dy, dz)`` ahead (cones: kinetic on SLIP nodes, static on the others);
        the state stays at the current point."""
        n = self._n
        sc, zc = self._s_prev, self._z_prev
        ds, zp = tiny[0], zc + tiny[1]
        prev, prev_sign = self._state, self._sign
        self._mu_node = np.where(prev == SLIP, self.mu_kinetic, self.mu)
        scale = self._r * max(float(np.max(self.model.node_z) - zp), 1e-9, float(np.max(np.abs(self._uy_prev))))
        _lam, u, state, sign, _it = self._solve_load(prev.copy(), prev_sign.copy(), sc + ds, zp, ds,
                                                     self.tol * scale, exact=True)
        self.solves += 1
        gap = zp - (self.model.node_z + u[n:])
        grazing = (state == OPEN) & (prev != OPEN) & (gap <= self._g_tol)
        new = np.where(grazing, prev, state).astype(np.int8)
        self._state = new
        self._sign = np.where(new == SLIP, np.where(state == SLIP, sign, prev_sign), 0.0)

    def _fill(self, lam_out, u_out, state_out, rows, lam_c, u_c, lam1, u1, frac):
        if lam1 is None:
            lam_out[rows] = lam_c
            if u_out is not None:
                u_out[rows] = u_c
        else:
            frac = np.asarray(frac)[:, None]
            lam_out[rows] = lam_c + frac * (lam1 - lam_c)
            if u_out is not None:
                u_out[rows] = u_c + frac * (u1 - u_c)
        if state_out is not None:
            state_out[rows] = self._state

    def _first_event(self, lam_c, u_c, lam1, u1, zc, z1, eps):
        """First point ``frac`` in [0, 1 + eps] of the piece from ``(lam_c, u_c)`` to
        ``(lam1, u1)`` where a node's status must change, and the events there:
        ``(node indices, kind)`` with kind 0 contact, 1 separation, 2 / 3 breakaway
        with the friction force along +y / -y. ``(None, None)`` if there is none."""
        n, mu = self._n, self.mu
        z0 = self.model.node_z
        state = self._state
        # feasibility functions that must stay >= 0, one row per event kind
        phi_c = np.stack([zc - z0 - u_c[n:], lam_c[n:], mu * lam_c[n:] - lam_c[:n], mu * lam_c[n:] + lam_c[:n]])
        phi_1 = np.stack([z1 - z0 - u1[n:], lam1[n:], mu * lam1[n:] - lam1[:n], mu * lam1[n:] + lam1[:n]])
        mask = np.stack([state == OPEN, state != OPEN, state == STICK, state == STICK])
        tol = self._evt_tol
        drop = phi_c - phi_1
        cand = mask & (drop > tol) & (phi_1 < 0)
        if not np.any(cand):
            return None, None
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.where(cand, np.clip(phi_c, 0.0, None) / np.where(cand, drop, 1.0), np.inf)
        first = float(frac.min())
        if first > 1.0 + eps:
            return None, None
        kinds, nodes = np.nonzero(frac <= first + eps)
        return first, (nodes, kinds)

    def _apply_events(self, events) -> int:
        """Change the status of the event nodes at the current point; a breakaway drops
        to the kinetic cone and sets off the cascade at this load. Returns the number
        of status changes."""
        nodes, kinds = events
        n = self._n
        state, sign, lam = self._state.copy(), self._sign.copy(), self._lam.copy()
        for i, kind in zip(nodes.tolist(), kinds.tolist()):
            if kind == 0:  # gap closes: the node touches and sticks where it is
                state[i], sign[i] = STICK, 0.0
            elif kind == 1:  # pressure reaches zero: the node lifts off
                state[i], sign[i] = OPEN, 0.0
                lam[i] = lam[n + i] = 0.0
            else:  # traction reaches the static cone: the node breaks away
                state[i], sign[i] = SLIP, (1.0 if kind == 2 else -1.0)
        self._state, self._sign, self._lam = state, sign, lam
        self._u = self._displacement(lam)
        self._uy_prev = self._u[:n].copy()
        changes = len(nodes)
        broke = nodes[kinds >= 2]
        # a breakaway sheds (mu - mu_kinetic) * ln: a cascade only where that is a load
        if broke.size and (self.mu - self.mu_kinetic) * float(np.max(lam[n + broke])) > self._f_tol:
            changes += self._cascade()
        return changes

    def _cascade(self) -> int:
        """The breakaway cascade at the current load (the module docstring, step 4):
        sliding nodes carry the kinetic cone, the others the static one; solve the
        load again from the current surface position, and drop every node that slides
        under its static cone to the kinetic one, until none does. Returns the number
        of status changes."""
        n, mu_k = self._n, self.mu_kinetic
        prev, prev_sign = self._state, self._sign
        z0 = self.model.node_z
        zp, sp = self._z_prev, self._s_prev
        self._mu_node = np.where(prev == SLIP, mu_k, self.mu)
        scale = self._r * max(float(np.max(z0) - zp), 1e-9, float(np.max(np.abs(self._uy_prev))))
        atol = self.tol * scale
        state, sign = prev.copy(), prev_sign.copy()
        for _ in range(n + 1):
            lam, u, state, sign, _it = self._solve_load(state, sign, sp, zp, 0.0, atol, exact=True)
            self.solves += 1
            moving = np.abs(u[:n] - self._uy_prev) > self._w_tol
            broke = (state == SLIP) & moving & (self._mu_node > mu_k)
            if not np.any(broke):
                break
            self._mu_node = np.where(broke, mu_k, self._mu_node)
        # statuses after the jump: a node that moved on its cone slides; a sliding node
        # still on its kinetic cone keeps sliding (its rate decides in the next piece);
        # any other touching node sticks where it is
        on_kinetic = np.abs(lam[:n]) >= mu_k * lam[n:] - self._f_tol
        slide_moved = (state == SLIP) & moving
        slide_kept = (prev == SLIP) & (state != OPEN) & ~moving & on_kinetic
        # a touching node at zero pressure whose gap stays closed keeps its status (the
        # next piece decides whether it lifts off)
        gap = zp - (z0 + u[n:])
        grazing = (state == OPEN) & (prev != OPEN) & (gap <= self._g_tol)
        new = np.where(state == OPEN, OPEN, np.where(slide_moved | slide_kept, SLIP, STICK)).astype(np.int8)
        new_sign = np.where(slide_moved, sign, np.where(slide_kept, prev_sign, 0.0))
        new = np.where(grazing, prev, new).astype(np.int8)
        new_sign = np.where(grazing, prev_sign, new_sign)
        changes = int(np.sum(new != prev))
        self._state, self._sign = new, new_sign
        self._lam, self._u = lam, u
        self._uy_prev = u[:n].copy()
        return changes

    def _report(self, lam, u, state, iterations) -> ContactStep:
        n = self._n
        w = self.model.weights
        touching = state != OPEN
        total = float(w[touching].sum())
        frac = float(w[state == SLIP].sum()) / total if total > 0 else 0.0
        f = np.concatenate([lam[:n], -lam[n:]])
        return ContactStep(forces=f, displacement=u, state=state.astype(np.int8), slip_fraction=frac,
                           iterations=int(iterations))


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

    # -- one piece of the piecewise-linear system
    def _solve_piece(self, state, sign, plate_z, ds):
        """Forces and displacements of the piece ``(state, sign)`` at the plate height
        ``plate_z`` with the stuck nodes moved by ``ds`` from ``self._uy_prev``."""
        A = np.flatnonzero(state != OPEN)
        T = np.flatnonzero(state == STICK)
        rhs = np.concatenate([plate_z - self.model.node_z[A], self._uy_prev[T] + ds])
        lam = self._solve_rhs(state, sign, rhs)
        return lam, self._displacement(lam)

    def _solve_rhs(self, state, sign, rhs):
        """Solve the piece ``(state, sign)`` (cones ``self._mu_node``) for the right-hand
        side ``rhs = (u_z of the touching nodes, u_y of the stuck nodes)``.

        The reduced solver writes the piece as all ``2n`` equations, two per node
        (open: ``lt = 0, ln = 0``; stuck: ``u_y, u_z`` given; sliding: ``lt = coef ln``,
        ``u_z`` given; displacement rows scaled by ``r``), so a change of a few nodes'
        statuses changes a few rows. It keeps the LU factors of a base piece and solves
        a nearby piece through the capacitance matrix of the changed rows (Woodbury:
        ``O(n^2)`` per changed node and per solve instead of a new ``O(n^3)``
        factorisation), refined by one step against the piece's own equations; the base
        is refactored when more than ``n / 16`` nodes differ from it."""
        n, mu = self._n, self._mu_node
        T = np.flatnonzero(state == STICK)
        A = np.flatnonzero(state != OPEN)
        slip_coef = np.where(state == SLIP, mu * sign, 0.0)  # lt = slip_coef * ln on slip nodes
        if not self.reduced:
            x = self.model.solve_piece_full(A, T, slip_coef[A], rhs)
            lam = np.zeros(2 * n)
            lam[n + A] = x[:A.size]
            lam[A] += slip_coef[A] * x[:A.size]
            lam[T] = x[A.size:]
            return lam
        key = (state.tobytes(), slip_coef.tobytes())
        if key != self._lu_key:
            self._update_piece(state, slip_coef)
            self._lu_key = key
        b = np.zeros(2 * n)
        b[n + A] = self._r * rhs[:A.size]
        b[T] = self._r * rhs[A.size:]
        x = self._solve_factored(b)
        if self._cap_rows is not None:
            # one step of iterative refinement against the piece's own equations: the
            # capacitance solve alone loses up to 2e-11 of the forces (its matrix reaches
            # condition numbers of 1e5), which the path carries on to 6e-10
            x = x + self._solve_factored(b - self._piece_product(state, slip_coef, x))
        return x

    def _solve_factored(self, b):
        """Solve the current piece (base factors, and the capacitance of its changed rows)."""
        x, _ = dgetrs(*self._lu, b)
        if self._cap_rows is not None:
            x = x - self._cap_W @ dgetrs(*self._cap_lu, self._cap_V @ x)[0]
        return x

    def _piece_product(self, state, slip_coef, x):
        """The piece matrix (rows as in :meth:`_piece_rows`) times ``x``."""
        n = self._n
        Gx = self._G @ x
        return np.concatenate([np.where(state == STICK, Gx[:n], x[:n] - slip_coef * x[n:]),
                               np.where(state != OPEN, Gx[n:], x[n:])])

    def _piece_rows(self, state, slip_coef, nodes):
        """Rows ``nodes`` then ``n + nodes`` of the piece matrix (displacement rows scaled
        by ``r``: ``r u = G lam``, ``G = r C P``)."""
        n = self._n
        G = self._G
        m = nodes.size
        rows = np.zeros((2 * m, 2 * n))
        k = np.arange(m)
        st = state[nodes]
        stick, slip, opn = st == STICK, st == SLIP, st == OPEN
        rows[k[stick]] = G[nodes[stick]]
        rows[k[~stick], nodes[~stick]] = 1.0
        rows[k[slip], n + nodes[slip]] = -slip_coef[nodes[slip]]
        rows[m + k[~opn]] = G[n + nodes[~opn]]
        rows[m + k[opn], n + nodes[opn]] = 1.0
        return rows

    def _update_piece(self, state, slip_coef):
        """Make ``(state, slip_coef)`` the current piece: capacitance of the rows that
        differ from the base piece, or a new base."""
        n = self._n
        if self._G is None:
            self._G = self._r * self._CP
        nodes = None
        if self._base is not None:
            nodes = np.flatnonzero((self._base[0] != state) | (self._base[1] != slip_coef))
            if nodes.size > max(4, n // 16):
                nodes = None
        if nodes is None:
            K = np.empty((2 * n, 2 * n))
            idx = np.arange(n)
            K[np.concatenate([idx, n + idx])] = self._piece_rows(state, slip_coef, idx)
            lu, piv, info = dgetrf(K, overwrite_a=True)
            if info != 0:
                raise ContactConvergenceError(f"singular contact system (LAPACK getrf info={info})")
            self._lu = (lu, piv)
            self._base = (state.copy(), slip_coef.copy())
            self._base_cols = {}
            self._cap_rows = None
            self.factorizations += 1
            return
        if nodes.size == 0:
            self._cap_rows = None
            return
        rows = np.concatenate([nodes, n + nodes])
        V = self._piece_rows(state, slip_coef, nodes)
        cols = self._base_cols  # per base row: (its row of the base matrix, column of K0^-1)
        new = [r for r in rows.tolist() if r not in cols]
        if new:
            E = np.zeros((2 * n, len(new)))
            E[new, np.arange(len(new))] = 1.0
            Wn, _ = dgetrs(*self._lu, E)
            new_nodes = np.unique(np.array(new) % n)
            base_rows = self._piece_rows(self._base[0], self._base[1], new_nodes)
            where = {r: j for j, r in enumerate(np.concatenate([new_nodes, n + new_nodes]).tolist())}
            for j, r in enumerate(new):
                cols[r] = (base_rows[where[r]], Wn[:, j])
        V -= np.stack([cols[r][0] for r in rows.tolist()])
        W = np.stack([cols[r][1] for r in rows.tolist()], axis=1)
        cap = np.eye(rows.size) + V @ W
        lu, piv, info = dgetrf(cap)
        if info != 0:
            raise ContactConvergenceError(f"singular contact system (capacitance getrf info={info})")
        self._cap_rows, self._cap_W, self._cap_V, self._cap_lu = rows, W, V, (lu, piv)
        self.updates += 1

    def _classify(self, lam, u, plate_z, ds):
        n, r, mu = self._n, self._r, self._mu_node
        lt, ln = lam[:n], lam[n:]
        g = plate_z - (self.model.node_z + u[n:])
        w = (u[:n] - self._uy_prev) - ds
        an = ln - r * g
        act = an > 0
        b = mu * np.where(act, an, 0.0)
        tau = lt - r * w
        stick = act & (np.abs(tau) <= b)
        slip = act & ~stick
        sgn = np.sign(tau)
        F = np.concatenate([np.where(stick, r * w, np.where(slip, lt - b * sgn, lt)), np.where(act, r * g, ln)])
        state = np.where(stick, STICK, np.where(slip, SLIP, OPEN)).astype(np.int8)
        return F, state, np.where(slip, sgn, 0.0)

    def _damped_newton(self, lam, plate_y, plate_z, ds, atol):
        F, J, u = self._residual(lam, plate_z, ds)
        norm = np.max(np.abs(F))
        it = 0
        while norm > atol:
            if it >= self.max_iter:
                raise ContactConvergenceError(
                    f"contact did not converge in {self.max_iter} iterations (residual {norm:.3e} N/m, "
                    f"tolerance {atol:.3e}); plate at y={plate_y:.6g} m, z={plate_z:.6g} m, mu={self.mu}"
                )
            try:
                d = np.linalg.solve(J, -F)
            except np.linalg.LinAlgError as exc:
                raise ContactConvergenceError(f"singular contact Jacobian at iteration {it}") from exc
            t = 1.0
            merit = float(F @ F)
            while True:
                trial = lam + t * d
                F2, J2, u2 = self._residual(trial, plate_z, ds)
                if float(F2 @ F2) <= (1 - 1e-4 * t) * merit or t < 1e-6:
                    break
                t *= 0.5
            lam, F, J, u = trial, F2, J2, u2
            norm = np.max(np.abs(F))
            it += 1
        return lam, u, it

    def _residual(self, lam, plate_z, ds):
        """Alart-Curnier residual at ``lam`` and its generalised Jacobian."""
        n, r, mu = self._n, self._r, self._mu_node
        u = self._displacement(lam)
        F, state, sign = self._classify(lam, u, plate_z, ds)
        stick, slip = state == STICK, state == SLIP
        act = stick | slip
        CP = self._CP
        dg = -CP[n:]  # dg/dlam (n, 2n)
        dw = CP[:n]  # dw/dlam
        eye = np.eye(2 * n)
        et, en = eye[:n], eye[n:]
        Jn = np.where(act[:, None], r * dg, en)
        dslip = et - (mu * sign)[:, None] * (en - r * dg)
        Jt = np.where(stick[:, None], r * dw, np.where(slip[:, None], dslip, et))
        return F, np.concatenate([Jt, Jn]), u
