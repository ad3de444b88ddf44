"""The Python reference backend of :class:`~tactile_mirror.contact.solver.ContactSolver`
(``backend="python"``, and every unreduced solver), part one: the solve of one load.

For a fixed status of every node (a *piece*: open, stuck, sliding with a sign) the
contact forces are linear in the load; :meth:`ReferenceActiveSet._solve_piece` solves
one piece, keeping the LU factors of a base piece and reaching nearby pieces through
the capacitance matrix of their changed rows (Woodbury). :meth:`~ReferenceActiveSet._solve_load`
solves the Alart-Curnier equations of one load (the module docstring of
:mod:`~tactile_mirror.contact.solver`) by primal-dual active-set iterations over the
pieces, with the damped Newton method when they cycle. The event-driven path
following that calls it is :mod:`~tactile_mirror.contact.reference_path`.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dgetrf, dgetrs

from tactile_mirror.contact.step import OPEN, SLIP, STICK, ContactConvergenceError

__all__ = ["ReferenceActiveSet"]


class ReferenceActiveSet:
    """The reference solve of one load, as methods of
    :class:`~tactile_mirror.contact.solver.ContactSolver` (which derives from it).

    Reads what the solver sets up: ``model``, ``reduced``, ``_n`` (nodes), ``_CP`` (the
    compliance with the normal columns negated, ``u = _CP lam``), ``_r`` (the
    Alart-Curnier stiffness), the parameters ``mu``, ``max_iter`` and
    ``max_active_set_iter``; and from the path following: the cones ``_mu_node`` of
    the solve, the surface position ``_uy_prev`` slip is measured from and the forces
    ``_lam`` (the damped Newton method's start). Keeps the factors of the pieces
    (``_lu``, ``_base``, the capacitance ``_cap_*``) and counts ``factorizations`` and
    ``updates``.
    """

    def _reset_pieces(self) -> None:
        """Forget every factored piece."""
        self._lu_key = None
        self._lu = None
        self._G = None
        self._base = None
        self._cap_rows = None
        self.factorizations = 0
        self.updates = 0

    def _displacement(self, lam: np.ndarray) -> np.ndarray:
        """Surface displacements ``(u_y, u_z)`` under the contact forces ``lam``: from the
        condensed compliance, or (unreduced) from a sparse solve with the full stiffness."""
        if self.reduced:
            return self._CP @ lam
        n = self._n
        f = np.concatenate([lam[:n], -lam[n:]])
        return self.model.contact_displacement_full(f)

    # -- one load: active-set iterations over the pieces, damped Newton as the fallback
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
        """The Alart-Curnier residual ``F`` at ``(lam, u)`` and the classification it
        implies: ``(F, state, sign)``, ``sign`` the slip direction of the SLIP nodes."""
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
        """Newton's method on ``F`` from ``lam``, backtracking on ``|F|^2``, until ``max |F|
        <= atol``: ``(lam, u, iterations)``, or ContactConvergenceError."""
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
