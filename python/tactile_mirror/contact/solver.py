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

The law, step by step (what both backends implement; ``n`` nodes)::

    1. cones: mu_i = mu_kinetic if node i slid in the previous step (reported SLIP),
       else mu (static).
    2. solve the step (previous plate position -> this one) with these cones: the
       Alart-Curnier equations below, from the previous classification.
    3. breakaway: B = {i : reported SLIP (on its cone and |w_i| > w_tol) and
       mu_i == mu > mu_kinetic}. If B is empty, accept the solution.
    4. cascade: mu_i = mu_kinetic for every i in B (all of one round at once, no
       ordering among them), solve the same step again (same plate position, same
       previous surface position ``u_y_prev``, warm start from the classification of
       step 3) and go back to 3. The set of kinetic cones only grows, so this ends in
       at most n rounds; with mu_kinetic == mu it never runs.
    5. accept: the history (u_y_prev, forces, classification) is the last solution's;
       nodes reported SLIP are the ones that slid, with the kinetic cone next step.

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

Two backends run this algorithm: ``"cpp"`` (the default: the compiled kernel
``contact_solver.hpp``, a few microseconds per step when the piece is unchanged; its
dense LU, triangular solves and compliance products run as AVX2+FMA code where the
CPU has it, else as x86-64 baseline code, chosen at run time) and
``"python"`` (numpy/LAPACK, the reference). They take the same steps in the same
order (the compiled one solves a piece near the last factored one by bordering its LU
instead of refactoring, with one step of iterative refinement) and agree to round-off (forces within 1e-10 relative, identical node states on
the paper's scenes and random ones: ``tests/test_contact_cpp.py``). Both leave the
contact history unchanged when a step fails.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgetrf, dgetrs

from .model import RidgeModel

try:
    from .. import _core
except ImportError:  # pragma: no cover - the compiled core is part of every install
    _core = None

__all__ = ["BACKENDS", "OPEN", "SLIP", "STICK", "ContactConvergenceError", "ContactSolver", "ContactStep"]

#: Implementations of the condensed solver: the compiled kernel and the Python reference.
BACKENDS = ("cpp", "python")

OPEN, STICK, SLIP = 0, 1, 2


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


class ContactSolver:
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

    def __init__(self, model: RidgeModel, mu: float, tol: float = 1e-10, max_iter: int = 60,
                 reduced: bool = True, mu_kinetic: float | None = None, backend: str = "cpp") -> None:
        if not (np.isfinite(mu) and mu > 0):
            raise ValueError(f"mu must be a positive number, got {mu!r}")
        mu_k = mu if mu_kinetic is None else mu_kinetic
        if not (np.isfinite(mu_k) and 0 < mu_k <= mu):
            raise ValueError(f"mu_kinetic must be in (0, mu], got {mu_kinetic!r}")
        if not (0 < tol < 1e-2):
            raise ValueError(f"tol must be in (0, 1e-2), got {tol!r}")
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
        self._params = {"mu": float(mu), "mu_kinetic": float(mu_k), "tol": float(tol), "max_iter": int(max_iter),
                        "max_active_set_iter": 25}
        self.backend = backend if self.reduced else "python"
        if self.backend == "cpp":
            if _core is None:  # pragma: no cover
                raise ImportError("backend='cpp' needs the compiled core (tactile_mirror._core)")
            self._kernel = _core._ContactSolver(np.ascontiguousarray(C, dtype=np.float64), model.node_z,
                                                model.weights, self._r, self._w_tol)
            self._kernel.set_params(**self._params)
        self.reset()

    # Parameters: plain attributes for the user, pushed to the kernel when set.
    def _set_param(self, name: str, value) -> None:
        self._params[name] = value
        if self._kernel is not None:
            self._kernel.set_params(**self._params)

    mu = property(lambda self: self._params["mu"], lambda self, v: self._set_param("mu", float(v)),
                  doc="Static Coulomb friction coefficient.")
    mu_kinetic = property(lambda self: self._params["mu_kinetic"],
                          lambda self, v: self._set_param("mu_kinetic", float(v)),
                          doc="Kinetic Coulomb friction coefficient (<= mu).")
    tol = property(lambda self: self._params["tol"], lambda self, v: self._set_param("tol", float(v)),
                   doc="Relative tolerance of the Alart-Curnier residual.")
    max_iter = property(lambda self: self._params["max_iter"],
                        lambda self, v: self._set_param("max_iter", int(v)),
                        doc="Damped-Newton iterations per step before ContactConvergenceError.")
    max_active_set_iter = property(lambda self: self._params["max_active_set_iter"],
                                   lambda self, v: self._set_param("max_active_set_iter", int(v)),
                                   doc="Active-set iterations per step before the damped-Newton fallback (25).")

    def get_state(self) -> dict:
        """The contact history (copies): forces ``lam`` (2n), ``uy_prev`` (n, m),
        ``s_prev`` (m), the classification ``state`` and slip ``sign`` the next step
        starts from, and ``sliding`` (the nodes on the kinetic cone)."""
        if self._kernel is not None:
            return self._kernel.get_history()
        return {"lam": self._lam.copy(), "uy_prev": self._uy_prev.copy(), "s_prev": self._s_prev,
                "state": self._state.copy(), "sign": self._sign.copy(), "sliding": self._sliding.copy()}

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
            self._kernel.set_history(lam, uy, s_prev, cls, sign, sliding)
            return
        self._lam, self._uy_prev, self._s_prev = lam, uy, s_prev
        self._state, self._sign, self._sliding = cls, sign, sliding
        self._lu_key = None

    def reset(self) -> None:
        """Back to the undeformed, unloaded state."""
        if self._kernel is not None:
            self._kernel.reset()
            return
        n = self._n
        self._lam = np.zeros(2 * n)
        self._uy_prev = np.zeros(n)
        self._s_prev = 0.0
        self._state = np.zeros(n, dtype=np.int8)
        self._sign = np.zeros(n)
        self._sliding = np.zeros(n, dtype=bool)  # slid in the previous step: kinetic cone
        self._lu_key = None
        self._lu = None

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
        if not (np.isfinite(plate_y) and np.isfinite(plate_z)):
            raise ValueError(f"plate position must be finite, got y={plate_y!r}, z={plate_z!r}")
        if self._kernel is not None:
            status, f, u, state, frac, it = self._kernel.step(float(plate_y), float(plate_z))
            if status:
                self._raise_status(status, plate_y, plate_z)
            return ContactStep(forces=f, displacement=u, state=state, slip_fraction=frac, iterations=it)
        n = self._n
        z0 = self.model.node_z
        ds = float(plate_y) - self._s_prev
        self._mu_node = np.where(self._sliding, self.mu_kinetic, self.mu)
        if np.max(z0) <= plate_z and not np.any(self._lam):
            # the plate does not reach the ridge: nothing to solve
            return self._accept(np.zeros(2 * n), np.zeros(2 * n), np.zeros(n, dtype=np.int8), plate_y, 0)
        scale = self._r * max(float(np.max(z0) - plate_z), 1e-9, float(np.max(np.abs(self._uy_prev))))
        atol = self.tol * scale
        state, sign = self._state.copy(), self._sign.copy()
        if not np.any(state != OPEN):  # first contact: the nodes the plate penetrates, stuck
            state = np.where(z0 > plate_z, STICK, OPEN).astype(np.int8)
            if not np.any(state):
                state[np.argmax(z0)] = STICK
        its = 0
        mu_k = self.mu_kinetic
        for _ in range(n + 1):
            lam, u, state, sign, it = self._solve_load(state, sign, plate_y, plate_z, ds, atol)
            its += it
            # Breakaway cascade at this load: a node that slides under its static cone
            # drops to the kinetic one now, and the load it sheds is redistributed
            # before the path goes on (all such nodes of a round at once).
            moving = (state == SLIP) & (np.abs((u[:n] - self._uy_prev) - ds) > self._w_tol)
            broke = moving & (self._mu_node > mu_k)
            if not np.any(broke):
                break
            self._mu_node = np.where(broke, mu_k, self._mu_node)
        return self._accept(lam, u, state, plate_y, its, sign)

    def _solve_load(self, state, sign, plate_y, plate_z, ds, atol):
        """Solve the step to ``(plate_y, plate_z)`` with the cones ``self._mu_node``,
        starting from the classification ``(state, sign)``: active-set iterations,
        then the damped Newton method if they cycle. Returns ``(lam, u, state, sign, its)``."""
        it = 0
        for it in range(1, self.max_active_set_iter + 1):
            lam, u = self._solve_piece(state, sign, plate_z, ds)
            F, new_state, new_sign = self._classify(lam, u, plate_z, ds)
            if np.max(np.abs(F)) <= atol:
                return lam, u, new_state, new_sign, it
            if np.array_equal(new_state, state) and np.array_equal(new_sign[state == SLIP], sign[state == SLIP]):
                break  # same piece but not converged: round-off trouble, use Newton
            state, sign = new_state, new_sign
        start = self._lam.copy()
        lam, u, it2 = self._damped_newton(start, plate_y, plate_z, ds, atol)
        _, new_state, new_sign = self._classify(lam, u, plate_z, ds)
        return lam, u, new_state, new_sign, it + it2

    def _raise_status(self, status: int, plate_y: float, plate_z: float):
        """The exception of the reference implementation for a kernel status."""
        info, residual, atol = self._kernel.error()
        if status == 1:
            raise ValueError(f"plate position must be finite, got y={plate_y!r}, z={plate_z!r}")
        if status == 2:
            raise ContactConvergenceError(f"singular contact system (LU getrf info={info})")
        if status == 3:
            raise ContactConvergenceError(f"singular contact Jacobian at iteration {info}")
        if status == 4:
            raise ContactConvergenceError(
                f"contact did not converge in {self.max_iter} iterations (residual {residual:.3e} N/m, "
                f"tolerance {atol:.3e}); plate at y={plate_y:.6g} m, z={plate_z:.6g} m, mu={self.mu}"
            )
        raise RuntimeError(f"contact kernel returned unknown status {status}")  # pragma: no cover

    # -- one piece of the piecewise-linear system
    def _solve_piece(self, state, sign, plate_z, ds):
        n, mu = self._n, self._mu_node
        T = np.flatnonzero(state == STICK)
        A = np.flatnonzero(state != OPEN)
        slip_coef = np.where(state == SLIP, mu * sign, 0.0)  # lt = slip_coef * ln on slip nodes
        rhs = np.concatenate([plate_z - self.model.node_z[A], self._uy_prev[T] + ds])
        key = (state.tobytes(), slip_coef.tobytes())
        if self.reduced:
            if key != self._lu_key:
                C = self.model.compliance
                # u = C[:, y_T] lt_T + (C[:, y_A] diag(slip_coef_A) - C[:, z_A]) ln_A, rows g_A and w_T
                rows = np.concatenate([n + A, T])[:, None]
                M = np.empty((rows.size, rows.size))
                M[:, :A.size] = C[rows, A] * slip_coef[A] - C[rows, n + A]
                M[:, A.size:] = C[rows, T]
                lu, piv, info = dgetrf(M, overwrite_a=True)
                if info != 0:
                    raise ContactConvergenceError(f"singular contact system (LAPACK getrf info={info})")
                self._lu = (lu, piv)
                self._lu_key = key
            x, info = dgetrs(*self._lu, rhs)
        else:
            x = self.model.solve_piece_full(A, T, slip_coef[A], rhs)
        lam = np.zeros(2 * n)
        lam[n + A] = x[:A.size]
        lam[A] += slip_coef[A] * x[:A.size]
        lam[T] = x[A.size:]
        return lam, self._displacement(lam)

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

    def _accept(self, lam, u, state, plate_y, it, sign=None) -> ContactStep:
        n = self._n
        # Reported state: a node on the friction cone that does not move relative to
        # the plate (a stopped plate) is stuck, not slipping; the solver keeps the
        # cone classification as its warm start.
        slip_increment = (u[:n] - self._uy_prev) - (float(plate_y) - self._s_prev)
        moving = np.abs(slip_increment) > self._w_tol
        reported = np.where((state == SLIP) & ~moving, STICK, state).astype(np.int8)
        self._lam = lam
        self._state = state
        self._sliding = reported == SLIP
        self._sign = np.zeros(n) if sign is None else sign
        self._uy_prev = u[:n].copy()
        self._s_prev = float(plate_y)
        w = self.model.weights
        touching = reported != OPEN
        total = float(w[touching].sum())
        frac = float(w[reported == SLIP].sum()) / total if total > 0 else 0.0
        state = reported
        f = np.concatenate([lam[:n], -lam[n:]])
        return ContactStep(forces=f, displacement=u, state=state, slip_fraction=frac, iterations=it)
