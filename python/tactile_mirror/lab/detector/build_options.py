"""How the detector build builds: :class:`BuildOptions` and the bundled nets' settings.

The seeds of the build's scene sets (training, validation, held-out, extra training),
their scene options (:data:`TRAIN_KWARGS`, :data:`TEST_KWARGS`), the training options
(:data:`TRAIN_OPTIONS`) and the training noise copies (:data:`NOISE_COPIES`,
:data:`NOISE_RANGE`) are the ones the bundled weights were made with;
:func:`~tactile_mirror.lab.detector.build.build_default` reads them from a
:class:`BuildOptions`, whose defaults they are.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactile_mirror.detector.memory import DEFAULT_LOAD_TAU
from tactile_mirror.detector.weights import KINDS
from tactile_mirror.lab.detector.selection import check_false_alarm_rate, condition_names

__all__ = [
    "EXTRA_TRAIN_SEED",
    "NOISE_COPIES",
    "NOISE_RANGE",
    "TEST_KWARGS",
    "TEST_SEED",
    "TRAIN_KWARGS",
    "TRAIN_OPTIONS",
    "TRAIN_SEED",
    "VALIDATION_SEED",
    "BuildOptions",
]

#: Seeds of the training, validation and held-out scene sets (different on purpose).
TRAIN_SEED = 20261121
#: Seed of the extra training scenes drawn from the held-out ranges (``BuildOptions.n_extra_train``;
#: the bound study's extra training seed).
EXTRA_TRAIN_SEED = 99
TEST_SEED = 777
VALIDATION_SEED = 4242

#: Scene options of the training set (``scenes.random`` defaults otherwise).
TRAIN_KWARGS = {"stop_after_slip": 0.3}
#: Training options of the bundled detector.
TRAIN_OPTIONS = {"negative_weight": 10.0, "normalisation": "rms", "pred_weight": 4.0}
#: Sensor-noise copies of every training scene and their noise range, V rms.
NOISE_COPIES = 2
NOISE_RANGE = (0.0, 5e-3)
#: The held-out set: wider friction, indent, slide speed, stop and noise ranges.
TEST_KWARGS = {"friction": (0.35, 1.0), "indent": (15e-6, 50e-6), "slide_speed": (0.05e-3, 0.6e-3),
               "stop_probability": 0.7, "stop_length": (0.02, 0.15), "noise": (0.0, 4e-3),
               "stop_after_slip": 0.3}


def _positive_int(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or int(value) != value or value < minimum:
        kind = "positive" if minimum == 1 else "non-negative"
        raise ValueError(f"{name} must be a {kind} integer, got {value!r}")
    return int(value)


def _pair(name: str, value) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a pair of numbers (low, high), got {value!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
        raise ValueError(f"{name} must satisfy 0 <= low <= high (finite), got {value!r}")
    return lo, hi


@dataclass(frozen=True)
class BuildOptions:
    """How :func:`~tactile_mirror.lab.detector.build.build_default` builds the detector.
    Frozen; fields are checked on construction (``ValueError``/``TypeError`` naming the
    field). The defaults made the bundled weights.

    Attributes
    ----------
    n_train, n_test : int
        Randomised training scenes (seed :data:`TRAIN_SEED`) and held-out scenes
        (seed :data:`TEST_SEED`, wider parameters via ``test_kwargs``). Defaults 64, 200.
    n_hidden : int
        Hidden size of the shipped net. Default 16.
    maxiter : int
        L-BFGS-B iterations per training run. Default 800.
    ridges_per_scene : int
        Ridges of each training scene used as sequences. Default 1.
    seed : int
        First initial seed of the training runs. Default 0.
    study_sizes : tuple of int, optional
        Also run :func:`~tactile_mirror.lab.detector.size_study.hidden_size_study` with
        these hidden sizes (scored on the validation scenes, not the held-out set).
    train_kwargs, test_kwargs : dict, optional
        Scene options of :func:`tactile_mirror.scenes.random`; default
        :data:`TRAIN_KWARGS`, :data:`TEST_KWARGS` (stored as copies).
    train_options : dict, optional
        Extra :func:`~tactile_mirror.lab.detector.training.train_detector` options;
        default :data:`TRAIN_OPTIONS`.
    gain_range : (float, float) or None
        Gain augmentation of the training sequences
        (:func:`~tactile_mirror.lab.detector.augment.augment_gains`), as factors.
        Default (0.6, 1.7); None: none.
    noise_copies : int
        Each training scene enters ``noise_copies`` times with fresh sensor noise
        (:func:`~tactile_mirror.lab.detector.augment.augment_noise`; 0: the scenes' own
        noise). Default :data:`NOISE_COPIES`.
    noise_range : (float, float)
        Range of that noise, V rms. Default :data:`NOISE_RANGE`.
    n_validation, candidates, checkpoint_every : int
        Each net (and the no-feedback baseline) is trained from ``candidates``
        initial seeds (``seed``, ``seed + 1``, ...); of these runs, and of their
        checkpoints every ``checkpoint_every`` iterations (0: final weights only),
        the best on ``n_validation`` scenes (seed :data:`VALIDATION_SEED`, held-out
        ranges) is kept (:func:`~tactile_mirror.lab.detector.selection.select_candidate`).
        Defaults 120, 4, 25.
    progress : bool
        Progress bars. Default True.
    kind : {"jordan", "jordan_memory", "jordan_bank"}
        ``"jordan"``: the paper's net on the four stress rates (``paper_detector.npz``);
        ``"jordan_memory"``: the same net on the load-memory channels
        (:mod:`~tactile_mirror.detector.memory`; ``memory_detector.npz``);
        ``"jordan_bank"``: on the filter-bank channels with the default bank
        (:mod:`~tactile_mirror.detector.bank`; ``bank_detector.npz``).
    load_tau : float
        Leak time constant of the load integrals of ``"jordan_memory"``, s.
    n_extra_train : int
        Extra training scenes drawn from the held-out ranges (``test_kwargs``) with seed
        :data:`EXTRA_TRAIN_SEED`: lower friction and stops, where slips creep in. Default 0.
    bank : dict, optional
        Time constants of the ``"jordan_bank"`` filter bank (:func:`~tactile_mirror.detector.bank.bank_config`);
        default :data:`~tactile_mirror.detector.bank.DEFAULT_BANK`.
    calibrate_fa : float, optional
        After the selection, move ``y_slip``'s decision point so that ``y_slip >= 0.8``
        gives at most this false-alarm rate on the validation scenes
        (:func:`~tactile_mirror.lab.detector.calibration.calibrate_slip`); None (default):
        no calibration.
    compress : bool
        ``"jordan_bank"`` only: train on the bank's inputs compressed to
        ``sign(x) log(1 + |x| / knee)`` (:func:`~tactile_mirror.detector.bank.log_compress`),
        the knees the median ``|x|`` of the training inputs (after the gains), kept in the
        weights' bank. Default False.
    calibrate_conditions : dict, optional
        Instead of ``calibrate_fa``: false-alarm bounds per sensor condition (keys of
        :data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`); the decision point is
        the lowest that keeps the validation scenes within every bound in its condition
        (:func:`~tactile_mirror.lab.detector.calibration.calibrate_slip` with ``conditions``).

        With either, the candidates are chosen by their validation detection at that
        false-alarm rate (the smallest bound) along their threshold sweep
        (``ValidationScorer(at_false_alarm=...)``), since the calibration, not the
        threshold the net was trained to, sets where they operate.
    select_conditions : tuple of str, optional
        Choose the candidates in these sensor conditions (keys of
        :data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`: the validation scenes'
        noise-free outputs plus each condition's noise, ``ValidationScorer(conditions=...)``)
        instead of in the scenes' own noise, by their mean detection at ``select_fa``.
    select_fa : float, optional
        The false-alarm rate of that choice (default: the calibration's, as above).
    """

    n_train: int = 64
    n_test: int = 200
    n_hidden: int = 16
    maxiter: int = 800
    ridges_per_scene: int = 1
    seed: int = 0
    study_sizes: tuple[int, ...] | None = None
    train_kwargs: dict | None = None
    test_kwargs: dict | None = None
    train_options: dict | None = None
    gain_range: tuple[float, float] | None = (0.6, 1.7)
    noise_copies: int = NOISE_COPIES
    noise_range: tuple[float, float] = NOISE_RANGE
    n_validation: int = 120
    candidates: int = 4
    checkpoint_every: int = 25
    progress: bool = True
    kind: str = "jordan"
    load_tau: float = DEFAULT_LOAD_TAU
    n_extra_train: int = 0
    bank: dict | None = None
    calibrate_fa: float | None = None
    calibrate_conditions: dict | None = None
    compress: bool = False
    select_conditions: tuple[str, ...] | None = None
    select_fa: float | None = None

    def __post_init__(self) -> None:
        def put(name, value):
            object.__setattr__(self, name, value)

        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {sorted(KINDS)}, got {self.kind!r}")
        if isinstance(self.load_tau, bool) or not isinstance(self.load_tau, (int, float)) \
                or not (np.isfinite(self.load_tau) and self.load_tau > 0):
            raise ValueError(f"load_tau must be a positive number of seconds, got {self.load_tau!r}")
        put("load_tau", float(self.load_tau))
        if not isinstance(self.compress, bool):
            raise TypeError(f"compress must be True or False, got {self.compress!r}")
        if self.compress and self.kind != "jordan_bank":
            raise ValueError(f"compress is for kind 'jordan_bank' (its bank's inputs), not {self.kind!r}")
        if self.bank is not None:
            from tactile_mirror.detector.bank import bank_config

            put("bank", bank_config(self.bank))
        for name in ("n_train", "n_test", "n_hidden", "maxiter", "ridges_per_scene", "candidates"):
            put(name, _positive_int(name, getattr(self, name)))
        for name in ("noise_copies", "checkpoint_every", "n_extra_train"):
            put(name, _positive_int(name, getattr(self, name), minimum=0))
        if isinstance(self.seed, bool) or int(self.seed) != self.seed:
            raise ValueError(f"seed must be an integer, got {self.seed!r}")
        put("seed", int(self.seed))
        if self.selecting:
            put("n_validation", _positive_int("n_validation", self.n_validation))
        if self.study_sizes is not None:
            put("study_sizes", tuple(_positive_int("study_sizes", h) for h in self.study_sizes))
        for name, default in (("train_kwargs", TRAIN_KWARGS), ("test_kwargs", TEST_KWARGS),
                              ("train_options", TRAIN_OPTIONS)):
            value = getattr(self, name)
            if value is not None and not isinstance(value, dict):
                raise TypeError(f"{name} must be a dict or None, got {type(value).__name__}")
            put(name, dict(default if value is None else value))
        if self.gain_range is not None:
            put("gain_range", _pair("gain_range", self.gain_range))
        put("noise_range", _pair("noise_range", self.noise_range))
        put("progress", bool(self.progress))
        if self.calibrate_fa is not None:
            fa = self.calibrate_fa
            if isinstance(fa, bool) or not isinstance(fa, (int, float)) or not 0 < fa < 1:
                raise ValueError(f"calibrate_fa must be a false-alarm rate in (0, 1), got {fa!r}")
            if not self.selecting:
                raise ValueError("calibrate_fa needs the validation scenes: candidates > 1 or checkpoint_every > 0")
            put("calibrate_fa", float(fa))
        if self.select_conditions is not None:
            put("select_conditions", condition_names(self.select_conditions, "select_conditions"))
            if not self.selecting:
                raise ValueError("select_conditions needs the validation scenes: candidates > 1 or "
                                 "checkpoint_every > 0")
            if self.select_fa is None and self.calibrate_fa is None and self.calibrate_conditions is None:
                raise ValueError("select_conditions needs a false-alarm rate: select_fa, calibrate_fa or "
                                 "calibrate_conditions")
        if self.select_fa is not None:
            check_false_alarm_rate(self.select_fa, "select_fa")
            put("select_fa", float(self.select_fa))
        if self.calibrate_conditions is not None:
            cc = self.calibrate_conditions
            if not isinstance(cc, dict) or not cc:
                raise ValueError(f"calibrate_conditions must be a non-empty dict, got {cc!r}")
            if self.calibrate_fa is not None:
                raise ValueError("give calibrate_fa or calibrate_conditions, not both")
            condition_names(cc, "calibrate_conditions")
            for name, fa in cc.items():
                if isinstance(fa, bool) or not isinstance(fa, (int, float)) or not 0 < fa < 1:
                    raise ValueError(f"calibrate_conditions[{name!r}] must be a false-alarm rate in (0, 1), "
                                     f"got {fa!r}")
            if not self.selecting:
                raise ValueError("calibrate_conditions needs the validation scenes: candidates > 1 or "
                                 "checkpoint_every > 0")
            put("calibrate_conditions", {k: float(v) for k, v in cc.items()})

    @property
    def selecting(self) -> bool:
        """Whether the build chooses among candidates on validation scenes."""
        return self.candidates > 1 or self.checkpoint_every > 0
