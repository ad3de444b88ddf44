"""The reduced ridge model: FEM assembly once, then everything on the contact surface.

The ridge is plane-strain linear elastic (quadratic triangles, which do not lock at
nu = 0.495), bonded at ``z = 0`` and loaded only through its top surface by the rigid
plate. Everything the contact solver and the sensors need is therefore linear in the
contact forces ``f`` at the candidate surface nodes, and is computed once per geometry:

``compliance``  (2n x 2n)
    ``u_c = C f``: displacements of the contact nodes (``y`` block, then ``z`` block)
    under nodal forces ``f`` (same layout), ``C = G^T K^-1 G``.
``sensor``      (n_strips * 3 x 2n)
    strip-averaged normal stresses ``(s1, s2, s3)`` of each strip in its own frame, read
    from the FEM stress as ``RidgeGeometry.stress_recovery`` says
    (``s1`` along the strip length = the ridge axis ``x``, ``s2`` along its width,
    ``s3`` through the film), ``sigma = S f``.
``reaction``    (2 x 2n)
    total reaction at the bonded base, for the force balance.

The full displacement field is ``u = X f`` with ``X = K^-1 G`` (kept for full-field
requests only). Nodes are the P2 nodes of the top surface (vertices and mid-sides);
``weights`` are their Simpson (consistent P2) lengths, so ``f / weight`` is a smooth
traction even though P2 nodal forces alternate ~1:4 between vertices and mid-sides.

Forces here are per unit length of ridge (N/m, plane strain).
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tactile_mirror.contact.mesh import ridge_mesh
from tactile_mirror.geometry import RidgeGeometry

__all__ = ["RidgeModel", "ridge_model"]


@dataclass
class RidgeModel:
    """Condensed model of one ridge (see the module docstring). Build with :func:`ridge_model`."""

    geometry: RidgeGeometry
    node_y: np.ndarray  # (n,) initial y of the contact nodes, m (sorted)
    node_z: np.ndarray  # (n,) initial z, m
    weights: np.ndarray  # (n,) Simpson lengths, m
    compliance: np.ndarray  # (2n, 2n) m/(N/m)
    sensor: np.ndarray  # (n_strips*3, 2n) Pa/(N/m)
    reaction: np.ndarray  # (2, 2n) base reaction (y, z) per unit contact force
    n_dofs: int
    n_elements: int
    setup_seconds: float
    _full: dict  # mesh, basis, K, factor, dof maps: for unreduced solves and full fields

    @property
    def n_nodes(self) -> int:
        return self.node_y.size

    @property
    def n_strips(self) -> int:
        return len(self.geometry.strip_y)

    def strip_stress(self, f: np.ndarray) -> np.ndarray:
        """Strip stresses ``(n_strips, 3)`` in Pa for contact forces ``f`` (2n,), N/m."""
        return (self.sensor @ f).reshape(self.n_strips, 3)

    # ------------------------------------------------------------ full FEM access
    def displacement_field(self, f: np.ndarray) -> np.ndarray:
        """Full nodal displacement vector (all P2 DOFs) for contact forces ``f``: an unreduced solve."""
        d = self._full
        rhs = np.zeros(d["n_free"])
        rhs[d["contact_free"]] = f
        u = np.zeros(self.n_dofs)
        u[d["free"]] = d["solve"](rhs)
        return u

    def contact_displacement_full(self, f: np.ndarray) -> np.ndarray:
        """``u_c`` from a sparse solve with the full stiffness (the unreduced reference)."""
        d = self._full
        rhs = np.zeros(d["n_free"])
        rhs[d["contact_free"]] = f
        return d["solve"](rhs)[d["contact_free"]]

    def solve_piece_full(self, A: npt.ArrayLike, T: npt.ArrayLike, slip_coef: npt.ArrayLike,
                         rhs: npt.ArrayLike) -> np.ndarray:
        """Unreduced solve of one active-set piece (the reference for the condensed one).

        Unknowns: the full displacement and the normal forces of the active nodes ``A``
        and tangential forces of the stuck nodes ``T``; slipping nodes carry
        ``lt = slip_coef * ln``. Constraints: ``u_z = rhs[:len(A)]`` on ``A`` and
        ``u_y = rhs[len(A):]`` on ``T``. One sparse LU of the bordered stiffness, no
        condensed quantity used. Returns ``(ln_A, lt_T)`` concatenated.
        """
        d = self._full
        n = self.n_nodes
        nf = d["n_free"]
        cf = d["contact_free"]
        A, T = np.asarray(A), np.asarray(T)
        m = A.size + T.size
        # force on the ridge: f_y = lt, f_z = -ln  ->  K u - B x = 0
        rows = np.concatenate([cf[A], cf[n + A], cf[T]])
        cols = np.concatenate([np.arange(A.size), np.arange(A.size), A.size + np.arange(T.size)])
        vals = np.concatenate([slip_coef, -np.ones(A.size), np.ones(T.size)])
        B = sp.csr_matrix((vals, (rows, cols)), shape=(nf, m))
        E = sp.csr_matrix((np.ones(m), (np.arange(m), np.concatenate([cf[n + A], cf[T]]))), shape=(m, nf))
        Kff = d["K"][d["free"]][:, d["free"]]
        KKT = sp.bmat([[Kff, -B], [E, None]], format="csc")
        sol = spla.spsolve(KKT, np.concatenate([np.zeros(nf), rhs]))
        return sol[nf:]

    def stress_field(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Element-averaged plane-strain stress ``(sxx, syy, szz, syz)`` per element, Pa,
        and the element centroids ``(2, n_elements)``."""
        from skfem.helpers import sym_grad, trace

        d = self._full
        u = self.displacement_field(f)
        lam, mu = d["lame"]
        basis = d["basis"]
        uh = basis.interpolate(u)
        eps = sym_grad(uh)
        tr = trace(eps)
        syy = lam * tr + 2 * mu * eps[0, 0]
        szz = lam * tr + 2 * mu * eps[1, 1]
        syz = 2 * mu * eps[0, 1]
        sxx = lam * tr
        dx = basis.dx
        area = dx.sum(axis=1)
        out = np.stack([(s * dx).sum(axis=1) / area for s in (sxx, syy, szz, syz)])
        return out, d["mesh"].p[:, d["mesh"].t].mean(axis=1)


