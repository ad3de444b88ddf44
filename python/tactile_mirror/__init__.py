"""tactile_mirror: closed-loop tactile displays that render static friction.

Data flow (one module or package per stage):

    scene -> contact/ (ridge FEM, Coulomb friction) -> circuit (PVDF charge amp and
    differentiator) -> estimator (stress rate from v_out, u_out) -> detector (Jordan MLP)
    -> pipeline (the real-time object and its control laws) -> loop (stage, runner, recording)

Filtering follows scipy.signal conventions (``sos``, ``zi``, ``axis``); everything is SI
(m, s, Pa, N, V) with time on the last axis.

This package is the runtime that lab code imports. Importing it loads numpy and the
compiled core only: each submodule, and scipy, scikit-fem or matplotlib where a submodule
needs them, load on first use of a name (``tactile_mirror.sosfilt`` imports
:mod:`tactile_mirror.filters` when first read). The studies that built and measured the
runtime (detector build and training, evaluation, the closed-loop experiment and envelope,
benchmarks, figures) are in :mod:`tactile_mirror.lab`, which the runtime never imports.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from tactile_mirror import _core  # noqa: F401  (the compiled core: loaded at import, as promised above)
from tactile_mirror._lazy import attach

__version__ = "0.1.0"

# Public name -> the submodule that defines it, imported when the name is first read.
__getattr__, __dir__, __all__ = attach(__name__, {
    "SLOPE_BAND": "circuit", "CircuitStream": "circuit", "PVDFCircuit": "circuit", "fit_circuit": "circuit",
    "Pad": "contact", "SimulationResult": "contact", "simulate": "contact", "simulate_many": "contact",
    "DetectorWeights": "detector", "SlipDetector": "detector", "WeightsError": "detector",
    "StressRateEstimator": "estimator", "differentiator_sos": "estimator", "equalizer_sos": "estimator",
    "estimate_stress_rate": "estimator",
    "SosFilter": "filters", "UnstableFilterWarning": "filters", "roundoff_bound": "filters",
    "simd_path": "filters", "sosfilt": "filters", "validate_sos": "filters",
    "RidgeGeometry": "geometry",
    "LoopRunner": "loop", "Recording": "loop", "SimulatedStage": "loop", "Stage": "loop", "StageLimits": "loop",
    "library_path": "loop",
    "SensorNoise": "noise",
    "MirrorPipeline": "pipeline", "PaperController": "pipeline", "ReferencePipeline": "pipeline",
    "VelocityController": "pipeline",
    "Scene": "scenes",
}, submodules=("circuit", "contact", "detector", "engine", "estimator", "filters", "geometry", "kernels", "loop", "noise",
               "pipeline", "scenes"))
__all__ += ["__version__"]

if TYPE_CHECKING:  # what type checkers and IDEs see; at run time the names load lazily
    from tactile_mirror import (
        circuit,
        contact,
        detector,
        engine,
        estimator,
        filters,
        geometry,
        kernels,
        loop,
        noise,
        pipeline,
        scenes,
    )
    from tactile_mirror.circuit import SLOPE_BAND, CircuitStream, PVDFCircuit, fit_circuit
    from tactile_mirror.contact import Pad, SimulationResult, simulate, simulate_many
    from tactile_mirror.detector import DetectorWeights, SlipDetector, WeightsError
    from tactile_mirror.estimator import (
        StressRateEstimator,
        differentiator_sos,
        equalizer_sos,
        estimate_stress_rate,
    )
    from tactile_mirror.filters import (
        SosFilter,
        UnstableFilterWarning,
        roundoff_bound,
        simd_path,
        sosfilt,
        validate_sos,
    )
    from tactile_mirror.geometry import RidgeGeometry
    from tactile_mirror.loop import LoopRunner, Recording, SimulatedStage, Stage, StageLimits, library_path
    from tactile_mirror.noise import SensorNoise
    from tactile_mirror.pipeline import MirrorPipeline, PaperController, ReferencePipeline, VelocityController
    from tactile_mirror.scenes import Scene
