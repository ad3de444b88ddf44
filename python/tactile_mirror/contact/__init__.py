"""Contact mechanics of the pad: a reduced plane-strain FEM ridge with Coulomb friction.

Pieces, each usable on its own:

* :mod:`.mesh`      the graded P2-ready mesh of a ridge (its geometry and material:
  :mod:`tactile_mirror.geometry`)
* :mod:`.model`     scikit-fem assembly and condensation to the contact surface
  (compliance, strip-stress sensor operator), cached per geometry
* :mod:`.solver`    quasi-static frictional contact of one ridge (semismooth Newton):
  ``ContactSolver``, which checks and hands each step to the compiled kernel or the
  Python reference (:mod:`.reference_path`: event-driven path following;
  :mod:`.reference_active_set`: the solve of one load)
* :mod:`.step`      what a step answers: node statuses ``OPEN`` / ``STICK`` / ``SLIP``,
  ``ContactStep``, ``ContactConvergenceError``
* :mod:`.pad`       several ridges under a curved finger, stepped with ``advance``
* :mod:`.simulation`  scenes -> signals (``simulate``, ``simulate_many``)
* :mod:`.result_arrays`  a simulation result as plain arrays and JSON, and back (what a
  result store keeps, :class:`tactile_mirror.engine.ResultStore`)
* :mod:`.plants`    the contact models of the closed loop behind one interface
  (``ContactPlant``, ``ContactState``) and the FEM pad with a pressing finger (``FemPad``)
* :mod:`.brush`     the reduced brush model of the ridges (``BrushRidges``), the other plant
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from tactile_mirror._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "BrushRidges": "brush",
    "ridge_mesh": "mesh",
    "RidgeModel": "model", "ridge_model": "model",
    "Pad": "pad", "PadState": "pad",
    "ContactPlant": "plants", "ContactState": "plants", "FemPad": "plants",
    "SimulationResult": "simulation", "calibrate_friction": "simulation", "simulate": "simulation",
    "simulate_many": "simulation",
    "ContactSolver": "solver",
    "OPEN": "step", "SLIP": "step", "STICK": "step", "ContactConvergenceError": "step", "ContactStep": "step",
})

if TYPE_CHECKING:
    from tactile_mirror.contact.brush import BrushRidges
    from tactile_mirror.contact.mesh import ridge_mesh
    from tactile_mirror.contact.model import RidgeModel, ridge_model
    from tactile_mirror.contact.pad import Pad, PadState
    from tactile_mirror.contact.plants import ContactPlant, ContactState, FemPad
    from tactile_mirror.contact.simulation import (
        SimulationResult,
        calibrate_friction,
        simulate,
        simulate_many,
    )
    from tactile_mirror.contact.solver import ContactSolver
    from tactile_mirror.contact.step import OPEN, SLIP, STICK, ContactConvergenceError, ContactStep
