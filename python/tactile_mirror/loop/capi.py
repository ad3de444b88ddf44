"""The C ABI (``tm.h``) from Python: where the library is, and a cffi ABI-mode binding.

The shared library ``libtactile_mirror_c`` and its header ``tm.h`` are installed in
the package directory (``include/tm.h``). C, LabVIEW, MATLAB or a DAQ callback link
against the library; :func:`library_path` and :func:`header_path` tell a build
where they are, e.g. ``cc prog.c -I$(dirname header) -L$(dirname lib) -ltactile_mirror_c``.

:func:`load` opens the library with cffi in ABI mode (no compiler needed), and
:class:`CPipeline` drives a pipeline through it with the same configuration
(:attr:`tactile_mirror.MirrorPipeline.config`) and the same methods as the
pybind11 class: the C ABI is tested against it this way.
"""
from __future__ import annotations

import contextlib
import os
import re
import sys
from pathlib import Path

import numpy as np

__all__ = ["CAPIError", "CPipeline", "controller_param_owner", "header_path", "include_dir", "library_path", "load",
           "new_config"]

_LIB_NAMES = {"linux": "libtactile_mirror_c.so", "darwin": "libtactile_mirror_c.dylib",
              "win32": "tactile_mirror_c.dll"}


def _package_dirs():
    from tactile_mirror import _core

    here = Path(__file__).resolve().parent.parent
    dirs = [Path(_core.__file__).resolve().parent, here]
    return list(dict.fromkeys(dirs))


def library_path() -> str:
    """Absolute path of the C ABI shared library installed with the package.

    Raises
    ------
    FileNotFoundError
        The library is not installed (a build without it).
    """
    name = _LIB_NAMES.get(sys.platform, _LIB_NAMES["linux"])
    for d in _package_dirs():
        p = d / name
        if p.is_file():
            return str(p)
    raise FileNotFoundError(f"{name} is not installed next to tactile_mirror._core")


def header_path() -> str:
    """Absolute path of ``tm.h`` installed with the package."""
    for d in _package_dirs():
        p = d / "include" / "tm.h"
        if p.is_file():
            return str(p)
    src = Path(__file__).resolve().parents[3] / "src" / "cpp" / "tm.h"
    if src.is_file():
        return str(src)
    raise FileNotFoundError("tm.h is not installed with tactile_mirror")


def include_dir() -> str:
    """Directory holding ``tm.h`` (for ``-I``)."""
    return os.path.dirname(header_path())


def cdef_from_header(text: str) -> str:
    """The declarations of tm.h in the subset of C that cffi's cdef parses."""
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.DOTALL)
    lines = []
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("#") or s in ('extern "C" {', "}") and not s.startswith("} "):
            continue
        lines.append(line.replace("TM_API ", ""))
    body = "\n".join(lines)
    body = re.sub(r"#define TM_ABI_VERSION \d+", "", body)
    return body


_FFI = None


def load(path: str | None = None):
    """Open the C library with cffi (ABI mode).

    Parameters
    ----------
    path : str, optional
        Library to open; default :func:`library_path`.

    Returns
    -------
    ffi, lib
        The ``cffi.FFI`` holding the declarations of ``tm.h`` and the opened library.
    """
    import cffi

    global _FFI
    if _FFI is None:
        ffi = cffi.FFI()
        ffi.cdef(cdef_from_header(Path(header_path()).read_text()))
        _FFI = ffi
    lib = _FFI.dlopen(path or library_path())
    # Resolve every declaration now. cffi resolves a name on first use under a lock of
    # the FFI object that all opened libraries share; a garbage collection inside that
    # look-up can run CPipeline.__del__ -> tm_pipeline_destroy -> a first look-up on
    # another library -> the same lock: a deadlock. Resolved names are plain
    # attributes, so later calls (and every __del__) never take that lock.
    for name in dir(lib):
        getattr(lib, name)
    return _FFI, lib


class CAPIError(RuntimeError):
    """A C ABI call returned an error code; ``code`` holds it."""

    def __init__(self, code: int, name: str, message: str):
        super().__init__(f"{name} ({code}): {message}")
        self.code = code


_CTRL_KINDS = {"none": 0, "paper": 1, "velocity": 2}


def _raise_status(ffi, lib, rc: int) -> int:
    """``rc`` if it is not an error code, else :class:`CAPIError` with the library's message."""
    if rc < 0:
        raise CAPIError(rc, ffi.string(lib.tm_status_name(rc)).decode(), ffi.string(lib.tm_last_error()).decode())
    return rc


def new_config(ffi, lib):
    """A ``tm_config*`` holding the library's defaults, filled as the header's ``tm_config_init``
    macro fills a C program's struct: ``tm_config_init_sized`` with the size these
    declarations give it. (The exported ``tm_config_init`` fills an ABI-6 struct, for programs
    built against the older headers.)"""
    cfg = ffi.new("tm_config*")
    _raise_status(ffi, lib, lib.tm_config_init_sized(cfg, ffi.sizeof("tm_config")))
    return cfg


