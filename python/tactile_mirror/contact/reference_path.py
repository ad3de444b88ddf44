"""The Python reference backend of :class:`~tactile_mirror.contact.solver.ContactSolver`
(``backend="python"``, and every unreduced solver), part two: the event-driven path
following (the law is the module docstring of :mod:`~tactile_mirror.contact.solver`,
steps 1-7; the compiled kernel ``contact_solver.hpp`` follows the same steps).

:class:`ReferencePath` keeps the contact history (forces, surface position, node
statuses and slip signs, the plate's last position), moves the load from sample to
sample and from event to event, fills the samples between, and runs the breakaway
cascade, the cycle rule (the status sets met at one point, :data:`SEEN_CAP` of them at
most) and the friction change. The solve of one load or one piece is
:mod:`~tactile_mirror.contact.reference_active_set`.
"""
from __future__ import annotations

import numpy as np

from tactile_mirror.contact.reference_active_set import ReferenceActiveSet
from tactile_mirror.contact.step import OPEN, SLIP, STICK, ContactConvergenceError, ContactStep

__all__ = ["SEEN_CAP", "ReferencePath"]

#: Status sets kept per point by the cycle rule (the kernel's kSeenCap).
SEEN_CAP = 256


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
    """More than SEEN_CAP status sets at one point: the statuses cycle."""


class ReferencePath(ReferenceActiveSet):
    """The reference path following, as methods of
    :class:`~tactile_mirror.contact.solver.ContactSolver` (which derives from it). The
    solver checks the arguments and calls :meth:`_reset_reference`, :meth:`_reference_history`,
    :meth:`_set_reference_history`, :meth:`_step_reference` and :meth:`_follow_reference`
    when it has no compiled kernel.

    Reads what the solver sets up (``model``, ``_n``, ``_r``, the tolerances ``_w_tol``,
    ``_g_tol``, ``_f_tol``, ``_evt_tol``, the parameters ``mu``, ``mu_kinetic``, ``tol``)
    and counts :attr:`solves` and :attr:`events` through the solver's properties.
    """

    # -- the history
    def _reset_reference(self) -> None:
        """Back to the undeformed, unloaded state."""
        n = self._n
        self._lam = np.zeros(2 * n)
        self._uy_prev = np.zeros(n)
        self._s_prev = 0.0
        self._state = np.zeros(n, dtype=np.int8)
        self._sign = np.zeros(n)
        self._u = np.zeros(2 * n)
        self._z_prev = None  # plate height of the current state (None: not placed yet)
        self._friction_applied = (self.mu, self.mu_kinetic)  # the cones the state was solved with
        self._unit_key = None
        self._reset_pieces()

    def _reference_history(self) -> dict:
        """The history as ContactSolver.get_state gives it (copies)."""
        return {"lam": self._lam.copy(), "uy_prev": self._uy_prev.copy(), "s_prev": self._s_prev,
                "state": self._state.copy(), "sign": self._sign.copy(), "sliding": self._state == SLIP,
                "z_prev": self._z_prev}

    def _set_reference_history(self, lam, s_prev, cls, sign, z_prev) -> None:
        """Take a checked history (ContactSolver.set_state); the surface position is
        recomputed from the forces."""
        n = self._n
        self._lam, self._s_prev = lam, s_prev
        self._state, self._sign = cls, sign
        self._u = self._displacement(lam)
        self._uy_prev = self._u[:n].copy()
        if z_prev is None and np.any(cls != OPEN):
            # the plate face is where the touching nodes are
            k = int(np.argmax(lam[n:]))
            z_prev = float(self.model.node_z[k] + self._u[n + k])
        self._z_prev = None if z_prev is None else float(z_prev)
        self._lu_key = None
        self._unit_key = None
        self._friction_applied = (self.mu, self.mu_kinetic)  # a given history holds under the current friction

    # -- following the load
    def _step_reference(self, y: float, z: float) -> ContactStep:
        """One step to the checked plate position ``(y, z)``: the path to it, solved at the sample."""
        lam = np.empty((1, 2 * self._n))
        u = np.empty((1, 2 * self._n))
        state = np.empty((1, self._n), dtype=np.int8)
        solves0 = self.solves
        self._follow_reference(np.array([y], dtype=np.float64), np.array([z], dtype=np.float64), True,
                               lam, u, state)
        return self._report(lam[0], u[0], state[0], self.solves - solves0)

    def _follow_reference(self, ys, zs, every, lam_out, u_out, state_out) -> tuple[int, int]:
        """ContactSolver.follow on checked samples (``every``: one segment per sample);
        ``(solves, events)`` of the call. On an error the history is restored."""
        N = ys.size
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
                end = k + 1 if every else self._segment_end(ys, zs, k)
                L = end - k
                thetas = np.arange(1, L + 1) / L
                self._follow_segment(float(ys[end - 1]), float(zs[end - 1]), thetas, 1e-9 / L, every or L > 1,
                                     lam_out[k:end], None if u_out is None else u_out[k:end],
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
        """The history and counts, for :meth:`_restore` after a failed call."""
        return (self._lam.copy(), self._u.copy(), self._uy_prev.copy(), self._s_prev, self._z_prev,
                self._state.copy(), self._sign.copy(), self.solves, self.events, self._friction_applied)

    def _restore(self, snap):
        """Back to a :meth:`_snapshot` (the cached piece is recomputed)."""
        (self._lam, self._u, self._uy_prev, self._s_prev, self._z_prev, self._state, self._sign,
         self.solves, self.events, self._friction_applied) = snap
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
        """Write the samples ``rows``: the point ``(lam_c, u_c)``, or (``lam1`` given) the
        linear interpolation at ``frac`` of the way to ``(lam1, u1)``; the current statuses."""
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
        """The breakaway cascade at the current load (:mod:`~tactile_mirror.contact.solver`, step 5):
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
        """The ContactStep of the forces ``lam = (lt, ln)`` and displacements ``u``."""
        n = self._n
        w = self.model.weights
        touching = state != OPEN
        total = float(w[touching].sum())
        frac = float(w[state == SLIP].sum()) / total if total > 0 else 0.0
        f = np.concatenate([lam[:n], -lam[n:]])
        return ContactStep(forces=f, displacement=u, state=state.astype(np.int8), slip_fraction=frac,
                           iterations=int(iterations))