def _strip_operator(geom: RidgeGeometry, mesh, basis, lam: float, mu: float):
    """Rows: (s1, s2, s3) of each strip as ``geom.stress_recovery`` reads them, per P2 DOF."""
    if geom.stress_recovery == "projected":
        return _projected_strip_operator(geom, mesh, basis, lam, mu)
    return _pointwise_strip_operator(geom, mesh, basis, lam, mu)


def _pointwise_strip_operator(geom: RidgeGeometry, mesh, basis, lam: float, mu: float) -> sp.csr_matrix:
    """Rows: (s1, s2, s3) of each strip, the P2 stress averaged over its mid-line sample points."""
    rows, cols, vals = [], [], []
    e2, e3 = geom.strip_directions
    nu_ps = lam / (2 * (lam + mu))  # Poisson's ratio from the Lame parameters
    for k, ys in enumerate(geom.strip_y):
        pts = geom.strip_points(ys).T  # (2, n)
        cells = mesh.element_finder(mapping=basis.mapping)(*pts)
        ref = basis.mapping.invF(pts[:, :, None], tind=cells)
        n_pts = pts.shape[1]
        for j in range(basis.Nbfun):
            g = basis.elem.gbasis(basis.mapping, ref, j, tind=cells)[0].grad  # (2, 2, n, 1)
            g = g[..., 0]
            eyy, ezz = g[0, 0], g[1, 1]
            eyz = 0.5 * (g[0, 1] + g[1, 0])
            tr = eyy + ezz
            syy = lam * tr + 2 * mu * eyy
            szz = lam * tr + 2 * mu * ezz
            syz = 2 * mu * eyz
            sxx = nu_ps * (syy + szz)  # plane strain: s_xx = nu (s_yy + s_zz)

            comps = (sxx,
                     e2[0] * e2[0] * syy + 2 * e2[0] * e2[1] * syz + e2[1] * e2[1] * szz,
                     e3[0] * e3[0] * syy + 2 * e3[0] * e3[1] * syz + e3[1] * e3[1] * szz)
            dofs = basis.element_dofs[j, cells]
            for c, s in enumerate(comps):
                rows.append(np.full(n_pts, 3 * k + c))
                cols.append(dofs)
                vals.append(s / n_pts)
    shape = (3 * len(geom.strip_y), basis.N)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=shape)


