"""Recordings of loop runs: samples, outputs, stage positions, the pipeline configuration.

A :class:`Recording` saves to one ``.npz`` file (numpy's zip of arrays, read back
with ``allow_pickle=False``) and replays offline through the pipeline's block API:
:meth:`Recording.replay` rebuilds the pipeline from the stored configuration and
gives, on the same build and CPU, outputs bit-identical to the recorded ones
(the block call is exactly a loop of the per-tick call).

File layout
-----------
==================  ==================  =============================================
key                 shape / type        meaning
==================  ==================  =============================================
``format``          str                 ``"tactile-mirror-recording"``
``format_version``  int                 :data:`FORMAT_VERSION`
``fs``              float               tick rate, Hz
``x0``              float               controller start position, m
``samples``         (n, n_inputs)       the pipeline's inputs, V
``outputs``         (n, n_outputs)      ``x_cmd, v_cmd, y_slip_0, y_non_0, y_pred_0, ...``
``accepted``        (n,) bool           False for rejected ticks
``stage_position``  (n,)                measured stage position, m
``cfg_<name>``      arrays              the pipeline configuration's arrays (sos, weights)
``config``          str (JSON)          the configuration's other fields
``metadata``        str (JSON)          free-form (run settings, latency, scene ...)
==================  ==================  =============================================
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from .._npzfile import check_json, read_versioned

__all__ = ["FORMAT", "FORMAT_VERSION", "Recording", "RecordingError"]

FORMAT = "tactile-mirror-recording"
FORMAT_VERSION = 1
_CFG_ARRAYS = ("sos_v", "sos_u", "sos_diff", "w1", "b1", "w2", "b2", "input_mean", "input_gain")


class RecordingError(ValueError):
    """A recording file or object is invalid."""


@dataclass
class Recording:
    """One run of the loop.

    Attributes
    ----------
    fs : float
        Tick rate, Hz.
    samples : ndarray, shape (n, n_inputs)
    outputs : ndarray, shape (n, n_outputs)
    accepted : ndarray of bool, shape (n,)
    stage_position : ndarray, shape (n,)
    config : dict
        :attr:`tactile_mirror.MirrorPipeline.config`.
    x0 : float
        Start position of the controller, m.
    metadata : dict
        JSON-serialisable.
    """

    fs: float
    samples: np.ndarray
    outputs: np.ndarray
    accepted: np.ndarray
    stage_position: np.ndarray
    config: dict
    x0: float = 0.0
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        self.validate()

    @property
    def n_ticks(self) -> int:
        return int(self.samples.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Tick times, s."""
        return np.arange(self.n_ticks) / self.fs

    def validate(self) -> None:
        """Raise :class:`RecordingError` unless shapes, types and the configuration agree."""
        if not (isinstance(self.fs, (int, float, np.floating)) and math.isfinite(self.fs) and self.fs > 0):
            raise RecordingError(f"fs must be a positive number of Hz, got {self.fs!r}")
        if not isinstance(self.config, dict):
            raise RecordingError(f"config must be a dict, got {type(self.config).__name__}")
        for key in ("n_ridges", "use_u", "fs"):
            if key not in self.config:
                raise RecordingError(f"config lacks {key!r}")
        R = int(self.config["n_ridges"])
        ni = 2 * R * (2 if self.config["use_u"] else 1)
        no = 2 + 3 * R
        arrays = {"samples": self.samples, "outputs": self.outputs, "accepted": self.accepted,
                  "stage_position": self.stage_position}
        for name, a in arrays.items():
            if not isinstance(a, np.ndarray):
                raise RecordingError(f"{name} must be a numpy array, got {type(a).__name__}")
        n = self.samples.shape[0] if self.samples.ndim == 2 else -1
        expected = {"samples": (n, ni), "outputs": (n, no), "accepted": (n,), "stage_position": (n,)}
        for name, shape in expected.items():
            if arrays[name].shape != shape:
                raise RecordingError(f"{name} must have shape {shape} for {R} ridges, got {arrays[name].shape}")
        if self.accepted.dtype != bool:
            raise RecordingError(f"accepted must be a bool array, got {self.accepted.dtype}")
        if not math.isclose(float(self.config["fs"]), float(self.fs), rel_tol=1e-12):
            raise RecordingError(f"fs={self.fs} differs from the configuration's {self.config['fs']}")
        check_json(self.metadata, "metadata", RecordingError)

    # -- files ----------------------------------------------------------------------------
    def save(self, path) -> None:
        """Write the recording to ``path`` (``.npz``; the suffix is not added)."""
        self.validate()
        cfg = dict(self.config)
        arrays = {}
        for k in _CFG_ARRAYS:
            v = cfg.pop(k, None)
            if v is not None:
                arrays["cfg_" + k] = np.asarray(v, dtype=np.float64)
        with open(os.fspath(path), "wb") as f:
            np.savez(f, format=np.array(FORMAT), format_version=np.array(FORMAT_VERSION),
                     fs=np.array(float(self.fs)), x0=np.array(float(self.x0)), samples=self.samples,
                     outputs=self.outputs, accepted=self.accepted, stage_position=self.stage_position,
                     config=np.array(json.dumps(cfg, sort_keys=True)),
                     metadata=np.array(json.dumps(self.metadata, sort_keys=True)), **arrays)

    @classmethod
    def load(cls, path) -> Recording:
        """Read and validate a file written by :meth:`save`."""
        path = os.fspath(path)
        data = read_versioned(path, FORMAT, FORMAT_VERSION, RecordingError, "tactile-mirror recording")
        for key in ("fs", "x0", "samples", "outputs", "accepted", "stage_position", "config", "metadata"):
            if key not in data:
                raise RecordingError(f"{path!r}: key {key!r} missing")
        try:
            cfg = json.loads(str(data["config"]))
            meta = json.loads(str(data["metadata"]))
        except ValueError as exc:
            raise RecordingError(f"{path!r}: config or metadata is not valid JSON: {exc}") from None
        for k in _CFG_ARRAYS:
            cfg[k] = data.get("cfg_" + k)
        return cls(fs=float(data["fs"]), samples=data["samples"], outputs=data["outputs"],
                   accepted=data["accepted"], stage_position=data["stage_position"], config=cfg,
                   x0=float(data["x0"]), metadata=meta)

    # -- replay ---------------------------------------------------------------------------
    def pipeline(self):
        """A fresh pipeline built from the stored configuration, reset to ``x0``."""
        from ..pipeline import MirrorPipeline

        pipe = MirrorPipeline.from_config(self.config)
        pipe.reset(self.x0)
        return pipe

    def replay(self):
        """Run the samples through the block API of a rebuilt pipeline.

        Returns
        -------
        outputs : ndarray, shape (n, n_outputs)
        accepted : ndarray of bool, shape (n,)
        """
        pipe = self.pipeline()
        out, acc = pipe.process_block(self.samples, accepted=True)
        return out, acc

    def verify(self) -> bool:
        """True if :meth:`replay` reproduces the recorded outputs bit for bit."""
        out, acc = self.replay()
        if out.shape != self.outputs.shape:
            return False
        bits = np.ascontiguousarray(out).view(np.uint64)
        ref = np.ascontiguousarray(self.outputs, dtype=np.float64).view(np.uint64)
        return bool(np.array_equal(bits, ref) and np.array_equal(acc, self.accepted))
