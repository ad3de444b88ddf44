"""The tactile-mirror loop: stages, the loop runner, recordings, the simulated closed loop.

- :mod:`~tactile_mirror.loop.design`: the default law designed from a stage's data sheet,
  the shear calibration and the sample rate (:func:`design_loop`);
- :mod:`~tactile_mirror.loop.calibration`: the shear calibration's fits (shear weights, the
  signal's sign and size per metre) from a known displacement;
- :mod:`~tactile_mirror.loop.stage`: the :class:`Stage` protocol and :class:`SimulatedStage`;
- :mod:`~tactile_mirror.loop.runner`: :class:`LoopRunner` (fixed rate, latency percentiles;
  :class:`StageError` when the stage driver fails mid-run);
- :mod:`~tactile_mirror.loop.recording`: :class:`Recording` (npz, bit-identical replay);
- :mod:`~tactile_mirror.loop.capi`: the C ABI's library path and a cffi binding;
- :mod:`~tactile_mirror.loop.finger`: finger paths (seeded, band-limited, within a stage's limits);
- :mod:`~tactile_mirror.loop.scene`: one simulated closed-loop scene (:class:`LoopScene`,
  :func:`run_scene`): finger, contact plant, circuit, pipeline and stage;

The control laws the pipeline runs are in :mod:`tactile_mirror.pipeline.controller`; the
closed-loop experiment, its envelope and figures in :mod:`tactile_mirror.lab.loop`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from tactile_mirror._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "header_path": "capi", "library_path": "capi",
    "band_pass": "calibration", "fit_shear_scale": "calibration", "fit_shear_weights": "calibration",
    "triangle_path": "calibration",
    "LoopDesign": "design", "design_loop": "design",
    "Recording": "recording", "RecordingError": "recording", "RigTrace": "recording",
    "ArraySource": "runner", "LoopResult": "runner", "LoopRunner": "runner", "StageError": "runner",
    "LoopScene": "scene", "SceneResult": "scene", "run_scene": "scene",
    "SimulatedStage": "stage", "Stage": "stage", "StageLimits": "stage",
})

if TYPE_CHECKING:
    from tactile_mirror.loop.calibration import band_pass, fit_shear_scale, fit_shear_weights, triangle_path
    from tactile_mirror.loop.capi import header_path, library_path
    from tactile_mirror.loop.design import LoopDesign, design_loop
    from tactile_mirror.loop.recording import Recording, RecordingError, RigTrace
    from tactile_mirror.loop.runner import ArraySource, LoopResult, LoopRunner, StageError
    from tactile_mirror.loop.scene import LoopScene, SceneResult, run_scene
    from tactile_mirror.loop.stage import SimulatedStage, Stage, StageLimits
