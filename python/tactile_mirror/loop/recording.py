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
``samples``         (n, n_inputs)       the pipeline's inputs, V (and N: a load cell's force, last)
``outputs``         (n, n_outputs)      ``x_cmd, v_cmd, y_slip_0, y_non_0, y_pred_0, ...``
``accepted``        (n,) bool           False for rejected ticks
``stage_position``  (n,)                measured stage position, m
``cfg_<name>``      arrays              the pipeline configuration's arrays (sos, weights)
``config``          str (JSON)          the configuration's other fields
``metadata``        str (JSON)          free-form (run settings, latency, scene ...)
==================  ==================  =============================================

Version 2 adds what a run on a rig (:mod:`tactile_mirror.rig`) records, all optional
(:class:`RigTrace`; a recording without it has none of them):

======================  ==================  =============================================
``rig_block_row``       (n_blocks,) int64   row of each acquisition block's first sample
``rig_block_index``     (n_blocks,) int64   its sample index since the acquisition started
``rig_block_lost``      (n_blocks,) int64   samples lost (never delivered) just before it
``rig_block_t_ns``      (n_blocks,) int64   ``monotonic_ns`` time of its last sample
``rig_command_row``     (n_cmd,) int64      row whose output was sent to the stage
``rig_command_t_ns``    (n_cmd,) int64      when it was sent
``rig_command_x``       (n_cmd,)            the target sent, m
``rig_aux``             (n, n_aux)          acquired channels the pipeline does not read
``rig_aux_names``       str (JSON)          their names
======================  ==================  =============================================

Files of version 1 (no rig members) are read as they are.

