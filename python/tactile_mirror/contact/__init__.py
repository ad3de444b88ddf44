"""Contact mechanics of the pad: a reduced plane-strain FEM ridge with Coulomb friction.

Pieces, each usable on its own:

* :mod:`.geometry`  ridge/block geometry, material, graded P2-ready mesh
* :mod:`.model`     scikit-fem assembly and condensation to the contact surface
  (compliance, strip-stress sensor operator), cached per geometry
* :mod:`.solver`    quasi-static frictional contact of one ridge (semismooth Newton)
* :mod:`.pad`       several ridges under a curved finger, stepped with ``advance``
* :mod:`.simulate`  scenes -> signals (``simulate``, ``simulate_many``)
* :mod:`.plants`    the contact models of the closed loop behind one interface
  (``ContactPlant``, ``ContactState``) and the FEM pad with a pressing finger (``FemPad``)
* :mod:`.brush`     the reduced brush model of the ridges (``BrushRidges``), the other plant
"""
from .brush import BrushRidges
from .geometry import Material, RidgeGeometry, ridge_mesh, wide_block
from .model import RidgeModel, ridge_model
from .pad import Pad, PadState
from .plants import ContactPlant, ContactState, FemPad
from .simulate import SimulationResult, calibrate_friction, simulate, simulate_many
from .solver import OPEN, SLIP, STICK, ContactConvergenceError, ContactSolver, ContactStep

__all__ = [
    "OPEN", "SLIP", "STICK", "BrushRidges", "ContactConvergenceError", "ContactPlant", "ContactSolver",
    "ContactState", "ContactStep", "FemPad", "Material", "Pad", "PadState", "RidgeGeometry", "RidgeModel",
    "SimulationResult", "calibrate_friction", "ridge_mesh", "ridge_model", "simulate", "simulate_many",
    "wide_block",
]
