"""Scenes: what one contact experiment does and which outputs it wants.

A :class:`Scene` describes the finger (rigid plate) motion, the friction, the pad, the
sample rate, sensor noise and the outputs wanted; :func:`tactile_mirror.simulate` runs it.

``paper(name)`` gives the paper's Figure 5(b) profiles: the plate moves down at
0.06 mm/s for 0.5 s (30 um indent), then sideways at 0.2 mm/s; ``"fig6"`` never stops,
``"fig7"`` stops at A (t = 1.00-1.05 s), ``"fig8"`` stops at B (t = 1.40-1.45 s, just
before slip). ``random(n, seed, ...)`` draws training and test scenes.

Scenes compare and hash by content (arrays included): a scene that went to a worker and
came back in its result equals the one sent, and :attr:`Scene.content_key` names a
scene's content in caches.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import numbers
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from tactile_mirror.checks import real_number, real_sequence
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.geometry import MAX_RIDGES, RidgeGeometry, too_many_ridges
from tactile_mirror.noise import SensorNoise

__all__ = ["DEFAULT_FRICTION", "DEFAULT_KINETIC_RATIO", "MAX_INDENT_STRAIN", "MAX_NOISE", "MAX_SAMPLES", "OUTPUTS", "Scene",
           "paper", "random"]

#: Coulomb friction between finger and ridge. Chosen so that the paper's fig6 scene
#: (default ridge, kinetic ratio 0.85) reaches gross slip inside the 1.4-1.5 s the paper
#: shows; measured with tactile_mirror.contact.calibrate_friction: 1.448 s with the
#: per-sample friction law, 1.471 s with the rate-independent event-driven one.
DEFAULT_FRICTION = 0.76

#: Kinetic / static friction of the finger on the silicone ridges (static friction of
#: skin-like contacts exceeds kinetic by 10-30 %).
DEFAULT_KINETIC_RATIO = 0.85

#: Outputs a scene may ask for. "forces", "slip" and "stress" are cheap (per step:
#: sums and one small matrix product); "signals" runs the PVDF circuit; "state" keeps
#: every surface node's stick/slip/open state and position; "fields" the full stress
#: field at ``field_times`` (one sparse solve each).
OUTPUTS = frozenset({"forces", "slip", "stress", "signals", "state", "fields"})

#: Deepest indent a scene may ask for, as a fraction of the ridge height (the
#: nominal compressive strain of the ridge). The contact model is linear
#: small-strain elasticity on the undeformed geometry; at 10 % nominal strain a
#: neo-Hookean solid (the usual model of silicone) already carries about 12 % more
#: stress than the linear law gives, and the error grows quickly beyond. The paper's
#: 30 um on a 2 mm ridge is 1.5 %; the training and held-out scenes reach at most 2.5 %.
MAX_INDENT_STRAIN = 0.10

#: Largest sensor noise a scene may add, V rms. The signals are tens of mV and the
#: front end's op-amps swing a few volts; Gaussian noise of 1 V rms would clip a
#: +-5 V swing in one sample of about 1.7 million, and beyond that the unclipped
#: noise model describes no real circuit.
MAX_NOISE = 1.0
#: Samples a generated scene may have (duration x fs): 1e9, hours at the kHz rates of a pad
#: (1e300 x 1e300 overflowed the sample count).
MAX_SAMPLES = 1e9
_DEFAULT_OUTPUTS = frozenset({"forces", "slip", "stress", "signals"})


def _feed_content(h, value) -> None:
    """Feed ``value``'s content to the hash ``h``, type-tagged and unambiguous: real numbers
    by value (``2`` and ``2.0`` alike, as they compare; a numpy float of another width than
    64 bits as the array it is, since it computes otherwise), arrays by dtype, shape and bytes,
    sequences and sets element by element, dataclasses field by field."""
    if value is None:
        h.update(b"N")
    elif isinstance(value, (bool, np.bool_)):
        h.update(b"B1" if value else b"B0")
    elif isinstance(value, numbers.Integral):
        h.update(f"I{int(value)};".encode())
    elif isinstance(value, np.floating) and value.dtype != np.float64:
        # a float32 computes otherwise than the float64 of the same value: not the same scene
        h.update(f"A{value.dtype.str};();".encode() + value.tobytes())
    elif isinstance(value, numbers.Real):
        v = float(value)
        h.update(f"I{int(v)};".encode() if v.is_integer() else f"F{v.hex()};".encode())
    elif isinstance(value, str):
        data = value.encode()
        h.update(f"S{len(data)};".encode() + data)
    elif isinstance(value, np.ndarray):
        if value.dtype.hasobject:
            raise TypeError("a scene's arrays must hold numbers, not objects")
        h.update(f"A{value.dtype.str};{value.shape};".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, (tuple, list)):
        h.update(f"T{len(value)};".encode())
        for v in value:
            _feed_content(h, v)
    elif isinstance(value, (frozenset, set)):
        parts = []
        for v in value:
            sub = hashlib.sha256()
            _feed_content(sub, v)
            parts.append(sub.digest())
        h.update(f"U{len(parts)};".encode() + b"".join(sorted(parts)))
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = dataclasses.fields(value)
        h.update(f"D{type(value).__module__}.{type(value).__qualname__};{len(fields)};".encode())
        for f in fields:
            _feed_content(h, f.name)
            _feed_content(h, getattr(value, f.name))
    else:
        raise TypeError(f"cannot name the content of a {type(value).__name__} in a scene")


@dataclass(frozen=True, eq=False)
class Scene:
    """One contact experiment.

    Scenes are immutable and compare and hash by content: two scenes are equal when every
    field is (arrays by dtype, shape and bytes; numbers by value, so ``duration=2`` equals
    ``duration=2.0``), whichever process made them. :attr:`content_key` is the hex digest
    of that content.

    Motion (SI units): the plate indents at ``indent_speed`` for ``indent_duration``,
    then slides along ``y`` at ``slide_speed``, standing still during each
    ``(start, end)`` interval in ``stops`` (seconds). Or give ``trajectory``: a pair of
    arrays ``(plate_y, indent)`` in m, one value per sample at ``fs``, which overrides
    the profile.

    Parameters
    ----------
    duration : float
        Length of the run, s (ignored with ``trajectory``).
    fs : float
        Sample rate of the outputs (and the quasi-static step rate), Hz.
    indent_speed, indent_duration, slide_speed : float
        m/s, s, m/s.
    stops : tuple of (float, float)
        Intervals during which the plate stands still.
    trajectory : tuple of arrays or None
        Explicit ``(plate_y, indent)``.
    friction : float
        Static Coulomb coefficient.
    kinetic_ratio : float
        Kinetic over static friction, in (0, 1] (1: plain Coulomb). Below 1, gross
        slip releases stored shear: the sharp stress drop that tells slip from a stop.
    n_ridges : int
        1 (the paper's single ridge) or more (a pad; 6 in the paper's hardware), at most
        :data:`~tactile_mirror.geometry.MAX_RIDGES` (64).
    finger_radius : float
        Effective curvature radius of the finger over the pad, m: inner ridges press
        deeper by ``y^2 / (2 R)``. The finger pulp flattens on the pad, so this is far
        larger than the fingertip's own radius; the default 2 m makes the outer ridges
        of a 6-ridge pad (7.5 mm off centre) press 14 um less than the centre ones.
    noise : float
        Sensor noise added to v_out and u_out, V rms, below :data:`MAX_NOISE`.
    seed : int
        Seed of the noise: a non-negative integer (what ``numpy.random.default_rng`` takes).
    outputs : frozenset of str
        Subset of :data:`OUTPUTS`.
    stop_after_slip : float or None
        End the run this long after gross slip (s), to save time when only the slip
        onset matters.
    geometry : RidgeGeometry
    circuit : PVDFCircuit
    field_times : tuple of float
        Times (s) at which full stress fields are kept when "fields" is asked.
    noise_model : SensorNoise or None
        Noise derived from the circuit (thermal, op-amp, mains hum;
        :class:`tactile_mirror.noise.SensorNoise`), added to v_out and u_out on top of
        the white ``noise``; drawn from seed ``[1, seed]`` (independent of the white
        noise). Its circuit must be the scene's ``circuit``. Default None: none.
    """

    duration: float = 2.0
    fs: float = 1000.0
    indent_speed: float = 0.06e-3
    indent_duration: float = 0.5
    slide_speed: float = 0.2e-3
    stops: tuple = ()
    trajectory: tuple | None = None
    friction: float = DEFAULT_FRICTION
    kinetic_ratio: float = DEFAULT_KINETIC_RATIO
    n_ridges: int = 1
    finger_radius: float = 2.0
    noise: float = 0.0
    seed: int = 0
    outputs: frozenset = _DEFAULT_OUTPUTS
    stop_after_slip: float | None = None
    geometry: RidgeGeometry = field(default_factory=RidgeGeometry)
    circuit: PVDFCircuit = field(default_factory=PVDFCircuit)
    field_times: tuple = ()
    noise_model: SensorNoise | None = None

    def __post_init__(self) -> None:
        # (checked, not converted: the fields keep the caller's values)
        for name, unit in (("duration", "s"), ("fs", "Hz"), ("indent_duration", "s"), ("friction", None)):
            real_number(getattr(self, name), name, unit=unit, positive=True)
        for name, unit in (("indent_speed", "m/s"), ("slide_speed", "m/s"), ("noise", "V rms")):
            real_number(getattr(self, name), name, unit=unit, nonnegative=True)
        radius = self.finger_radius
        if isinstance(radius, bool) or not isinstance(radius, numbers.Real):
            raise TypeError(f"finger_radius must be a real number (m), got {type(radius).__name__}")
        if not radius > 0:
            raise ValueError(f"finger_radius must be positive (m; inf for a flat finger), got {radius!r}")
        for k, ft in enumerate(self.field_times):
            real_number(ft, f"field_times[{k}]", unit="s", nonnegative=True)
        if not self.noise < MAX_NOISE:
            raise ValueError(f"noise must be below {MAX_NOISE:g} V rms (MAX_NOISE: the front end swings a few "
                             f"volts), got {self.noise!r}")
        if isinstance(self.seed, (bool, np.bool_)) or not isinstance(self.seed, numbers.Real):
            raise TypeError(f"seed must be a non-negative integer (a numpy random seed), got {self.seed!r}")
        if not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer (a numpy random seed), got {self.seed!r}")
        if not (0 < real_number(self.kinetic_ratio, "kinetic_ratio") <= 1):
            raise ValueError(f"kinetic_ratio must be in (0, 1], got {self.kinetic_ratio!r}")
        nr = self.n_ridges
        if isinstance(nr, (bool, np.bool_)) or not isinstance(nr, numbers.Real) or not math.isfinite(nr):
            raise TypeError(f"n_ridges must be a positive integer, got {nr!r}")
        if int(nr) != nr or nr < 1:
            raise ValueError(f"n_ridges must be a positive integer, got {nr!r}")
        if nr > MAX_RIDGES:  # (1e5 ridges ran out of memory in simulate, with no message)
            raise ValueError(too_many_ridges(nr))
        # (a string was iterated: ("12",) became ((1.0, 2.0),))
        if isinstance(self.stops, (str, bytes)):
            raise TypeError(f"stops must be a sequence of (start, end) pairs in s, got {self.stops!r}")
        stops = []
        for k, st in enumerate(self.stops):
            pair = real_sequence(st, f"stops[{k}]")
            if len(pair) != 2:
                raise ValueError(f"stops[{k}] must be a (start, end) pair in s, got {st!r}")
            stops.append(pair)
        stops = tuple(stops)
        for a, b in stops:
            if not (0 <= a < b):
                raise ValueError(f"stops must be (start, end) intervals with 0 <= start < end, got {(a, b)}")
        object.__setattr__(self, "stops", stops)
        outs = frozenset(self.outputs)
        unknown = outs - OUTPUTS
        if unknown:
            raise ValueError(f"outputs: unknown {sorted(unknown)}; choose from {sorted(OUTPUTS)}")
        object.__setattr__(self, "outputs", outs)
        if self.trajectory is not None:
            y, z = (np.asarray(a) for a in self.trajectory)
            if y.dtype.kind not in "biuf" or z.dtype.kind not in "biuf":
                raise TypeError(f"trajectory must hold real numbers (m), got dtypes {y.dtype}, {z.dtype}")
            y, z = y.astype(float), z.astype(float)
            if y.ndim != 1 or y.shape != z.shape or y.size < 2:
                raise ValueError("trajectory must be two 1-D arrays (plate_y, indent) of the same length >= 2")
            if not (np.all(np.isfinite(y)) and np.all(np.isfinite(z))):
                raise ValueError("trajectory contains non-finite values")
            y.setflags(write=False)
            z.setflags(write=False)
            object.__setattr__(self, "trajectory", (y, z))
        if self.stop_after_slip is not None:
            real_number(self.stop_after_slip, "stop_after_slip", unit="s", nonnegative=True)
        if self.trajectory is None and not self.duration * self.fs <= MAX_SAMPLES:
            raise ValueError(f"duration x fs must give at most {MAX_SAMPLES:g} samples, got "
                             f"{self.duration * self.fs:g} (duration={self.duration!r} s, fs={self.fs!r} Hz)")
        if self.n_samples < 2:
            raise ValueError(f"duration x fs must give at least 2 samples, got {self.n_samples} "
                             f"(duration={self.duration!r} s, fs={self.fs!r} Hz)")
        end = self.n_samples / self.fs
        for k, ft in enumerate(self.field_times):  # (times past the last sample were dropped silently)
            if not ft < end:
                raise ValueError(f"field_times[{k}] = {ft!r} s is not before the end of the run, {end:g} s")
        for name, cls in (("circuit", PVDFCircuit), ("geometry", RidgeGeometry)):
            if not isinstance(getattr(self, name), cls):  # (None failed later, inside simulate)
                raise TypeError(f"{name} must be a {cls.__name__}, got {type(getattr(self, name)).__name__}")
        self._check_indent()
        if self.noise_model is not None:
            if not isinstance(self.noise_model, SensorNoise):
                raise TypeError(f"noise_model must be a tactile_mirror.noise.SensorNoise or None, "
                                f"got {type(self.noise_model).__name__}")
            if self.noise_model.circuit != self.circuit:
                raise ValueError("noise_model: its circuit differs from the scene's circuit (the noise gains "
                                 "come from the circuit); build it as SensorNoise(circuit=scene.circuit, ...)")

    def _check_indent(self) -> None:
        """Refuse an indent beyond the contact model's small-strain range (:data:`MAX_INDENT_STRAIN`)."""
        height = float(self.geometry.height)
        limit = MAX_INDENT_STRAIN * height
        if self.trajectory is not None:
            deepest, what = float(np.max(self.trajectory[1])), "trajectory"
        else:
            deepest = self.indent_speed * min(self.duration, self.indent_duration)
            what = "indent_speed"
        if deepest > limit:
            raise ValueError(
                f"{what}: the plate would indent {deepest * 1e6:.4g} um, beyond the model's small-strain limit "
                f"of {limit * 1e6:.4g} um (MAX_INDENT_STRAIN = {MAX_INDENT_STRAIN:g} of the {height * 1e3:g} mm "
                f"ridge height; the contact model is linear elasticity, which stops holding at larger strain)")

    @functools.cached_property
    def content_key(self) -> str:
        """The scene's content as 64 hex digits (SHA-256): equal for equal scenes, in any
        process and on any machine, and different when any field differs. Computed once."""
        h = hashlib.sha256(b"tactile_mirror.scenes.Scene content 1\0")
        for f in dataclasses.fields(self):
            _feed_content(h, f.name)
            _feed_content(h, getattr(self, f.name))
        return h.hexdigest()

    def __eq__(self, other: object) -> bool:
        if other is self:
            return True
        if type(other) is not type(self):
            return NotImplemented
        return self.content_key == other.content_key

    def __hash__(self) -> int:
        return hash(self.content_key)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("content_key", None)  # (recomputed where it is needed)
        return state

    def __setstate__(self, state: dict) -> None:
        # pickling drops numpy's read-only flag: an unpickled scene stays immutable too
        if state.get("trajectory") is not None:
            y, z = (np.array(a) for a in state["trajectory"])
            y.setflags(write=False)
            z.setflags(write=False)
            state = {**state, "trajectory": (y, z)}
        self.__dict__.update(state)

    @property
    def n_samples(self) -> int:
        if self.trajectory is not None:
            return self.trajectory[0].size
        return round(self.duration * self.fs)

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.n_samples) / self.fs

    def plate_motion(self) -> tuple[np.ndarray, np.ndarray]:
        """``(plate_y, indent)`` per sample, m."""
        if self.trajectory is not None:
            return self.trajectory
        t = self.t
        indent = self.indent_speed * np.minimum(t, self.indent_duration)
        # sliding time: time after the indent phase, minus the time spent in stops
        moving = np.clip(t - self.indent_duration, 0.0, None)
        for a, b in self.stops:
            a2, b2 = max(a, self.indent_duration), max(b, self.indent_duration)
            moving -= np.clip(t - a2, 0.0, b2 - a2)
        return self.slide_speed * moving, indent

    def with_outputs(self, *outputs: str) -> Scene:
        return replace(self, outputs=frozenset(outputs))