def _projected_strip_operator(geom: RidgeGeometry, mesh, basis, lam: float, mu: float) -> np.ndarray:
    """Rows: (s1, s2, s3) of each strip, the stress L2-projected onto continuous P1 fields,
    averaged over its mid-line sample points (``stress_recovery="projected"``: why, in
    :class:`RidgeGeometry`). Dense: the projection spreads every row over the mesh."""
    from skfem import Basis, BilinearForm, ElementTriP1, asm
    from skfem.helpers import sym_grad

    e2, e3 = geom.strip_directions
    nu_ps = lam / (2 * (lam + mu))  # Poisson's ratio from the Lame parameters
    p1 = Basis(mesh, ElementTriP1(), quadrature=basis.quadrature)  # same points as the P2 basis

    def component(kind):
        @BilinearForm
        def form(u, q, w):
            eps = sym_grad(u)
            tr = eps[0, 0] + eps[1, 1]
            if kind == "yy":
                return (lam * tr + 2 * mu * eps[0, 0]) * q
            if kind == "zz":
                return (lam * tr + 2 * mu * eps[1, 1]) * q
            return 2 * mu * eps[0, 1] * q
        return asm(form, basis, p1).tocsr()  # (N_p1, N): int sigma(u) phi_i

    mass = spla.splu(asm(BilinearForm(lambda p, q, w: p * q), p1).tocsc())
    B = {kind: component(kind) for kind in ("yy", "zz", "yz")}
    rows = []
    for ys in geom.strip_y:
        pts = geom.strip_points(ys).T  # (2, n)
        average = np.asarray(p1.probes(pts).mean(axis=0)).ravel()  # mean over the points of a P1 field
        z = mass.solve(average)  # the projection's adjoint: mean of P(s) = (M^-1 average) . (int s phi)
        syy, szz, syz = (np.asarray(B[kind].T @ z).ravel() for kind in ("yy", "zz", "yz"))
        sxx = nu_ps * (syy + szz)  # plane strain: s_xx = nu (s_yy + s_zz)
        rows += [sxx,
                 e2[0] * e2[0] * syy + 2 * e2[0] * e2[1] * syz + e2[1] * e2[1] * szz,
                 e3[0] * e3[0] * syy + 2 * e3[0] * e3[1] * syz + e3[1] * e3[1] * szz]
    return np.array(rows)


