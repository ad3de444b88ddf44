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
  Static and kinetic friction: a node that slid in the previous step has the cone
  ``mu_kinetic``, any other ``mu`` (static, >= kinetic). With ``mu_kinetic < mu`` a node
  that breaks away sheds load one step later, so gross slip releases the stored shear
  (a sharp stress drop) where a plate that merely stops does not.
  A node is reported as slipping when it is on the cone *and* moves relative to the
  plate (``|w| > 1e-11 * ridge height``); on the cone but still (a stopped plate) it
  is reported as stuck.

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
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgetrf, dgetrs

from .model import RidgeModel

__all__ = ["OPEN", "SLIP", "STICK", "ContactConvergenceError", "ContactSolver", "ContactStep"]

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
        reference, same answers, much slower).
    """

    max_active_set_iter = 25

    def __init__(self, model: RidgeModel, mu: float, tol: float = 1e-10, max_iter: int = 60,
                 reduced: bool = True, mu_kinetic: float | None = None) -> None:
        if not (np.isfinite(mu) and mu > 0):
            raise ValueError(f"mu must be a positive number, got {mu!r}")
        mu_k = mu if mu_kinetic is None else mu_kinetic
        if not (np.isfinite(mu_k) and 0 < mu_k <= mu):
            raise ValueError(f"mu_kinetic must be in (0, mu], got {mu_kinetic!r}")
        self.mu_kinetic = float(mu_k)
        if not (0 < tol < 1e-2):
            raise ValueError(f"tol must be in (0, 1e-2), got {tol!r}")
        self.model = model
        self.mu = float(mu)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.reduced = bool(reduced)
        n = model.n_nodes
        self._n = n
        C = model.compliance
        # u = C f = C P lam with P = diag(1, -1): columns of the normal block flip sign
        self._CP = np.concatenate([C[:, :n], -C[:, n:]], axis=1)
        self._r = 1.0 / float(np.mean(np.diag(C)))
        # slip increments below this count as no motion (round-off is ~1e-19 m)
        self._w_tol = 1e-11 * model.geometry.height
        self.reset()

    def reset(self) -> None:
        """Back to the undeformed, unloaded state."""
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
        n = self._n
        z0 = self.model.node_z
        if not (np.isfinite(plate_y) and np.isfinite(plate_z)):
            raise ValueError(f"plate position must be finite, got y={plate_y!r}, z={plate_z!r}")
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
        it = 0
        for it in range(1, self.max_active_set_iter + 1):
            lam, u = self._solve_piece(state, sign, plate_z, ds)
            F, new_state, new_sign = self._classify(lam, u, plate_z, ds)
            if np.max(np.abs(F)) <= atol:
                return self._accept(lam, u, new_state, plate_y, it, new_sign)
            if np.array_equal(new_state, state) and np.array_equal(new_sign[state == SLIP], sign[state == SLIP]):
                break  # same piece but not converged: round-off trouble, use Newton
            state, sign = new_state, new_sign
        lam, u, it2 = self._damped_newton(self._lam.copy(), plate_y, plate_z, ds, atol)
        _, new_state, new_sign = self._classify(lam, u, plate_z, ds)
        return self._accept(lam, u, new_state, plate_y, it + it2, new_sign)

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
