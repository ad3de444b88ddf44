"""The real-time tactile-mirror pipeline: sensor samples in, stage command out.

:class:`MirrorPipeline` is one C++ object (``src/cpp/pipeline.hpp``) stepped once per
tick with no allocation: stress-rate estimation (the equaliser sections of
:mod:`tactile_mirror.estimator`), the slip detector (one Jordan MLP instance per
ridge: the paper's net on the four stress rates, or the filter-bank net of
:mod:`tactile_mirror.detector.bank` on those plus its filter channels) and a stage
controller (:mod:`tactile_mirror.pipeline.controller`). The same
object is reachable through the plain C ABI ``tm.h``
(:mod:`tactile_mirror.loop.capi`), built from the same :attr:`MirrorPipeline.config`.

Channel layout of a tick (float64, whatever the arithmetic)::

    x   = [v_L0, v_R0, v_L1, v_R1, ..., u_L0, u_R0, u_L1, ...]     (u part only with use_u)
    out = [x_cmd (m), v_cmd (m/s), y_slip_0, y_non_0, y_pred_0, y_slip_1, ...]

:class:`~tactile_mirror.pipeline.reference.ReferencePipeline` is the same tick written with
scipy and numpy: the reference the C++ results are tested against.
"""
from __future__ import annotations

import copy
import math
import numbers

import numpy as np

from tactile_mirror import _core
from tactile_mirror._owner import NotCopyable
from tactile_mirror.checks import integer, real_number, sample_rate
from tactile_mirror.filters import validate_sos
from tactile_mirror.pipeline.controller import Controller, controller_from_dict

__all__ = ["PIPELINE_DETECTOR_KINDS", "MirrorPipeline", "as_detector_weights", "pipeline_config"]

_CORES = {("float64", "float64"): "_MirrorPipelineF64", ("float32", "float32"): "_MirrorPipelineF32",
          ("float64", "float32"): "_MirrorPipelineF64F32"}
# Defaults shared with the C ABI (pipeline.hpp): v_limit, u_limit are the front
# end's output swing (V).
_DEFAULTS = _core.pipeline_defaults()


#: Detector kinds the pipeline runs (weights ``kind``).
PIPELINE_DETECTOR_KINDS = ("jordan", "jordan_bank")


def as_detector_weights(detector):
    """DetectorWeights from a SlipDetector, DetectorWeights or a mapping of arrays."""
    w = getattr(detector, "weights", detector)
    if isinstance(w, dict):
        return w
    needed = ("params", "input_mean", "input_scale", "fs")
    if not all(hasattr(w, k) for k in needed):
        raise TypeError("detector must be a SlipDetector, a DetectorWeights or a dict of weight arrays, "
                        f"got {type(detector).__name__}")
    kind = getattr(w, "kind", "jordan")
    if kind not in PIPELINE_DETECTOR_KINDS:
        raise ValueError(f"the pipeline runs detectors of kind {PIPELINE_DETECTOR_KINDS}; weights of kind "
                         f"{kind!r} run through SlipDetector only")
    p = w.params
    bank = w.bank if kind == "jordan_bank" else None
    return {"w1": p.w1, "b1": p.b1, "w2": p.w2, "b2": p.b2, "input_mean": w.input_mean,
            "input_gain": 1.0 / np.asarray(w.input_scale, dtype=np.float64), "fs": float(w.fs),
            # the filter-bank net derives its other inputs from the stress rates in C++
            "features": "stress_rate" if bank is not None else getattr(w, "features", "stress_rate"),
            "detector_kind": kind, "bank": bank}


def _positive(value, name: str) -> float:
    return real_number(value, name, positive=True)


def _position(value, name: str) -> float:
    return real_number(value, name, unit="m")


