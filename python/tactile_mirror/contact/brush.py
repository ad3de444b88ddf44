"""A reduced quasi-static contact model of a finger on the ridges: the brush model.

Not the FEM of :mod:`tactile_mirror.contact` (see :class:`~tactile_mirror.contact.plants.FemPad`
for that one behind the same interface): each ridge is a row of surface points in
series with the finger pad's tangential compliance, each point holding traction up
to ``mu p_i`` (Coulomb) and sliding beyond it. Traction concentrates at the ridge
edges (flat-punch-like stiffness) while pressure is highest at the centre, so local
slip starts at the edges and spreads inward as the tangential load grows, and gross
slip is every point sliding. The strips see the bending of the ridge (opposite
signs, L vs R) plus the traction near their own edge.

It implements :class:`~tactile_mirror.contact.plants.ContactPlant`. Units:
displacements m, forces N, stiffnesses N/m, stresses Pa.
"""
from __future__ import annotations

import numbers

import numpy as np
import numpy.typing as npt

from tactile_mirror.checks import real_array, real_number
from tactile_mirror.contact.plants import ContactState

__all__ = ["BrushRidges"]


class BrushRidges:
    """Reduced quasi-static contact of a finger on the ridges (see :mod:`tactile_mirror.contact.brush`).

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
        for name, v in (("n_ridges", n_ridges), ("n_points", n_points)):
            if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not 1 <= v <= 10_000:
                raise ValueError(f"{name} must be an integer in [1, 10000], got {v!r}")
        self.n_ridges = int(n_ridges)
        self.set_mu(mu)
        self.P = real_number(normal_load, "normal_load", unit="N", positive=True)
        k_finger = real_number(k_finger, "k_finger", unit="N/m", positive=True)
        strip_area = real_number(strip_area, "strip_area", unit="m^2", positive=True)
        for name, v in (("bending", bending), ("edge", edge), ("normal", normal)):
            real_number(v, name)
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

    def reset(self) -> None:
        self.s = np.zeros((self.n_ridges, self.k.size))   # slid offsets of the points, m

    def set_mu(self, mu: npt.ArrayLike) -> None:
        """Set the friction coefficient (one value, or one per ridge; positive and finite)."""
        # (a string or a bool passed the float conversion)
        m = np.broadcast_to(real_array(mu, "mu"), (self.n_ridges,)).copy()
        if not np.all(np.isfinite(m) & (m > 0)):  # (NaN passed a plain `mu <= 0` check)
            raise ValueError(f"mu must be positive and finite, got {mu!r}")
        self.mu = m

    def advance(self, dy: float) -> ContactState:
        """Relative displacement finger - pad (m) -> contact state.

        Raises ValueError for a non-finite ``dy`` or one beyond 1 m
        (:data:`~tactile_mirror.contact.solver.MAX_PLATE_POSITION`, as the FEM pad), the
        state unchanged (an infinite one was taken into the slid offsets for good)."""
        from tactile_mirror.contact.solver import MAX_PLATE_POSITION

        dy = real_number(dy, "dy", unit="m")
        if not abs(dy) <= MAX_PLATE_POSITION:
            raise ValueError(f"dy must lie within {MAX_PLATE_POSITION:g} m, got {dy!r}")
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
