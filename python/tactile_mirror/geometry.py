"""Ridge geometry and material of the pad (plane strain, SI units); the mesh is made in
:mod:`tactile_mirror.contact.mesh`.

Coordinates: ``y`` is across the ridge (the sliding direction), ``z`` is up; the ridge
occupies ``-width/2 <= y <= width/2``, ``0 <= z <= top(y)`` with a circular top of radius
``top_radius`` whose crown is at ``z = height``. The bottom ``z = 0`` is bonded to the
acrylic plate. The out-of-plane axis ``x`` runs along the ridge (and along the PVDF strips).

PVDF strips: each strip is a 1 mm wide, 80 um thick film running along the ridge; in the
cross-section it is a short segment. ``strip_angle`` is the angle of the segment (its
*width* direction) from the ``y`` axis: 90 degrees (the default) means the films stand
vertically in the ridge, one left (``L``, ``y < 0``) and one right (``R``, ``y > 0``) of the
centre plane, so that their through-thickness axis is ``y`` and their width axis is ``z``.
Under a tangential load the ridge shears and bends, and the two films' stresses part: in the
fig6 scene at t = 1.4 s the through-film ``s3 = s_yy`` is +8 kPa (L) and -10 kPa (R), the
along-width ``s2 = s_zz`` -131 kPa (L) and -160 kPa (R) on top of the indentation's
compression. The circuit weighs all three with the film's d31, d32, d33, and the difference L - R
is the ``sigma_L - sigma_R`` signal of the paper's Fig. 6-8. The films are
much thinner than the mesh and are treated as not perturbing the rubber; their stress is the
rubber stress averaged along the strip's mid-line.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["MAX_RIDGES", "STRESS_RECOVERIES", "Material", "RidgeGeometry", "too_many_ridges", "wide_block"]

#: How the strips may read the FEM stress (``RidgeGeometry.stress_recovery``).
STRESS_RECOVERIES = ("pointwise", "projected")


#: Most ridges a pad (and a contact scene, :class:`tactile_mirror.Scene`) may have. A pad is
#: the few ridges under one fingertip: 6 in the paper's hardware, and at the default pitch
#: (3 mm) 64 ridges span 19 cm, beyond any finger. Each ridge keeps its own contact solver
#: and outputs (about 4 MB per ridge for a 0.6 s scene), so 1e5 ridges ran out of memory
#: with no message. A recording holds at most as many (:mod:`tactile_mirror.loop.recording`
#: takes this limit).
MAX_RIDGES = 64


def too_many_ridges(n_ridges) -> str:
    """The error message for a pad or scene with more than :data:`MAX_RIDGES` ridges."""
    return (f"n_ridges must be at most {MAX_RIDGES} (MAX_RIDGES: the ridges under one finger; each keeps "
            f"its own contact solver), got {n_ridges!r}")


@dataclass(frozen=True)
class Material:
    """Isotropic linear elastic material.

    Parameters
    ----------
    E : float
        Young's modulus, Pa (default: KE12 silicone, 4.96 MPa).
    nu : float
        Poisson's ratio (default 0.495, nearly incompressible).
    rho : float
        Mass density, kg/m^3 (default 1230; unused by the quasi-static model, kept for
        completeness and dynamic extensions).
    """

    E: float = 4.96e6
    nu: float = 0.495
    rho: float = 1230.0

    def __post_init__(self) -> None:
        if not (self.E > 0):
            raise ValueError(f"E must be positive, got {self.E!r}")
        if not (-1.0 < self.nu < 0.5):
            raise ValueError(f"nu must be in (-1, 0.5), got {self.nu!r}")
        if not (self.rho > 0):
            raise ValueError(f"rho must be positive, got {self.rho!r}")

    @property
    def plane_strain_modulus(self) -> float:
        """E* = E / (1 - nu^2), Pa (contact modulus against a rigid body)."""
        return self.E / (1.0 - self.nu**2)


@dataclass(frozen=True)
class RidgeGeometry:
    """Parametric ridge (or block) cross-section and its mesh resolution.

    Parameters
    ----------
    width, height : float
        Ridge width (along y) and crown height (along z), m. Defaults 2 mm x 2 mm (not given
        in the paper; chosen so that two 1 mm strips fit in a ridge on a 3 mm pitch).
    top_radius : float
        Curvature radius of the top surface, m (paper: 100 mm). ``inf`` gives a flat top.
    strip_y : tuple of float
        y of the strip centres (L, R), m. Default (-0.5 mm, +0.5 mm).
    strip_depth : float
        Depth of the strip centres below the crown, m. Default 1.0 mm.
    strip_width, strip_thickness : float
        Film width in the cross-section (1 mm) and thickness (80 um), m.
    strip_angle : float
        Angle of the strip's width direction from the y axis, degrees (90: vertical films).
    contact_halfwidth : float or None
        Half-width of the candidate contact zone on the top, m; None means the whole top.
    mesh_size : float
        Element size far from the contact zone, m (the largest element diameter); the
        contact zone and the strips are meshed finer (``contact_mesh_size``,
        ``strip_mesh_size``). Default 0.2 mm, from ``bench/mesh_study.py`` (fig6 scene, mesh
        size ``h`` with the contact zone at ``h / 4``, against ``h = 0.05 mm``): with
        ``stress_recovery="projected"`` the strip-stress error falls steadily with ``h``
        (observed order 1.65), 3.0e-3 of the peak (rms) at 0.2 mm against 5.0e-3 at 0.3 mm
        and 1.7e-3 at 0.15 mm, at 0.08 / 0.04 / 0.17 ms per sample solved (C++, every
        sample; ``docs/figures/mesh_study.json``). Read pointwise (the default) the errors
        are 4.4e-2 / 6.1e-2 / 2.5e-2. fig6's gross slip comes at 1.471 s at 0.2 mm, 1.450 s
        at 0.3 mm and 1.44 s on the fine meshes. The default stays 0.2 mm: 0.3 mm would halve
        the cost per sample at 1.7x the error and move fig6's gross slip; the bundled
        detector weights and the loop's calibration were made at 0.2 mm. The earlier finding that 0.2 mm was less accurate than 0.3 mm came from
        the pointwise stress reading (see ``stress_recovery``) and from meshes with an odd
        number of columns at 0.4 and 0.3 mm (now always even, see :func:`ridge_mesh`).
    contact_mesh_size : float
        Element size (edge length of P2 triangles) on the contact zone, m; the P2 surface
        nodes are half this apart.
    strip_mesh_size : float or None
        Element size around the strips, m (default: ``mesh_size``).
    grading : float
        Growth of the element size with the distance from the contact zone (dimensionless).
    n_strip_samples : int
        Number of sample points along each strip's mid-line for the stress average.
    stress_recovery : {"pointwise", "projected"}
        How the strips read the FEM stress. ``"pointwise"`` (default): the P2 stress at the
        sample points. At nu = 0.495 its pressure part ``lam div u`` carries a spurious
        mode, a sawtooth of +-10 kPa along the strips at ``mesh_size`` 0.2 mm (as large as
        the through-film stress itself), and the strip average keeps a bias that depends on
        where the strip cuts the elements: the strip stresses do not converge steadily with
        the mesh (rms error 4.8e-2 of the peak at 0.2 mm, 3.8e-2 at 0.3 mm). ``"projected"``:
        every stress component is L2-projected onto continuous piecewise-linear fields
        first, which filters the mode (P1 is a stable pressure space for P2 displacements);
        the error is then ten times smaller and falls steadily with the mesh size. The
        default stays ``"pointwise"`` until the bundled detector weights and the loop's
        shear calibration are rebuilt on projected stresses (the contact itself, forces and
        slip, does not depend on this choice).
    """

    width: float = 2.0e-3
    height: float = 2.0e-3
    top_radius: float = 0.1
    strip_y: tuple = (-0.5e-3, 0.5e-3)
    strip_depth: float = 1.0e-3
    strip_width: float = 1.0e-3
    strip_thickness: float = 80e-6
    strip_angle: float = 90.0
    contact_halfwidth: float | None = None
    mesh_size: float = 0.2e-3
    contact_mesh_size: float = 0.05e-3
    strip_mesh_size: float | None = None
    grading: float = 0.5
    n_strip_samples: int = 40
    stress_recovery: str = "pointwise"
    material: Material = field(default_factory=Material)

    def __post_init__(self) -> None:
        for name in ("width", "height", "top_radius", "strip_width", "strip_thickness", "mesh_size",
                     "contact_mesh_size", "grading"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if self.top_radius < self.width / 2:
            raise ValueError(f"top_radius must be at least width/2, got {self.top_radius!r}")
        if self.contact_mesh_size > self.mesh_size:
            raise ValueError("contact_mesh_size must not exceed mesh_size")
        object.__setattr__(self, "strip_y", tuple(float(v) for v in self.strip_y))
        if self.contact_halfwidth is not None and not (0 < self.contact_halfwidth <= self.width / 2):
            raise ValueError(f"contact_halfwidth must be in (0, width/2], got {self.contact_halfwidth!r}")
        if self.stress_recovery not in STRESS_RECOVERIES:
            raise ValueError(f"stress_recovery must be one of {STRESS_RECOVERIES}, got {self.stress_recovery!r}")
        if int(self.n_strip_samples) < 2:
            raise ValueError(f"n_strip_samples must be >= 2, got {self.n_strip_samples!r}")
        for ys in self.strip_y:
            for p in self.strip_points(ys):
                if not (abs(p[0]) < self.width / 2 and 0 < p[1] < self.height - self.sag(p[0])):
                    raise ValueError(f"strip at y={ys!r} does not fit inside the ridge (strip_depth, strip_y)")

    def sag(self, y: npt.ArrayLike) -> np.ndarray:
        """Drop of the top surface below the crown at ``y``, m."""
        y = np.asarray(y, dtype=float)
        if math.isinf(self.top_radius):
            return np.zeros_like(y)
        return self.top_radius - np.sqrt(self.top_radius**2 - y**2)

    @property
    def strip_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors (e2 = along the strip width, e3 = film normal) in the (y, z) plane."""
        a = math.radians(self.strip_angle)
        e2 = np.array([math.cos(a), math.sin(a)])
        e3 = np.array([-math.sin(a), math.cos(a)])
        return e2, e3

    def strip_points(self, ys: float) -> np.ndarray:
        """Mid-line sample points of the strip centred at ``(ys, height - strip_depth)``, shape (n, 2)."""
        n = int(self.n_strip_samples)
        e2, _ = self.strip_directions
        s = (np.arange(n) + 0.5) / n - 0.5
        c = np.array([ys, self.height - self.strip_depth])
        return c[None, :] + self.strip_width * s[:, None] * e2[None, :]


def wide_block(width: float = 20e-3, height: float = 10e-3, top_radius: float = 0.1,
               contact_halfwidth: float = 1.5e-3, contact_mesh_size: float = 25e-6, mesh_size: float = 1.5e-3,
               **kw: Any) -> RidgeGeometry:
    """A wide block for Hertz / Cattaneo-Mindlin validation (default 20 x 10 mm, R = 100 mm).

    The strips are placed 0.5 mm apart at 1 mm depth (they only matter for sensor checks).
    """
    kw.setdefault("strip_y", (-0.5e-3, 0.5e-3))
    kw.setdefault("strip_depth", 1.0e-3)
    kw.setdefault("grading", 0.35)
    return RidgeGeometry(width=width, height=height, top_radius=top_radius,
                         contact_halfwidth=contact_halfwidth, contact_mesh_size=contact_mesh_size,
                         mesh_size=mesh_size, **kw)
