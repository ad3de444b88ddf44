"""Building and studying slip detectors: training (BPTT + L-BFGS-B), evaluation on held-out
scenes, the threshold sweep, the detector build (scene cache, candidate selection,
calibration) and Figure 10.

- :mod:`.training`: :func:`train_detector`, :class:`TrainingSet`; :mod:`.augment`: its augmentations;
- :mod:`.evaluation`: :func:`evaluate`, the sensor conditions, the force-ratio baseline;
- :mod:`.thresholds`: :func:`roc`, detection against false alarms over thresholds;
- :mod:`.build`: the default detector's build (``tactile-mirror train``);
- :mod:`.figures`: Figure 10; :mod:`.synthetic`: synthetic scenes for kernel benchmarks.
"""
from __future__ import annotations

from tactile_mirror.lab.detector.augment import augment_noise
from tactile_mirror.lab.detector.evaluation import (
    NOISE_CONDITIONS,
    DetectionMetrics,
    EvaluationReport,
    ForceRatioDetector,
    evaluate,
)
from tactile_mirror.lab.detector.figures import figure10, figure10_data
from tactile_mirror.lab.detector.thresholds import RocCurve, roc
from tactile_mirror.lab.detector.training import TrainingSet, make_training_set, train_detector

__all__ = [
    "NOISE_CONDITIONS",
    "DetectionMetrics",
    "EvaluationReport",
    "ForceRatioDetector",
    "RocCurve",
    "TrainingSet",
    "augment_noise",
    "evaluate",
    "figure10",
    "figure10_data",
    "make_training_set",
    "roc",
    "train_detector",
]
