"""The tactile-mirror loop: controllers, stages, the loop runner, recordings.

- :mod:`~tactile_mirror.loop.controller`: the paper's stage law and a velocity law
  with limits (both run inside the C++ pipeline; numpy references here);
- :mod:`~tactile_mirror.loop.design`: the default law designed from a stage's data sheet,
  the shear calibration and the sample rate (:func:`design_loop`);
- :mod:`~tactile_mirror.loop.envelope`: gross slips and tracking error against peak finger
  speed (``tactile-mirror loop envelope``);
- :mod:`~tactile_mirror.loop.stage`: the :class:`Stage` protocol and :class:`SimulatedStage`;
- :mod:`~tactile_mirror.loop.runner`: :class:`LoopRunner` (fixed rate, latency percentiles;
  :class:`StageError` when the stage driver fails mid-run);
- :mod:`~tactile_mirror.loop.recording`: :class:`Recording` (npz, bit-identical replay);
- :mod:`~tactile_mirror.loop.capi`: the C ABI's library path and a cffi binding;
- :mod:`~tactile_mirror.loop.finger`: finger paths (seeded, band-limited, within a stage's limits);
- :mod:`~tactile_mirror.loop.scene`: one simulated closed-loop scene (:class:`LoopScene`,
  :func:`run_scene`): finger, contact plant, circuit, pipeline and stage;
- :mod:`~tactile_mirror.loop.figures`: the Fig. 12/13 layout of a run;
- :mod:`~tactile_mirror.loop.experiment`: the closed-loop experiment of the paper's section 4
  (:class:`~tactile_mirror.loop.experiment.ExperimentOptions`, ``run_experiment``).
"""
from __future__ import annotations

from .capi import header_path, library_path
from .controller import Controller, NoController, PaperController, VelocityController, controller_from_dict
from .design import LoopDesign, design_loop
from .recording import Recording, RecordingError
from .runner import ArraySource, LoopResult, LoopRunner, StageError
from .scene import LoopScene, SceneResult, run_scene
from .stage import SimulatedStage, Stage, StageLimits

__all__ = [
    "ArraySource",
    "Controller",
    "LoopDesign",
    "LoopResult",
    "LoopRunner",
    "LoopScene",
    "NoController",
    "PaperController",
    "Recording",
    "RecordingError",
    "SceneResult",
    "SimulatedStage",
    "Stage",
    "StageError",
    "StageLimits",
    "VelocityController",
    "controller_from_dict",
    "design_loop",
    "header_path",
    "library_path",
    "run_scene",
]
