"""Slip detection: the Jordan recurrent MLP of the paper (section 3.2, Figs 9-10), and the
same net with load-memory inputs (:mod:`.memory`: the ridge's load integrals and the pad's
shear rate and load), and the same net on a bank of IIR filters over the rates (:mod:`.bank`:
low-passed rates, rate energy, load and peak load), which sees slips that creep in.

Inputs per ridge: ``[v_L, v_R, u_L, u_R]`` (stress rates from the estimator,
or raw circuit voltages; the kind is stored with the weights) plus the net's own
previous ``y_pred``; outputs ``y_slip`` (slip when >= 0.8), ``y_non = 1 - y_slip``
and ``y_pred`` (the incipient-slip level). Training is numpy BPTT with
L-BFGS-B; running is the allocation-free C++ kernel ``jordan_mlp.hpp``.

``evaluate`` here is the function :func:`.evaluate.evaluate`, not its module (which it
shadows as an attribute); ``from tactile_mirror.detector.evaluate import roc`` reaches the
module's names, ``importlib.import_module("tactile_mirror.detector.evaluate")`` the module.
"""
from __future__ import annotations

from .bank import DEFAULT_BANK, bank_features
from .core import (
    BANK_WEIGHTS,
    DEFAULT_WEIGHTS,
    EARLY_WEIGHTS,
    MEMORY_WEIGHTS,
    PAPER_WEIGHTS,
    SlipDetector,
    reference_run,
)
from .data_prep import features_from_result, targets_from_result
from .evaluate import DetectionMetrics, EvaluationReport, ForceRatioDetector, evaluate
from .figures import figure10, figure10_data
from .memory import MEMORY_CHANNELS, memory_features
from .network import Params, forward, init_params, loss_and_grad
from .training import TrainingSet, augment_noise, fit_normalisation, make_training_set, train_detector
from .weights import FEATURE_KINDS, FORMAT_VERSION, KINDS, DetectorWeights, WeightsError

__all__ = [
    "BANK_WEIGHTS",
    "DEFAULT_BANK",
    "DEFAULT_WEIGHTS",
    "EARLY_WEIGHTS",
    "FEATURE_KINDS",
    "FORMAT_VERSION",
    "KINDS",
    "MEMORY_CHANNELS",
    "MEMORY_WEIGHTS",
    "PAPER_WEIGHTS",
    "DetectionMetrics",
    "DetectorWeights",
    "EvaluationReport",
    "ForceRatioDetector",
    "Params",
    "SlipDetector",
    "TrainingSet",
    "WeightsError",
    "augment_noise",
    "bank_features",
    "evaluate",
    "features_from_result",
    "figure10",
    "figure10_data",
    "fit_normalisation",
    "forward",
    "init_params",
    "loss_and_grad",
    "make_training_set",
    "memory_features",
    "reference_run",
    "targets_from_result",
    "train_detector",
]