def controller_param_owner(cfg, name: str):
    """The struct of ``cfg`` that holds controller parameter ``name``: ``cfg.controller``, or
    ``cfg`` itself for the parameters added after ABI 6 (kept in ``tm_config``'s tail:
    ``planner_decel``); None if these declarations have neither (an older header)."""
    if hasattr(cfg.controller, name):
        return cfg.controller
    return cfg if hasattr(cfg, name) else None
_REASONS = {0: "", 1: "nonfinite", 2: "out_of_range", 3: "overflow"}


def _tick_vector(a, n: int, name: str, writable: bool) -> np.ndarray:
    """``a`` itself if it is a float64, 1-D, C-contiguous array of length ``n``
    (writable for an output); else an error naming the argument. No conversion: a
    wrong buffer handed to C would be read or written past its end."""
    if not isinstance(a, np.ndarray):
        raise TypeError(f"{name} must be a numpy array of float64, got {type(a).__name__}")
    if a.dtype != np.float64:
        raise TypeError(f"{name} must have dtype float64, got {a.dtype}")
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    if not a.flags.c_contiguous:
        raise ValueError(f"{name} must be C-contiguous")
    if writable and not a.flags.writeable:
        raise ValueError(f"{name} must be writeable")
    return a


class CPipeline:
    """A pipeline driven through the C ABI, built from a :attr:`MirrorPipeline.config`
    (checked first as :meth:`MirrorPipeline.from_config` checks it, unless ``check=False``).

    Same tick semantics as :class:`tactile_mirror.MirrorPipeline` (``step``,
    ``process_block``, ``reset``, ``set_position``, ``status``); every call goes
    through ``tm.h``.
    """

    def __init__(self, config: dict, path: str | None = None, *, check: bool = True):
        from tactile_mirror.pipeline import MirrorPipeline

        # Checked by building it as MirrorPipeline.from_config builds it (every array's
        # shape against the sizes it implies): the C ABI takes bare pointers and reads as
        # many values as the sizes say, so a short array here would be read past its end.
        # check=False hands the config to tm_pipeline_create as it is, for testing the C
        # side's own checks (its arrays must then have the sizes the config implies).
        c = MirrorPipeline.from_config(config).config if check else config
        ffi, lib = load(path)
        self.ffi, self.lib = ffi, lib
        cfg = new_config(ffi, lib)
        self._keep = []

        def arr(a):
            if a is None:
                return ffi.NULL, 0
            a = np.ascontiguousarray(a, dtype=np.float64)
            self._keep.append(a)
            return ffi.cast("const double*", ffi.from_buffer(a)), (a.shape[0] if a.ndim == 2 else a.size)

        cfg.precision = 64 if np.dtype(c["dtype"]) == np.float64 else 32
        cfg.detector_precision = 64 if np.dtype(c.get("detector_dtype") or c["dtype"]) == np.float64 else 32
        cfg.n_ridges = int(c["n_ridges"])
        cfg.fs = float(c["fs"])
        cfg.use_u = 1 if c["use_u"] else 0
        cfg.sos_v, cfg.n_sos_v = arr(c["sos_v"])
        cfg.sos_u, cfg.n_sos_u = arr(c["sos_u"])
        cfg.sos_diff, cfg.n_sos_diff = arr(c["sos_diff"])
        cfg.v_limit = float(c["v_limit"])
        cfg.u_limit = float(c["u_limit"])
        w1 = np.asarray(c["w1"])
        cfg.n_hidden = int(w1.shape[0])
        cfg.w1, _ = arr(c["w1"])
        cfg.b1, _ = arr(c["b1"])
        cfg.w2, _ = arr(c["w2"])
        cfg.b2, _ = arr(c["b2"])
        cfg.input_mean, _ = arr(c["input_mean"])
        cfg.input_gain, _ = arr(c["input_gain"])
        cfg.weights_fs = float(c["weights_fs"])
        cfg.activation = 1 if c["activation"] == "fast" else 0
        cfg.slip_threshold = float(c["slip_threshold"])
        cfg.max_hold_ticks = int(c["max_hold_ticks"])
        cfg.shear_weights = arr(c.get("shear_weights"))[0]
        bank = c.get("bank")
        if bank is not None:
            cfg.detector_kind = 1
            cfg.bank_lp_taus, cfg.bank_n_lp = arr(np.asarray(bank["lp_taus"], dtype=np.float64))
            cfg.bank_abs_taus, cfg.bank_n_abs = arr(np.asarray(bank["abs_taus"], dtype=np.float64))
            cfg.bank_load_tau = float(bank["load_tau"])
            cfg.bank_peak_tau = float(bank["peak_tau"])
            if bank.get("knee") is not None:
                cfg.bank_knee = arr(np.asarray(bank["knee"], dtype=np.float64))[0]
            cfg.bank_pad_mean = 1 if bank.get("pad_mean") else 0
        cfg.force_input = 1 if c.get("force_input") else 0
        if c.get("force_limit") is not None:
            cfg.force_limit = float(c["force_limit"])
        ctrl = c["controller"]
        cfg.controller.kind = _CTRL_KINDS[ctrl["kind"]]
        for k, v in ctrl.items():
            if k != "kind":
                setattr(controller_param_owner(cfg, k), k, float(v))
        h = ffi.new("tm_pipeline*")
        self._check(lib.tm_pipeline_create(cfg, h))
        self._keep.clear()
        self.handle = h[0]
        ni = ffi.new("size_t*")
        no = ffi.new("size_t*")
        self._check(lib.tm_pipeline_sizes(self.handle, ni, no))
        self.n_inputs, self.n_outputs = int(ni[0]), int(no[0])
        self.fs = float(c["fs"])
        self.n_ridges = int(c["n_ridges"])
        self.last_accepted = True
        self._out = np.zeros(self.n_outputs)

    def _check(self, rc: int) -> int:
        return _raise_status(self.ffi, self.lib, rc)

    def step(self, x, out=None) -> float:
        """One tick, as :meth:`tactile_mirror.MirrorPipeline.step`: ``x`` float64
        (n_inputs,) C-contiguous; ``out`` float64 (n_outputs,) C-contiguous and
        writeable. No conversion is made (TypeError / ValueError otherwise)."""
        x = _tick_vector(x, self.n_inputs, "x", False)
        o = self._out if out is None else _tick_vector(out, self.n_outputs, "out", True)
        rc = self._check(self.lib.tm_pipeline_step(self.handle, self.ffi.from_buffer("double[]", x), x.size,
                                                   self.ffi.from_buffer("double[]", o), o.size))
        self.last_accepted = rc == 0
        return float(o[0])

    def process_block(self, x, accepted: bool = False):
        x = np.asarray(x)
        if x.dtype.kind not in "iuf":  # (bools refused, as MirrorPipeline.process_block does)
            raise TypeError(f"x must hold real numbers, got dtype {x.dtype}")
        x = np.ascontiguousarray(x, dtype=np.float64)  # a copy in the right layout
        if x.ndim != 2 or x.shape[1] != self.n_inputs:
            raise ValueError(f"x must have shape (n_ticks, {self.n_inputs}), got {x.shape}")
        n = x.shape[0]
        out = np.zeros((n, self.n_outputs))
        acc = np.zeros(n, dtype=np.uint8)
        nrej = self.ffi.new("size_t*")
        self._check(self.lib.tm_pipeline_process_block(
            self.handle, self.ffi.from_buffer("double[]", x), n, self.n_inputs,
            self.ffi.from_buffer("double[]", out), self.n_outputs, self.ffi.from_buffer("uint8_t[]", acc), nrej))
        return (out, acc.astype(bool)) if accepted else (out,)

    def reset(self, x0: float = 0.0) -> None:
        """Back to rest at ``x0`` (m); a non-finite ``x0`` is a CAPIError (TM_ERR_ARGUMENT)."""
        self._check(self.lib.tm_pipeline_reset(self.handle, float(x0)))

    def set_position(self, x: float) -> None:
        """Tell the controller where the stage is (m); non-finite: CAPIError (TM_ERR_ARGUMENT)."""
        self._check(self.lib.tm_pipeline_set_position(self.handle, float(x)))

    @property
    def features(self) -> np.ndarray:
        f = np.zeros((self.n_ridges, 4))
        self._check(self.lib.tm_pipeline_features(self.handle, self.ffi.from_buffer("double[]", f), f.size))
        return f

    @property
    def status(self) -> dict:
        s = self.ffi.new("tm_pipeline_status*")
        s.struct_size = self.ffi.sizeof("tm_pipeline_status")
        self._check(self.lib.tm_pipeline_get_status(self.handle, s))
        return {"ticks": s.ticks, "rejected": s.rejected, "nonfinite": s.nonfinite,
                "out_of_range": s.out_of_range, "last_bad_tick": s.last_bad_tick,
                "last_bad_channel": s.last_bad_channel, "consecutive_rejected": s.consecutive_rejected,
                "fault": bool(s.fault), "slip": bool(s.slip), "at_limit": bool(s.at_limit),
                "position": s.position, "velocity": s.velocity, "overflow": s.overflow,
                "last_reason": _REASONS.get(s.last_reason, str(s.last_reason))}

    def time_step_ns(self, n_iter: int = 200000) -> float:
        ns = self.ffi.new("double*")
        self._check(self.lib.tm_pipeline_time_step_ns(self.handle, int(n_iter), ns))
        return float(ns[0])

    def close(self) -> None:
        """Destroy the pipeline. Safe while another thread is inside a call on it:
        that call finishes first, later calls raise CAPIError (TM_ERR_HANDLE)."""
        h = getattr(self, "handle", 0)
        if h:
            self.handle = 0
            self.lib.tm_pipeline_destroy(h)

    def __del__(self):
        with contextlib.suppress(Exception):  # at interpreter shutdown the library may be gone
            self.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
