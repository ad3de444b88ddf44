"""tactile_mirror: closed-loop tactile displays that render static friction.

Data flow (one module or package per stage):

    scene -> contact/ (ridge FEM, Coulomb friction) -> circuit (PVDF charge amp and
    differentiator) -> estimator (stress rate from v_out, u_out) -> detector (Jordan MLP)
    -> loop (controller, stage)

Filtering follows scipy.signal conventions (``sos``, ``zi``, ``axis``); everything is SI
(m, s, Pa, N, V) with time on the last axis.
"""
from __future__ import annotations

from . import loop, scenes
from .circuit import SLOPE_BAND, CircuitStream, PVDFCircuit, fit_circuit
from .contact import Pad, RidgeGeometry, SimulationResult, simulate, simulate_many
from .detector import DetectorWeights, SlipDetector, WeightsError, evaluate, train_detector
from .estimator import StressRateEstimator, differentiator_sos, equalizer_sos, estimate_stress_rate
from .filters import SosFilter, UnstableFilterWarning, roundoff_bound, simd_path, sosfilt, validate_sos
from .loop import (
    LoopRunner,
    PaperController,
    Recording,
    SimulatedStage,
    Stage,
    StageLimits,
    VelocityController,
    library_path,
)
from .noise import SensorNoise
from .pipeline import MirrorPipeline, ReferencePipeline
from .scenes import Scene

__version__ = "0.1.0"

__all__ = [
    "SLOPE_BAND",
    "CircuitStream",
    "DetectorWeights",
    "LoopRunner",
    "MirrorPipeline",
    "PVDFCircuit",
    "Pad",
    "PaperController",
    "Recording",
    "ReferencePipeline",
    "RidgeGeometry",
    "Scene",
    "SensorNoise",
    "SimulatedStage",
    "SimulationResult",
    "SlipDetector",
    "SosFilter",
    "Stage",
    "StageLimits",
    "StressRateEstimator",
    "UnstableFilterWarning",
    "VelocityController",
    "WeightsError",
    "__version__",
    "differentiator_sos",
    "equalizer_sos",
    "estimate_stress_rate",
    "evaluate",
    "fit_circuit",
    "library_path",
    "loop",
    "roundoff_bound",
    "scenes",
    "simd_path",
    "simulate",
    "simulate_many",
    "sosfilt",
    "train_detector",
    "validate_sos",
]
