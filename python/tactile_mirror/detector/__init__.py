"""Slip detection at run time: the Jordan recurrent MLP of the paper (section 3.2, Figs 9-10),
the same net with load-memory inputs (:mod:`.memory`: the ridge's load integrals and the pad's
shear rate and load), and the same net on a bank of IIR filters over the rates (:mod:`.bank`:
low-passed rates, rate energy, load and peak load), which sees slips that creep in.

Inputs per ridge: ``[v_L, v_R, u_L, u_R]`` (stress rates from the estimator,
or raw circuit voltages; the kind is stored with the weights) plus the net's own
previous ``y_pred``; outputs ``y_slip`` (slip when >= 0.8), ``y_non = 1 - y_slip``
and ``y_pred`` (the incipient-slip level). Running is the allocation-free C++ kernel
``jordan_mlp.hpp``; :mod:`.network` is its numpy specification. Training, evaluation and
the detector build are in :mod:`tactile_mirror.lab.detector`.
"""
from __future__ import annotations

from tactile_mirror.detector.bank import DEFAULT_BANK, bank_features
from tactile_mirror.detector.core import (
    BANK_WEIGHTS,
    DEFAULT_WEIGHTS,
    EARLY_WEIGHTS,
    MEMORY_WEIGHTS,
    PAD_WEIGHTS,
    PAPER_WEIGHTS,
    SlipDetector,
    reference_run,
)
from tactile_mirror.detector.data_prep import features_from_result, targets_from_result
from tactile_mirror.detector.memory import MEMORY_CHANNELS, memory_features
from tactile_mirror.detector.network import Params, forward, init_params, loss_and_grad
from tactile_mirror.detector.normalisation import fit_normalisation
from tactile_mirror.detector.weights import (
    FEATURE_KINDS,
    FORMAT_VERSION,
    KINDS,
    DetectorWeights,
    WeightsError,
)

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
    "PAD_WEIGHTS",
    "PAPER_WEIGHTS",
    "DetectorWeights",
    "Params",
    "SlipDetector",
    "WeightsError",
    "bank_features",
    "features_from_result",
    "fit_normalisation",
    "forward",
    "init_params",
    "loss_and_grad",
    "memory_features",
    "reference_run",
    "targets_from_result",
]
