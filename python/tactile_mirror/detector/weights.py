"""Detector weights: a versioned, validated file.

File format (``.npz``, numpy's zip of arrays, loaded with ``allow_pickle=False``):

==================  =====================  ==========================================
key                 shape / type           meaning
==================  =====================  ==========================================
``format``          str                    ``"tactile-mirror-detector"``
``format_version``  int                    :data:`FORMAT_VERSION` (version 1 files, which
                                           have no ``kind``, still load as ``"jordan"``)
``kind``            str                    :data:`KINDS`: ``"jordan"`` (the paper's net,
                                           4 inputs), ``"jordan_memory"`` (the same
                                           net on the 8 load-memory channels) or
                                           ``"jordan_bank"`` (on the filter-bank channels)
``w1``              (H, n_inputs + 1)      input-to-hidden weights, last column y_pred(t-1)
``b1``              (H,)
``w2``              (2, H)                 hidden-to-output, rows y_slip, y_pred
``b2``              (2,)
``input_mean``      (n_inputs,)            normalisation: xn = (x - mean) / scale
``input_scale``     (n_inputs,)            positive, in the units of the features
``fs``              float                  sample rate the net was trained for (Hz)
``metadata``        str (JSON)             features kind and units, targets, training;
                                           ``load_tau`` (s) for ``"jordan_memory"``,
                                           ``bank`` (time constants) for ``"jordan_bank"``
==================  =====================  ==========================================

The loader reads only these members (others are ignored, unread), checks each
one's dtype and shape against bounds (``n_hidden <=`` :data:`MAX_HIDDEN`) from its npy
header before reading its data, then checks every key, shape, dtype and
finiteness. Anything wrong with the file's content raises :class:`WeightsError` (a
:class:`ValueError`) saying what; only a path that cannot be opened raises
:class:`OSError`. :meth:`DetectorWeights.save` writes a temporary file beside the
target and moves it into place, so a failed save leaves the previous file intact.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from tactile_mirror._npzfile import Member, check_json, parse_json, read_versioned, write_versioned
from tactile_mirror.detector.bank import bank_channels, bank_config, bank_units
from tactile_mirror.detector.memory import MEMORY_CHANNELS, MEMORY_UNITS
from tactile_mirror.detector.network import Params

__all__ = ["FEATURE_CHANNELS", "FEATURE_KINDS", "FORMAT", "FORMAT_VERSION", "KINDS", "MAX_HIDDEN",
           "DetectorWeights", "WeightsError"]

FORMAT = "tactile-mirror-detector"
#: Version written. 2 added ``kind``; version 1 files load as kind ``"jordan"``.
FORMAT_VERSION = 2
_READ_VERSIONS = (1, 2)
#: Network kinds -> the feature kinds they read.
KINDS = {"jordan": ("stress_rate", "circuit"), "jordan_memory": ("stress_rate_memory",),
         "jordan_bank": ("stress_rate_bank",)}
_KIND_OF_FEATURES = {f: k for k, fs in KINDS.items() for f in fs}

#: Largest hidden size a weights object or file may have: the C++ detector kernel's limit.
MAX_HIDDEN = 1024
_MAX_INPUTS = 64  # bound on stored input widths; the feature kinds have 4
_MAX_METADATA_CHARS = 1 << 20
_MEMBERS = {
    "w1": Member("f", 2, (MAX_HIDDEN, _MAX_INPUTS + 1)),
    "b1": Member("f", 1, (MAX_HIDDEN,)),
    "w2": Member("f", 2, (16, MAX_HIDDEN)),  # bounds only; validate() checks exact shapes
    "b2": Member("f", 1, (16,)),
    "input_mean": Member("f", 1, (_MAX_INPUTS,)),
    "input_scale": Member("f", 1, (_MAX_INPUTS,)),
    "fs": Member("f", 0),
    "metadata": Member("U", 0, max_itemsize=4 * _MAX_METADATA_CHARS),
    "kind": Member("U", 0, max_itemsize=4 * 32, required=False),
}

#: Kinds of input features and their channel units ([v_L, v_R, u_L, u_R] order, then
#: the load-memory channels of :mod:`tactile_mirror.detector.memory`).
FEATURE_KINDS = {
    "stress_rate": ("Pa/s", "Pa/s", "Pa/s^2", "Pa/s^2"),
    "circuit": ("V", "V", "V", "V"),
    "stress_rate_memory": MEMORY_UNITS,
    "stress_rate_bank": bank_units(),  # with the default bank; a weights file's own: its metadata["bank"]
}
#: Channel names per feature kind.
FEATURE_CHANNELS = {
    "stress_rate": MEMORY_CHANNELS[:4],
    "circuit": MEMORY_CHANNELS[:4],
    "stress_rate_memory": MEMORY_CHANNELS,
    "stress_rate_bank": bank_channels(),
}


def feature_units(features: str, bank=None) -> tuple:
    """Units of the channels of a feature kind (of the filter bank ``bank`` for ``"stress_rate_bank"``)."""
    return bank_units(bank) if features == "stress_rate_bank" else FEATURE_KINDS[features]


def feature_channels(features: str, bank=None) -> tuple:
    """Channel names of a feature kind (of the filter bank ``bank`` for ``"stress_rate_bank"``)."""
    return bank_channels(bank) if features == "stress_rate_bank" else FEATURE_CHANNELS[features]


class WeightsError(ValueError):
    """A weights file or object is invalid (wrong version, shape, values)."""


@dataclass
class DetectorWeights:
    """Weights, normalisation and provenance of one trained detector.

    Attributes
    ----------
    params : Params
        Network weights (float64).
    input_mean, input_scale : ndarray, shape (n_inputs,)
        Feature normalisation ``xn = (x - input_mean) / input_scale``, in the
        units of the feature kind (``input_scale > 0``).
    fs : float
        Sample rate in Hz the detector was trained for.
    metadata : dict
        JSON-serialisable. Keys used by the library: ``"features"`` (a key of
        :data:`FEATURE_KINDS`), ``"units"``, ``"targets"``, ``"training"``.
    """

    params: Params
    input_mean: np.ndarray
    input_scale: np.ndarray
    fs: float
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        self.validate()

    @property
    def n_hidden(self) -> int:
        return self.params.n_hidden

    @property
    def n_inputs(self) -> int:
        return self.params.n_inputs

    @property
    def features(self) -> str:
        return self.metadata.get("features", "stress_rate")

    @property
    def kind(self) -> str:
        """``"jordan"`` (the paper's 4-input net), ``"jordan_memory"`` (load-memory inputs) or
        ``"jordan_bank"`` (filter-bank inputs)."""
        return _KIND_OF_FEATURES.get(self.features, "jordan")

    @property
    def load_tau(self) -> float | None:
        """Leak time constant (s) of the load integrals of a ``"jordan_memory"`` net, else None."""
        return float(self.metadata["load_tau"]) if self.kind == "jordan_memory" else None

    @property
    def bank(self) -> dict | None:
        """Time constants of the filter bank of a ``"jordan_bank"`` net (:func:`~.bank.bank_config`), else None."""
        return bank_config(self.metadata["bank"]) if self.kind == "jordan_bank" else None

    @property
    def input_gain(self) -> np.ndarray:
        """``1 / input_scale``: what the kernel multiplies by."""
        return 1.0 / self.input_scale

    def validate(self) -> None:
        """Raise :class:`WeightsError` unless every field is consistent and finite."""
        p = self.params
        arrays = {"w1": p.w1, "b1": p.b1, "w2": p.w2, "b2": p.b2,
                  "input_mean": self.input_mean, "input_scale": self.input_scale}
        for name, a in arrays.items():
            if not isinstance(a, np.ndarray) or a.dtype.kind != "f":
                raise WeightsError(f"{name} must be a float array, got {type(a).__name__}"
                                   f"{'' if not isinstance(a, np.ndarray) else ' of ' + str(a.dtype)}")
        if p.w1.ndim != 2 or p.w1.shape[1] < 2 or p.w1.shape[0] < 1:
            raise WeightsError(f"w1 must have shape (n_hidden, n_inputs + 1), got {p.w1.shape}")
        h, m = p.w1.shape
        if h > MAX_HIDDEN:
            raise WeightsError(f"n_hidden = {h} exceeds {MAX_HIDDEN}, the detector kernel's limit")
        expected = {"b1": (h,), "w2": (2, h), "b2": (2,), "input_mean": (m - 1,), "input_scale": (m - 1,)}
        for name, shape in expected.items():
            if arrays[name].shape != shape:
                raise WeightsError(f"{name} must have shape {shape} for n_hidden={h}, n_inputs={m - 1}, "
                                   f"got {arrays[name].shape}")
        for name, a in arrays.items():
            if not np.all(np.isfinite(a)):
                raise WeightsError(f"{name} contains non-finite values")
        if np.any(self.input_scale < np.finfo(np.float64).tiny):
            # subnormal scales pass "> 0" but their reciprocal, the kernel's gain, is inf
            raise WeightsError(f"input_scale must be positive and normal (>= {np.finfo(np.float64).tiny:.3g}), "
                               f"got {float(self.input_scale.min())!r}")
        if not isinstance(self.fs, (int, float, np.floating)) or not math.isfinite(self.fs) or self.fs <= 0:
            raise WeightsError(f"fs must be a positive number of Hz, got {self.fs!r}")
        if not isinstance(self.metadata, dict):
            raise WeightsError(f"metadata must be a dict, got {type(self.metadata).__name__}")
        kind = self.metadata.get("features", "stress_rate")
        if not isinstance(kind, str) or kind not in FEATURE_KINDS:
            raise WeightsError(f"metadata['features'] must be one of {sorted(FEATURE_KINDS)}, got {kind!r}")
        bank = None
        if kind == "stress_rate_bank":
            if not isinstance(self.metadata.get("bank"), dict):
                raise WeightsError("metadata['bank'] (the filter bank's time constants) is required for "
                                   "'stress_rate_bank' features")
            try:
                bank = bank_config(self.metadata["bank"])
            except ValueError as exc:
                raise WeightsError(f"metadata: {exc}") from None
        n_ch = len(feature_units(kind, bank))
        if m - 1 != n_ch:
            raise WeightsError(f"features {kind!r} have {n_ch} channels, the weights take {m - 1}")
        if kind == "stress_rate_memory":
            tau = self.metadata.get("load_tau")
            if isinstance(tau, bool) or not isinstance(tau, (int, float)) or not math.isfinite(tau) or tau <= 0:
                raise WeightsError(f"metadata['load_tau'] must be a positive number of seconds for "
                                   f"'stress_rate_memory' features, got {tau!r}")
        check_json(self.metadata, "metadata", WeightsError)

    def save(self, path) -> None:
        """Write the weights to ``path`` (``.npz``; the suffix is not added).

        Atomic: the file is written beside ``path`` and moved into place, so a
        failed or interrupted save leaves a previous file at ``path`` intact.
        """
        self.validate()
        p = self.params
        write_versioned(path, FORMAT, FORMAT_VERSION, kind=np.array(self.kind),
                        w1=p.w1, b1=p.b1, w2=p.w2, b2=p.b2, input_mean=self.input_mean,
                        input_scale=self.input_scale, fs=np.array(float(self.fs)),
                        metadata=np.array(json.dumps(self.metadata, sort_keys=True)))

    @classmethod
    def load(cls, path) -> DetectorWeights:
        """Read and validate a weights file written by :meth:`save`.

        Raises
        ------
        WeightsError
            Not a weights file (or a damaged one), unsupported ``format_version``,
            missing key, wrong or oversized shape, wrong dtype, non-finite value, or
            invalid metadata.
        OSError
            ``path`` cannot be opened (:class:`FileNotFoundError` if it does not exist).
        """
        path = os.fspath(path)
        data = read_versioned(path, FORMAT, _READ_VERSIONS, WeightsError, "detector weights file", _MEMBERS)
        fs = data["fs"]
        meta = parse_json(data["metadata"], "metadata", WeightsError, repr(path))
        params = Params(data["w1"], data["b1"], data["w2"], data["b2"])
        try:
            w = cls(params, data["input_mean"], data["input_scale"], float(fs), meta)
        except WeightsError as exc:
            raise WeightsError(f"{path!r}: {exc}") from None
        kind = str(data["kind"]) if "kind" in data else "jordan"
        if int(data["format_version"]) >= 2 and "kind" not in data:
            raise WeightsError(f"{path!r}: key 'kind' missing (format_version 2)")
        if kind not in KINDS:
            raise WeightsError(f"{path!r}: kind must be one of {sorted(KINDS)}, got {kind[:64]!r}")
        if kind != w.kind:
            raise WeightsError(f"{path!r}: kind {kind!r} does not match features {w.features!r}")
        return w

    def check_compatible(self, fs=None, features=None) -> None:
        """Raise :class:`WeightsError` if the weights were made for another rate or feature kind."""
        if fs is not None and not math.isclose(float(fs), self.fs, rel_tol=1e-9):
            raise WeightsError(f"fs={float(fs)} Hz does not match the {self.fs} Hz the detector was trained for")
        if features is not None and features != self.features:
            raise WeightsError(f"features={features!r} do not match the detector's {self.features!r}")
