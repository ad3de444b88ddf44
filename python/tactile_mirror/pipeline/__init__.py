"""The real-time pipeline: sensor samples in, stage command out, in one C++ object.

- :mod:`~tactile_mirror.pipeline.mirror`: :class:`MirrorPipeline` (estimator, detector and
  control law, stepped per tick with no allocation) and :func:`pipeline_config`;
- :mod:`~tactile_mirror.pipeline.controller`: the control laws it runs (the paper's stage law,
  the velocity law with limits), their one definition of parameters and numpy references;
- :mod:`~tactile_mirror.pipeline.reference`: :class:`ReferencePipeline`, the same tick in
  scipy and numpy.
"""
from __future__ import annotations

from tactile_mirror.pipeline.controller import (
    Controller,
    NoController,
    PaperController,
    VelocityController,
    controller_from_dict,
)
from tactile_mirror.pipeline.mirror import (
    PIPELINE_DETECTOR_KINDS,
    MirrorPipeline,
    as_detector_weights,
    pipeline_config,
)
from tactile_mirror.pipeline.reference import ReferencePipeline

__all__ = [
    "PIPELINE_DETECTOR_KINDS",
    "Controller",
    "MirrorPipeline",
    "NoController",
    "PaperController",
    "ReferencePipeline",
    "VelocityController",
    "as_detector_weights",
    "controller_from_dict",
    "pipeline_config",
]