Loading reads only these members (others are ignored, unread) and checks each one's
dtype and shape against bounds (at most :data:`MAX_TICKS` ticks, :data:`MAX_RIDGES`
ridges) from its npy header before reading its data; anything wrong with the file's
content raises :class:`RecordingError`, only a path that cannot be opened raises
:class:`OSError`. Saving writes a temporary file beside the target and moves it into
place, so a failed save leaves the previous file intact.
"""
from __future__ import annotations

import json
import math
import numbers
import os
from dataclasses import dataclass, field

import numpy as np

from tactile_mirror._npzfile import Member, check_json, parse_json, read_versioned, write_versioned
from tactile_mirror.geometry import MAX_RIDGES

__all__ = ["FORMAT", "FORMAT_VERSION", "MAX_RIDGES", "MAX_TICKS", "READ_VERSIONS", "Recording", "RecordingError",
           "RigTrace"]

FORMAT = "tactile-mirror-recording"
#: The version :meth:`Recording.save` writes (2: the rig's members, :class:`RigTrace`).
FORMAT_VERSION = 2
#: The versions :meth:`Recording.load` reads.
READ_VERSIONS = (1, 2)
_CFG_ARRAYS = ("sos_v", "sos_u", "sos_diff", "w1", "b1", "w2", "b2", "input_mean", "input_gain", "shear_weights")

#: Longest recording a file may hold: 1e8 ticks, 28 h at 1 kHz (a 6-ridge recording
#: that long is 27 GB of samples and outputs).
MAX_TICKS = 10**8
# MAX_RIDGES: most ridges a recording may have, those of a pad (geometry.MAX_RIDGES, 64)
_MAX_IN, _MAX_OUT = 4 * MAX_RIDGES, 2 + 3 * MAX_RIDGES
_MAX_HIDDEN, _MAX_SECTIONS, _MAX_JSON_CHARS = 1024, 64, 1 << 22
_MEMBERS = {
    "fs": Member("f", 0), "x0": Member("f", 0),
    "samples": Member("f", 2, (MAX_TICKS, _MAX_IN)),
    "outputs": Member("f", 2, (MAX_TICKS, _MAX_OUT)),
    "accepted": Member("b", 1, (MAX_TICKS,), max_itemsize=1),
    "stage_position": Member("f", 1, (MAX_TICKS,)),
    "config": Member("U", 0, max_itemsize=4 * _MAX_JSON_CHARS),
    "metadata": Member("U", 0, max_itemsize=4 * _MAX_JSON_CHARS),
    **{"cfg_" + k: Member("f", 2, (_MAX_SECTIONS, 6), required=False) for k in ("sos_v", "sos_u", "sos_diff")},
    "cfg_w1": Member("f", 2, (_MAX_HIDDEN, _MAX_IN + 1), required=False),
    "cfg_b1": Member("f", 1, (_MAX_HIDDEN,), required=False),
    "cfg_w2": Member("f", 2, (16, _MAX_HIDDEN), required=False),
    "cfg_b2": Member("f", 1, (16,), required=False),
    "cfg_input_mean": Member("f", 1, (_MAX_IN,), required=False),
    "cfg_input_gain": Member("f", 1, (_MAX_IN,), required=False),
    "cfg_shear_weights": Member("f", 2, (MAX_RIDGES, 2), required=False),
    **{"rig_" + k: Member("iu", 1, (MAX_TICKS,), required=False)
       for k in ("block_row", "block_index", "block_lost", "block_t_ns", "command_row", "command_t_ns")},
    "rig_command_x": Member("f", 1, (MAX_TICKS,), required=False),
    "rig_aux": Member("f", 2, (MAX_TICKS, _MAX_IN), required=False),
    "rig_aux_names": Member("U", 0, max_itemsize=4 * _MAX_JSON_CHARS, required=False),
}
_RIG_INTS = ("block_row", "block_index", "block_lost", "block_t_ns", "command_row", "command_t_ns")


class RecordingError(ValueError):
    """A recording file or object is invalid."""


@dataclass
class RigTrace:
    """What a run on a rig adds to a :class:`Recording` (format version 2).

    The recording's rows are the samples the acquisition delivered, in order; samples it
    lost (its buffer overflowed) are not rows, they are counted here, before the block that
    came after them.

    Attributes
    ----------
    block_row, block_index, block_lost, block_t_ns : ndarray of int64, shape (n_blocks,)
        Per acquisition block: the row of its first sample, that sample's index since the
        acquisition started, the samples lost just before it, the ``monotonic_ns`` time of
        its last sample.
    command_row, command_t_ns : ndarray of int64, shape (n_commands,)
        Per command sent to the stage: the row whose output it was, when it was sent.
    command_x : ndarray, shape (n_commands,)
        The target sent, m.
    aux : ndarray, shape (n, n_aux)
        Acquired channels the pipeline does not read (e.g. ``force_y``, ``force_z``), per row.
    aux_names : tuple of str
    """

    block_row: np.ndarray
    block_index: np.ndarray
    block_lost: np.ndarray
    block_t_ns: np.ndarray
    command_row: np.ndarray
    command_t_ns: np.ndarray
    command_x: np.ndarray
    aux: np.ndarray
    aux_names: tuple = ()

    def __post_init__(self):
        for k in _RIG_INTS:
            a = getattr(self, k)
            if not isinstance(a, np.ndarray) or a.ndim != 1 or a.dtype.kind not in "iu":
                raise RecordingError(f"rig {k} must be a 1-D integer array")
            setattr(self, k, a.astype(np.int64, copy=False))
        if not isinstance(self.command_x, np.ndarray) or self.command_x.ndim != 1 or self.command_x.dtype.kind != "f":
            raise RecordingError("rig command_x must be a 1-D float array")
        if not isinstance(self.aux, np.ndarray) or self.aux.ndim != 2 or self.aux.dtype.kind != "f":
            raise RecordingError("rig aux must be a 2-D float array (rows, channels)")
        self.aux_names = tuple(self.aux_names)
        if not all(isinstance(n, str) for n in self.aux_names) or len(self.aux_names) != self.aux.shape[1]:
            raise RecordingError(f"rig aux_names must name the {self.aux.shape[1]} aux channels, got "
                                 f"{self.aux_names!r}")
        nb = self.block_row.size
        if any(getattr(self, k).size != nb for k in ("block_index", "block_lost", "block_t_ns")):
            raise RecordingError("rig block arrays must have one entry per block each")
        nc = self.command_row.size
        if self.command_t_ns.size != nc or self.command_x.size != nc:
            raise RecordingError("rig command arrays must have one entry per command each")

    @property
    def lost_samples(self) -> int:
        """Samples the acquisition lost during the run."""
        return int(self.block_lost.sum())

    def check(self, n: int) -> None:
        """Raise :class:`RecordingError` unless it fits a recording of ``n`` rows."""
        if self.aux.shape[0] != n:
            raise RecordingError(f"rig aux has {self.aux.shape[0]} rows for {n} samples")
        r = self.block_row
        if r.size and (r[0] != 0 or np.any(np.diff(r) <= 0) or r[-1] >= max(n, 1)):
            raise RecordingError("rig block_row must start at 0 and grow within the rows")
        if np.any(self.block_lost < 0) or np.any(np.diff(self.block_index) <= 0):
            raise RecordingError("rig block_lost must be >= 0 and block_index grow")
        c = self.command_row
        if c.size and (np.any(c < 0) or np.any(c >= n) or np.any(np.diff(c) < 0)):
            raise RecordingError("rig command_row must be rows of the recording, in order")


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
    rig : RigTrace or None
        What a run on a rig adds (blocks, lost samples, commands sent, other channels).
    """

    fs: float
    samples: np.ndarray
    outputs: np.ndarray
    accepted: np.ndarray
    stage_position: np.ndarray
    config: dict
    x0: float = 0.0
    metadata: dict = field(default_factory=dict)
    rig: RigTrace | None = None

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
        R, use_u, cfg_fs = self.config["n_ridges"], self.config["use_u"], self.config["fs"]
        if isinstance(R, (bool, np.bool_)) or not isinstance(R, (int, np.integer)) or not 1 <= R <= MAX_RIDGES:
            raise RecordingError(f"config['n_ridges'] must be an integer in [1, {MAX_RIDGES}], got {R!r}")
        if not isinstance(use_u, (bool, np.bool_)):
            raise RecordingError(f"config['use_u'] must be a bool, got {use_u!r}")
        if isinstance(cfg_fs, (bool, np.bool_)) or not isinstance(cfg_fs, (int, float, np.integer, np.floating)):
            raise RecordingError(f"config['fs'] must be a number, got {cfg_fs!r}")
        R = int(R)
        force = self.config.get("force_input", False)  # (recordings made before the load cell have none)
        if not isinstance(force, (bool, np.bool_)):
            raise RecordingError(f"config['force_input'] must be a bool, got {force!r}")
        ni = 2 * R * (2 if use_u else 1) + (1 if force else 0)
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
        # what load() reads back (an int or complex array saved and then failed to load)
        for name in ("samples", "outputs", "stage_position"):
            if arrays[name].dtype.kind != "f" or arrays[name].dtype.itemsize > 8:
                raise RecordingError(f"{name} must be a float array (at most 64-bit), got {arrays[name].dtype}")
        if isinstance(self.x0, (bool, np.bool_)) or not isinstance(self.x0, numbers.Real) \
                or not math.isfinite(self.x0):
            raise RecordingError(f"x0 must be a finite position in m, got {self.x0!r}")
        check_json({k: v for k, v in self.config.items() if k not in _CFG_ARRAYS}, "config", RecordingError)
        if self.samples.shape[0] > MAX_TICKS:
            raise RecordingError(f"{self.samples.shape[0]} ticks exceed MAX_TICKS = {MAX_TICKS}")
        if not math.isclose(float(self.config["fs"]), float(self.fs), rel_tol=1e-12):
            raise RecordingError(f"fs={self.fs} differs from the configuration's {self.config['fs']}")
        check_json(self.metadata, "metadata", RecordingError)
        if self.rig is not None:
            if not isinstance(self.rig, RigTrace):
                raise RecordingError(f"rig must be a RigTrace or None, got {type(self.rig).__name__}")
            self.rig.check(self.samples.shape[0])

    # -- files ----------------------------------------------------------------------------
    def save(self, path) -> None:
        """Write the recording to ``path`` (``.npz``; the suffix is not added).

        Atomic: the file is written beside ``path`` and moved into place, so a
        failed or interrupted save leaves a previous file at ``path`` intact.
        """
        self.validate()
        cfg = dict(self.config)
        arrays = {}
        for k in _CFG_ARRAYS:
            v = cfg.pop(k, None)
            if v is not None:
                arrays["cfg_" + k] = np.asarray(v, dtype=np.float64)
        write_versioned(path, FORMAT, FORMAT_VERSION,
                        fs=np.array(float(self.fs)), x0=np.array(float(self.x0)), samples=self.samples,
                        outputs=self.outputs, accepted=self.accepted, stage_position=self.stage_position,
                        config=np.array(json.dumps(cfg, sort_keys=True)),
                        metadata=np.array(json.dumps(self.metadata, sort_keys=True)), **arrays, **self._rig_arrays())

    def _rig_arrays(self) -> dict:
        r = self.rig
        if r is None:
            return {}
        out = {"rig_" + k: getattr(r, k) for k in _RIG_INTS}
        out.update(rig_command_x=np.asarray(r.command_x, dtype=np.float64),
                   rig_aux=np.asarray(r.aux, dtype=np.float64), rig_aux_names=np.array(json.dumps(list(r.aux_names))))
        return out

    @classmethod
    def load(cls, path) -> Recording:
        """Read and validate a file written by :meth:`save`.

        Raises
        ------
        RecordingError
            Anything wrong with the file's content (not a recording, a damaged file,
            another version, a missing member, a dtype or shape out of bounds,
            inconsistent shapes, invalid JSON).
        OSError
            ``path`` cannot be opened (:class:`FileNotFoundError` if it does not exist).
        """
        path = os.fspath(path)
        data = read_versioned(path, FORMAT, READ_VERSIONS, RecordingError, "tactile-mirror recording", _MEMBERS)
        cfg = parse_json(data["config"], "config", RecordingError, repr(path))
        meta = parse_json(data["metadata"], "metadata", RecordingError, repr(path))
        if not isinstance(cfg, dict):
            raise RecordingError(f"{path!r}: config must be a JSON object")
        for k in _CFG_ARRAYS:
            cfg[k] = data.get("cfg_" + k)
        rig_keys = [k for k in data if k.startswith("rig_")]
        rig = None
        if rig_keys:
            missing = [k for k in ["rig_" + k for k in _RIG_INTS] + ["rig_command_x", "rig_aux", "rig_aux_names"]
                       if k not in data]
            if missing:
                raise RecordingError(f"{path!r}: key {missing[0]!r} missing (the file has other rig members)")
            names = parse_json(data["rig_aux_names"], "rig_aux_names", RecordingError, repr(path))
            if not isinstance(names, list):
                raise RecordingError(f"{path!r}: rig_aux_names must be a JSON list")
            try:
                rig = RigTrace(**{k: data["rig_" + k] for k in _RIG_INTS}, command_x=data["rig_command_x"],
                               aux=data["rig_aux"], aux_names=tuple(names))
            except RecordingError as exc:
                raise RecordingError(f"{path!r}: {exc}") from None
        try:
            return cls(fs=float(data["fs"]), samples=data["samples"], outputs=data["outputs"],
                       accepted=data["accepted"], stage_position=data["stage_position"], config=cfg,
                       x0=float(data["x0"]), metadata=meta, rig=rig)
        except RecordingError as exc:  # (the checks of the constructor name the field, not the file)
            raise RecordingError(f"{path!r}: {exc}") from None

    # -- replay ---------------------------------------------------------------------------
    def pipeline(self):
        """A fresh pipeline built from the stored configuration, reset to ``x0``."""
        from tactile_mirror.pipeline import MirrorPipeline

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