@functools.lru_cache(maxsize=8)
def ridge_model(geometry: RidgeGeometry | None = None) -> RidgeModel:
    """Build (or fetch from the cache) the condensed model of a ridge geometry.

    The cache is keyed by the (frozen, hashable) geometry, so a second run of the same
    model costs nothing. Setup time is in ``model.setup_seconds``.
    """
    from skfem import Basis, ElementTriP2, ElementVector, asm
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    geom = geometry if geometry is not None else RidgeGeometry()
    if not isinstance(geom, RidgeGeometry):
        raise TypeError(f"geometry must be a RidgeGeometry, got {type(geometry).__name__}")
    t0 = time.perf_counter()
    mesh = ridge_mesh(geom)
    basis = Basis(mesh, ElementVector(ElementTriP2()))
    lam, mu = lame_parameters(geom.material.E, geom.material.nu)
    K = asm(linear_elasticity(lam, mu), basis).tocsr()

    # bonded base
    p = mesh.p
    base_facets = mesh.facets_satisfying(lambda x: np.isclose(x[1], 0.0, atol=1e-12), boundaries_only=True)
    fixed = np.unique(np.concatenate([basis.nodal_dofs[:, np.unique(mesh.facets[:, base_facets])].ravel(),
                                      basis.facet_dofs[:, base_facets].ravel()]))

    # candidate contact nodes: P2 nodes of the top surface within the contact zone
    top_v = np.isclose(p[1], geom.height - geom.sag(p[0]), rtol=0, atol=1e-12)
    bf = mesh.boundary_facets()
    top_f = bf[np.all(top_v[mesh.facets[:, bf]], axis=0)]
    hc = geom.contact_halfwidth if geom.contact_halfwidth is not None else geom.width / 2
    mid_y = p[0, mesh.facets[:, top_f]].mean(axis=0)
    top_f = top_f[np.abs(mid_y) <= hc * (1 + 1e-9)]
    verts = np.unique(mesh.facets[:, top_f])
    # node records: (y, z, dof_y, dof_z)
    vy, vz = p[0, verts], p[1, verts]
    fa, fb = mesh.facets[:, top_f]
    my, mz = 0.5 * (p[0, fa] + p[0, fb]), 0.5 * (p[1, fa] + p[1, fb])
    ny = np.concatenate([vy, my])
    nz = np.concatenate([vz, mz])
    dy = np.concatenate([basis.nodal_dofs[0, verts], basis.facet_dofs[0, top_f]])
    dz = np.concatenate([basis.nodal_dofs[1, verts], basis.facet_dofs[1, top_f]])
    # Simpson weights: L/6 to each end vertex, 4L/6 to the mid-side node
    length = np.hypot(p[0, fb] - p[0, fa], p[1, fb] - p[1, fa])
    w = np.concatenate([np.zeros(verts.size), 4 * length / 6])
    vpos = {v: i for i, v in enumerate(verts)}
    for a, b, L in zip(fa, fb, length):
        w[vpos[a]] += L / 6
        w[vpos[b]] += L / 6
    order = np.argsort(ny)
    ny, nz, dy, dz, w = ny[order], nz[order], dy[order], dz[order], w[order]
    contact_dofs = np.concatenate([dy, dz])

    free = np.setdiff1d(np.arange(basis.N), fixed)
    free_index = -np.ones(basis.N, dtype=np.int64)
    free_index[free] = np.arange(free.size)
    contact_free = free_index[contact_dofs]
    if np.any(contact_free < 0):
        raise ValueError("geometry: contact nodes coincide with the bonded base")
    Kff = K[free][:, free].tocsc()
    lu = spla.splu(Kff)
    n2 = contact_dofs.size
    G = np.zeros((free.size, n2))
    G[contact_free, np.arange(n2)] = 1.0
    X = lu.solve(G)  # K^-1 G
    C = X[contact_free]
    C = 0.5 * (C + C.T)  # symmetric up to round-off
    S_full = _strip_operator(geom, mesh, basis, lam, mu)
    S = S_full[:, free] @ X
    Kcf = K[fixed][:, free]
    R_dofs = Kcf @ X  # reaction at fixed dofs per unit contact force (sign: force on the ridge)
    is_y = np.isin(fixed, basis.nodal_dofs[0]) | np.isin(fixed, basis.facet_dofs[0])
    reaction = np.stack([R_dofs[is_y].sum(axis=0), R_dofs[~is_y].sum(axis=0)])
    full = {
        "mesh": mesh, "basis": basis, "K": K, "free": free, "n_free": free.size,
        "contact_free": contact_free, "solve": lu.solve, "X": X, "lame": (lam, mu),
        "fixed": fixed,
    }
    return RidgeModel(
        geometry=geom, node_y=ny, node_z=nz, weights=w, compliance=C, sensor=np.asarray(S),
        reaction=reaction, n_dofs=basis.N, n_elements=mesh.t.shape[1],
        setup_seconds=time.perf_counter() - t0, _full=full,
    )