def _validated_config(config: dict) -> dict:
    """A :attr:`MirrorPipeline.config` (e.g. read from a recording) through
    :func:`pipeline_config` and its checks; the C++ constructor that
    :meth:`MirrorPipeline.from_config` then builds checks every weight array's shape.
    Raises ValueError / TypeError naming the entry."""
    cfg = dict(config)
    missing = [k for k in ("w1", "b1", "w2", "b2", "input_mean", "input_gain", "weights_fs", "fs", "n_ridges")
               if k not in cfg]
    if missing:
        raise ValueError(f"config lacks {', '.join(missing)}: not a MirrorPipeline.config")
    weights = {k: cfg[k] for k in ("w1", "b1", "w2", "b2", "input_mean", "input_gain")}
    weights["fs"] = cfg["weights_fs"]
    weights["features"] = cfg.get("features", "stress_rate")
    weights["detector_kind"] = cfg.get("detector_kind") or "jordan"
    weights["bank"] = cfg.get("bank")
    kw = {k: cfg.get(k) for k in ("sos_v", "sos_u", "sos_diff", "use_u", "v_limit", "u_limit",
                                   "controller", "dtype", "detector_dtype", "activation", "slip_threshold",
                                   "max_hold_ticks", "ridges", "shear_weights", "force_limit")}
    kw["force_input"] = cfg.get("force_input", False)  # (recordings made before the load cell have none)
    return pipeline_config(weights, cfg["fs"], cfg["n_ridges"], **kw)  # (which checks n_ridges)