def paper(name: str, **overrides: Any) -> Scene:
    """The paper's scenes: ``"fig6"`` (no stop), ``"fig7"`` (stop at A, 1.00-1.05 s),
    ``"fig8"`` (stop at B, 1.40-1.45 s). Keyword overrides go to :class:`Scene`."""
    stops = {"fig6": (), "fig7": ((1.00, 1.05),), "fig8": ((1.40, 1.45),)}
    if name not in stops:
        raise ValueError(f"name must be one of {sorted(stops)}, got {name!r}")
    kw = {"duration": 2.0, "stops": stops[name]}
    kw.update(overrides)
    return Scene(**kw)


def _range(value, name: str) -> tuple[float, float]:
    """``(low, high)`` of a random scene parameter: a pair with ``low <= high``, or one
    number (a fixed value)."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        v = real_number(value, name)
        return v, v
    pair = real_sequence(value, name)
    if len(pair) != 2 or not pair[0] <= pair[1] or not all(math.isfinite(x) for x in pair):
        raise ValueError(f"{name} must be a number or a finite range (low, high) with low <= high, got {value!r}")
    return pair


def random(n: int, seed: int = 0, *, friction: tuple[float, float] = (0.45, 0.85),
           indent: tuple[float, float] = (20e-6, 40e-6), slide_speed: tuple[float, float] = (0.1e-3, 0.4e-3),
           stop_probability: float = 0.5, stop_length: tuple[float, float] = (0.02, 0.1),
           noise: tuple[float, float] = (0.0, 2e-3), duration: float = 2.5, **overrides: Any) -> list[Scene]:
    """``n`` randomized scenes for training and testing (deterministic for a seed).

    Each draws a friction coefficient, an indent depth (reached in 0.5 s), a slide
    speed, sensor noise (V rms) and, with ``stop_probability``, one stop of
    ``stop_length`` s at a random time during the slide. Ranges are ``(low, high)``
    with ``low <= high``; a single number is a fixed value. A stop needs ``duration``
    of at least 0.9 s (it starts between 0.6 s and 0.3 s before the end).
    """
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n!r}")
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not (0.0 <= real_number(stop_probability, "stop_probability") <= 1.0):
        raise ValueError(f"stop_probability must be in [0, 1], got {stop_probability!r}")
    friction, indent, slide_speed, stop_length, noise = (
        _range(v, name) for v, name in ((friction, "friction"), (indent, "indent"), (slide_speed, "slide_speed"),
                                        (stop_length, "stop_length"), (noise, "noise")))
    duration = real_number(duration, "duration", unit="s", positive=True)
    if stop_probability > 0 and duration < 0.9:
        raise ValueError(f"duration must be at least 0.9 s when stops are drawn (stop_probability > 0), got {duration!r}")
    rng = np.random.default_rng(seed)
    scenes = []
    for i in range(int(n)):
        mu = rng.uniform(*friction)
        depth = rng.uniform(*indent)
        v = rng.uniform(*slide_speed)
        stops = ()
        if rng.random() < stop_probability:
            a = rng.uniform(0.6, duration - 0.3)
            stops = ((a, a + rng.uniform(*stop_length)),)
        kw = {"duration": duration, "friction": mu, "indent_speed": depth / 0.5, "slide_speed": v,
              "stops": stops, "noise": rng.uniform(*noise), "seed": int(seed) * 100_003 + i}
        kw.update(overrides)
        scenes.append(Scene(**kw))
    return scenes