def pipeline_config(detector, fs, n_ridges: int = 6, *, estimator=None, sos_v=None, sos_u=None, sos_diff=None,
                    use_u: bool | None = None, v_limit=None, u_limit=None, controller=None,
                    dtype=np.float64, detector_dtype=None, activation: str = "fast", slip_threshold: float = 0.8,
                    max_hold_ticks: int = 100, ridges=None, shear_weights=None, force_input: bool = False,
                    force_limit=None) -> dict:
    """Validate and assemble a pipeline configuration (see :class:`MirrorPipeline`)."""
    fs = sample_rate(fs)  # [1, 1e7] Hz, as pipeline.hpp (the laws divide by fs: a denormal rate made commands NaN)
    if isinstance(n_ridges, bool) or not isinstance(n_ridges, numbers.Integral) or not 1 <= n_ridges <= 64:
        raise ValueError(f"n_ridges must be an integer in [1, 64], got {n_ridges!r}")
    n_ridges = int(n_ridges)
    if ridges is None:
        ridges = list(range(n_ridges))
    ridges = [int(r) for r in ridges]
    if len(ridges) != n_ridges or len(set(ridges)) != n_ridges or min(ridges) < 0:
        raise ValueError(f"ridges must list {n_ridges} distinct non-negative ridge indices, got {ridges}")
    w = as_detector_weights(detector)
    weights_fs = _positive(w["fs"], "detector fs")
    if not math.isclose(weights_fs, fs, rel_tol=1e-9):
        raise ValueError(f"fs={fs} Hz does not match the {weights_fs} Hz the detector was trained for")
    features = w.get("features", "stress_rate")
    detector_kind = w.get("detector_kind") or "jordan"
    if detector_kind not in PIPELINE_DETECTOR_KINDS:
        raise ValueError(f"detector_kind must be one of {PIPELINE_DETECTOR_KINDS}, got {detector_kind!r}")
    bank = None
    if detector_kind == "jordan_bank":
        from tactile_mirror.detector.bank import bank_channels, bank_config

        bank = bank_config(w.get("bank"))
        if features != "stress_rate":
            raise ValueError("the filter-bank detector takes stress-rate features")
    elif w.get("bank") is not None:
        raise ValueError("bank is given but detector_kind is 'jordan' (the paper's net has no filter bank)")
    n_det = 4 if bank is None else len(bank_channels(bank))
    if estimator is not None:
        if any(s is not None for s in (sos_v, sos_u, sos_diff)):
            raise ValueError("give either estimator or sos_v/sos_u/sos_diff, not both")
        if not math.isclose(float(estimator.fs), fs, rel_tol=1e-9):
            raise ValueError(f"estimator fs={estimator.fs} Hz does not match fs={fs} Hz")
        sos_v = estimator.sos_rate
        if estimator.use_u:
            sos_u = estimator.sos_rate2
        else:
            sos_diff = estimator.sos_diff
        if use_u is not None and bool(use_u) != bool(estimator.use_u):
            raise ValueError(f"use_u={use_u} contradicts the estimator (use_u={estimator.use_u})")
        use_u = estimator.use_u
    if use_u is None:
        use_u = sos_diff is None
    use_u = bool(use_u)
    sos_v = None if sos_v is None else validate_sos(sos_v, name="sos_v")
    sos_u = None if sos_u is None else validate_sos(sos_u, name="sos_u")
    sos_diff = None if sos_diff is None else validate_sos(sos_diff, name="sos_diff")
    if use_u and sos_diff is not None:
        raise ValueError("sos_diff must be None when u_out is sampled (use_u=True)")
    if not use_u:
        if sos_u is not None:
            raise ValueError("sos_u must be None without u_out (use_u=False)")
        if sos_diff is None:
            raise ValueError("sos_diff (the digital differentiator) is required without u_out (use_u=False)")
    if features == "stress_rate" and sos_v is None:
        raise ValueError("the detector takes stress-rate features: give the estimator (or sos_v and sos_u)")
    if features == "circuit" and (sos_v is not None or sos_u is not None):
        raise ValueError("the detector takes raw circuit voltages: sos_v and sos_u must be None")
    v_limit = float(_DEFAULTS["v_limit"]) if v_limit is None else _positive(v_limit, "v_limit")
    u_limit = float(_DEFAULTS["u_limit"]) if u_limit is None else _positive(u_limit, "u_limit")
    ctrl = controller_from_dict(controller) if not isinstance(controller, Controller) else controller
    dt = np.dtype(dtype)
    if dt not in (np.float32, np.float64):
        raise TypeError(f"dtype must be float32 or float64, got {dt}")
    ddt = dt if detector_dtype is None else np.dtype(detector_dtype)
    if (dt.name, ddt.name) not in _CORES:
        raise TypeError(f"detector_dtype must be dtype, or float32 with float64 filters; got {ddt} with {dt}")
    if activation not in ("exact", "fast"):
        raise ValueError(f"activation must be 'exact' or 'fast', got {activation!r}")
    slip_threshold = _positive(slip_threshold, "slip_threshold")
    if not slip_threshold < 1:
        raise ValueError(f"slip_threshold must lie in (0, 1), got {slip_threshold}")
    if isinstance(max_hold_ticks, bool) or not isinstance(max_hold_ticks, numbers.Integral) \
            or not 0 <= max_hold_ticks <= 2**31 - 1:
        raise ValueError(f"max_hold_ticks must be an integer in [0, 2**31 - 1], got {max_hold_ticks!r}")
    if shear_weights is not None:
        sw = np.asarray(shear_weights, dtype=np.float64)
        if sw.shape != (n_ridges, 2):
            raise ValueError(f"shear_weights must have shape (n_ridges, 2) = ({n_ridges}, 2), got {sw.shape}")
        if not np.all(np.isfinite(sw)):
            raise ValueError("shear_weights must be finite")
        shear_weights = sw.copy()
    if not isinstance(force_input, (bool, np.bool_)):
        raise TypeError(f"force_input must be True or False, got {type(force_input).__name__}")
    force_limit = float(_DEFAULTS["force_limit"]) if force_limit is None else _positive(force_limit, "force_limit")
    if not force_limit <= 1e6:  # (as pipeline.hpp: the force's change times fs stays far from overflow)
        raise ValueError(f"force_limit must lie in (0, 1e6] N, got {force_limit!r}")
    arrays = {}
    for k in ("w1", "b1", "w2", "b2", "input_mean", "input_gain"):
        a = np.asarray(w[k], dtype=np.float64)
        if not np.all(np.isfinite(a)):
            raise ValueError(f"detector {k} must be finite")
        arrays[k] = a.copy()
    if arrays["w1"].ndim != 2 or arrays["w1"].shape[1] != n_det + 1:
        raise ValueError(f"detector w1 must have shape (n_hidden, {n_det + 1}) for a {detector_kind!r} net, "
                         f"got {arrays['w1'].shape}")
    for k in ("input_mean", "input_gain"):
        if arrays[k].shape != (n_det,):
            raise ValueError(f"detector {k} must have shape ({n_det},) for a {detector_kind!r} net, "
                             f"got {arrays[k].shape}")
    return {
        "n_ridges": n_ridges, "ridges": ridges, "fs": fs, "use_u": use_u,
        "sos_v": sos_v, "sos_u": sos_u, "sos_diff": sos_diff,
        "v_limit": v_limit, "u_limit": u_limit, **arrays, "weights_fs": weights_fs,
        "features": features, "activation": activation, "slip_threshold": slip_threshold,
        "max_hold_ticks": int(max_hold_ticks), "controller": ctrl.params(), "dtype": dt.name,
        "detector_dtype": ddt.name, "shear_weights": shear_weights,
        "detector_kind": detector_kind, "bank": bank,
        "force_input": bool(force_input), "force_limit": force_limit,
    }


class MirrorPipeline(NotCopyable):
    """Samples -> stress rates -> slip detector -> stage command, one C++ tick at a time.

    Parameters
    ----------
    detector : SlipDetector or DetectorWeights
        The trained detector, of kind ``"jordan"`` (the paper's net) or
        ``"jordan_bank"`` (the filter-bank net, its bank run in C++ on the stress
        rates); its sample rate must equal ``fs`` (weights made for another rate are
        refused) and its feature kind decides the estimator: ``"stress_rate"`` needs
        equaliser sections, ``"circuit"`` takes raw voltages.
    fs : float
        Tick rate, Hz.
    n_ridges : int
        Ridges in use (each gives 2 strips: L, R).
    estimator : StressRateEstimator, optional
        Source of the sections (``sos_rate``, ``sos_rate2`` or ``sos_diff``) and of
        ``use_u``. Alternatively give ``sos_v``, ``sos_u`` / ``sos_diff`` directly.
    use_u : bool, optional
        ``u_out`` is sampled (``n_inputs = 4 n_ridges``); without it the 2nd-order
        rate comes from the digital differentiator ``sos_diff`` (``n_inputs = 2 n_ridges``).
    v_limit, u_limit : float, optional
        Largest valid ``|v_out|``, ``|u_out|`` (V), e.g. the ADC range; a tick with a
        sample beyond it, or a NaN/Inf sample, is rejected and counted, all state kept.
        Default 15 V, the output swing of a +-15 V front end; must be finite.
    controller : Controller or dict, optional
        :class:`~tactile_mirror.pipeline.PaperController`,
        :class:`~tactile_mirror.pipeline.VelocityController` or None (detection only).
    dtype : {numpy.float64, numpy.float32}
        Arithmetic of filters and detector (inputs and outputs are float64 either way).
    detector_dtype : numpy.float32, optional
        Arithmetic of the detector when it differs from ``dtype``: float64 filters
        (accurate slow poles) with a float32 detector (the dominant cost, halved).
    activation : {"fast", "exact"}
        Detector sigmoid (``"fast"``: polynomial, |error| <= 5e-10 in float64).
    slip_threshold : float
        ``y_slip`` level reported as slip in :attr:`status` (0.8, the paper's).
    max_hold_ticks : int
        Consecutive rejected ticks after which the pipeline is in fault and the
        controller stops the stage.
    ridges : sequence of int, optional
        Which pad ridges the inputs belong to (metadata, kept in :attr:`config`).
    shear_weights : array_like, shape (n_ridges, 2), optional
        The controller's shear signal is ``sum_r w[r, 0] rate_L + w[r, 1] rate_R``;
        default ``(+1, -1)`` per ridge (the L-R stress-rate difference). A calibrated
        set (:func:`tactile_mirror.lab.loop.experiment.calibrate_shear_weights`) stays monotonic in the
        shear where the L-R difference turns back as the ridge edges start to slide.
    force_input : bool
        One more input after the voltages: the pad's tangential force, N, from a load cell
        under the pad (or the stage's force readout). The controller's shear signal is then
        the force's change per tick times ``fs`` (N/s; the integrator holds the force since
        the tare), not the strips' rates: the total force moves only with the relative
        displacement, while the strips also see the tractions a friction change releases
        inside the contact (docs/loop.md, sweat). The detector still reads the strips.
        Calibrate with ``calibrate_shear(..., load_cell=True)`` and design with
        ``design_loop(..., sensor="force")``. Default False.
    force_limit : float
        Largest valid ``|force|``, N (the load cell's range); a tick beyond it, or with a
        NaN/Inf force, is rejected like a bad voltage. Default 100 N; at most 1e6 N.

    Notes
    -----
    :meth:`step` is the C++ method itself (no Python layer in between). A rejected
    tick holds the detector outputs; the controller keeps running on them unless
    the fault state is reached. A tick is rejected when a sample is NaN/Inf
    (``nonfinite``), beyond its limit (``out_of_range``) or when its update would
    make any filter, detector or controller state non-finite (``overflow``): the
    state is then exactly what it was before the tick.

    Threads: one thread at a time steps a pipeline. A call of :meth:`step`,
    :meth:`process_block`, :meth:`reset`, :meth:`set_position`, :attr:`features` or
    :attr:`controller_state` while another thread is inside one of them raises
    ``RuntimeError`` at once (an atomic owner flag; nothing waits). :attr:`status`
    may be read from any thread: it is the status published at the end of the last
    call, never torn. :attr:`outputs` is a live view for the stepping thread. :meth:`process_block` is exactly a loop of
    :meth:`step`, so a recording replays bit for bit.

    Examples
    --------
    >>> pipe = MirrorPipeline(detector, fs=1000.0, estimator=est,            # doctest: +SKIP
    ...                       controller=VelocityController(v_max=0.02))
    >>> out = np.zeros(pipe.n_outputs)
    >>> x_cmd = pipe.step(sample, out)        # sample: float64 (pipe.n_inputs,)
    """

    def __init__(self, detector, fs, n_ridges: int = 6, **kwargs):
        cfg = pipeline_config(detector, fs, n_ridges, **kwargs)
        self._init_from_config(cfg)

    @classmethod
    def from_config(cls, config: dict) -> MirrorPipeline:
        """Rebuild a pipeline from :attr:`config` (e.g. stored in a recording)."""
        self = cls.__new__(cls)
        self._init_from_config(_validated_config(config))
        return self

    def _init_from_config(self, cfg):
        core_cls = getattr(_core, _CORES[(cfg["dtype"], cfg.get("detector_dtype") or cfg["dtype"])])
        self._config = cfg
        self._core = core_cls(cfg["n_ridges"], cfg["fs"], cfg["use_u"], cfg["sos_v"], cfg["sos_u"],
                              cfg["sos_diff"], cfg["v_limit"], cfg["u_limit"], cfg["w1"], cfg["b1"],
                              cfg["w2"], cfg["b2"], cfg["input_mean"], cfg["input_gain"], cfg["weights_fs"],
                              cfg["activation"], cfg["slip_threshold"], cfg["max_hold_ticks"],
                              dict(cfg["controller"]), cfg.get("shear_weights"), cfg.get("bank"),
                              bool(cfg.get("force_input", False)),
                              float(cfg.get("force_limit", _DEFAULTS["force_limit"])))
        self._controller = controller_from_dict(cfg["controller"])
        # Bound C++ methods: calling them costs no Python frame.
        self.step = self._core.step
        self.process_block = self._core.process_block

    # The two methods below are replaced per instance by the C++ ones; they are
    # here for the documentation.
    def step(self, x, out=None) -> float:
        """One tick.

        Parameters
        ----------
        x : ndarray, float64, shape (n_inputs,), C-contiguous
            The tick's samples (V); no conversion is made.
        out : ndarray, float64, shape (n_outputs,), optional
            Receives ``[x_cmd, v_cmd, y_slip_0, y_non_0, y_pred_0, ...]``.

        Returns
        -------
        float
            The commanded stage position, m.
        """
        raise NotImplementedError  # pragma: no cover

    def process_block(self, x, features: bool = False, accepted: bool = False):
        """Run ``n`` ticks: exactly ``n`` calls of :meth:`step`.

        Parameters
        ----------
        x : array_like, shape (n, n_inputs)
        features : bool
            Also return the detector's features, shape (n, n_ridges, 4):
            ``rate_L, rate_R, rate2_L, rate2_R`` (Pa/s, Pa/s^2 with an estimator).
        accepted : bool
            Also return a bool array (n,), False for rejected ticks.

        Returns
        -------
        tuple
            ``(out,)``, ``(out, features)``, ``(out, accepted)`` or
            ``(out, features, accepted)``, ``out`` of shape (n, n_outputs).
        """
        raise NotImplementedError  # pragma: no cover

    # -- properties -----------------------------------------------------------------
    @property
    def config(self) -> dict:
        """Everything the pipeline was built from (plain arrays, numbers, strings)."""
        return {k: (v.copy() if isinstance(v, np.ndarray) else copy.deepcopy(v)) for k, v in self._config.items()}

    @property
    def controller(self) -> Controller:
        return self._controller

    @property
    def fs(self) -> float:
        return self._core.fs

    @property
    def n_ridges(self) -> int:
        return self._core.n_ridges

    @property
    def n_inputs(self) -> int:
        return self._core.n_inputs

    @property
    def n_outputs(self) -> int:
        return self._core.n_outputs

    @property
    def use_u(self) -> bool:
        return self._core.use_u

    @property
    def dtype(self) -> np.dtype:
        return self._core.dtype

    @property
    def detector_kind(self) -> str:
        """``"jordan"`` (the paper's net) or ``"jordan_bank"`` (the filter-bank net)."""
        return self._config["detector_kind"]

    @property
    def detector_dtype(self) -> np.dtype:
        return self._core.detector_dtype

    @property
    def simd_path(self) -> str:
        """Code paths of the filters and the detector on this CPU."""
        return self._core.simd_path

    @property
    def outputs(self) -> np.ndarray:
        """Read-only view of the last tick's outputs (updated in place)."""
        return self._core.outputs

    @property
    def features(self) -> np.ndarray:
        """Features of the last accepted tick, shape (n_ridges, 4)."""
        return self._core.features

    @property
    def last_accepted(self) -> bool:
        return self._core.last_accepted

    @property
    def status(self) -> dict:
        """Counters and flags: ``ticks``, ``rejected``, ``nonfinite``, ``out_of_range``,
        ``overflow``, ``last_bad_tick``, ``last_bad_channel``, ``consecutive_rejected``,
        ``fault``, ``slip``, ``at_limit``, ``last_reason`` (``"nonfinite"``,
        ``"out_of_range"``, ``"overflow"`` or ``""``). Readable from any thread."""
        return self._core.status

    @property
    def controller_state(self) -> dict:
        """``position`` (the law's, m), ``command`` (what goes to the stage: the position led by the
        braking distance of a planning stage, ``planner_decel``; m), ``velocity`` (m/s), ``asymmetry``
        and ``direction``."""
        return self._core.controller_state

    def reset(self, x0: float = 0.0) -> None:
        """Back to rest with the command at ``x0`` (m, finite); counters cleared."""
        self._core.reset(_position(x0, "x0"))

    def set_position(self, x: float) -> None:
        """Tell the controller where the stage is (m, finite); the commanded velocity becomes 0."""
        self._core.set_position(_position(x, "x"))

    def time_step_ns(self, n_iter: int = 200000, repeats: int = 5) -> float:
        """Mean time of one tick measured inside C++, ns (best of ``repeats``; state restored)."""
        return self._core.time_step_ns(integer(n_iter, "n_iter", 1, 10**9), integer(repeats, "repeats", 1, 1000))

    def __repr__(self) -> str:
        c = self._config
        return (f"MirrorPipeline(n_ridges={c['n_ridges']}, fs={c['fs']:g} Hz, use_u={c['use_u']}, "
                f"controller={c['controller']['kind']!r}, dtype={c['dtype']})")
