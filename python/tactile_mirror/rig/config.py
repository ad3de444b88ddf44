"""The rig's configuration: one TOML file, every key checked before anything moves.

:func:`load_config` reads the file (``tomllib``; ``tomli`` below Python 3.11) and
:func:`parse_config` checks a parsed table: an unknown key, a missing one or a value of the
wrong kind raises one :class:`ConfigError` naming the key (``stage.analog.counts_per_m``)
and what it expects. Nothing is guessed: the force amplifiers' N/V, the encoder's counts per
metre and a serial controller's units per metre have no defaults.

The sections (SI units: m, s, V, N, Hz; ``python/tactile_mirror/rig/example_rig.toml`` is a
complete example, ``docs/rig.md`` explains each key):

``[pad]``            the ridges (two PVDF strips each)
``[acquisition]``    sample rate, block size, buffer, the NI device and the channel map
``[force_sensor]``   the force sensor's charge amplifiers' N/V (y, z)
``[front_end]``      the PVDF charge amplifiers' component values (:class:`~tactile_mirror.circuit.PVDFCircuit`)
``[amplifier_reset]`` how the charge amplifiers are reset before the sensors-only run
``[stage]``          soft limits, speed, acceleration, servo lag, start position, kind;
                     ``[stage.analog]`` or ``[stage.serial]``
``[loop]``           command rate, detector, estimator and the law's design targets
``[bringup]``        the sensors-only run, the calibration move, the delay measurement
``[safety]``         watchdog, position age, communication timeout, late blocks
``[simulation]``     what ``--simulate`` puts in place of the hardware (finger, plant, noise)
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field

from tactile_mirror.loop.stage import StageLimits
from tactile_mirror.rig.daq import TERMINAL_CONFIGS, InputChannel, input_names

__all__ = ["DIALECT_NAMES", "MAX_POSITION_AGE", "ConfigError", "RigConfig", "load_config", "parse_config"]

#: Dialects ``stage.serial.dialect`` names: the built-ins and ``"generic"`` (its strings in
#: ``[stage.serial.generic]``).
DIALECT_NAMES = ("pi_gcs2", "zaber_ascii", "generic")

#: ``safety.max_position_age`` where the file gives none, s, per ``stage.kind``: the analog
#: path's encoder is read every block (a reading some ms old at most; 12 ms stops a frozen
#: counter within 20 ms), a serial line's position every few ms behind the moves (up to about
#: 13 ms old at 115200 baud on Zaber's line, which queries every other command; a silent
#: controller is found by its overdue answer instead, and 40 ms lets a 10-15 ms stall of the
#: machine pass: 25 ms stopped a Zaber run at a 9.4 ms stall).
MAX_POSITION_AGE = {"analog": 0.012, "serial": 0.04}

_REQUIRED = object()


class ConfigError(ValueError):
    """A bad rig configuration: ``key`` (dotted, e.g. ``"stage.soft_limits"``) and what it
    expects, in the message."""

    def __init__(self, key: str, message: str, source: str = ""):
        self.key = key
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{key}: {message}")


# ---------------------------------------------------------------------- value checks
class _Expect(str):
    """What a check returns for a bad value: what it expects, in words."""


# Each takes the value and returns it converted, or an _Expect: what it expects.
def _real(v):
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None


def _number(lo=None, hi=None, lo_open=False, what="a finite number"):
    def check(v):
        x = _real(v)
        if x is None or (lo is not None and (x <= lo if lo_open else x < lo)) or (hi is not None and x > hi):
            return _Expect(what)
        return x
    return check


_POS = _number(0.0, lo_open=True, what="a positive number")
_NONNEG = _number(0.0, what="a number >= 0")
_ANY = _number()


def _int(lo=None, hi=None):
    def check(v):
        if isinstance(v, bool) or not isinstance(v, int) or (lo is not None and v < lo) or (hi is not None and v > hi):
            bounds = f" in [{lo}, {hi}]" if hi is not None else (f" >= {lo}" if lo is not None else "")
            return _Expect(f"an integer{bounds}")
        return v
    return check


def _nonzero(what):
    def check(v):
        x = _real(v)
        return _Expect(what) if x is None or x == 0 else x
    return check


def _str(v):
    return v if isinstance(v, str) else _Expect("a string")


def _bool(v):
    return v if isinstance(v, bool) else _Expect("true or false")


def _choice(*options):
    def check(v):
        return v if isinstance(v, str) and v in options else _Expect("one of " + ", ".join(repr(o) for o in options))
    return check


def _pair(what="a pair [low, high] of numbers with low < high"):
    def check(v):
        if not isinstance(v, list) or len(v) != 2:
            return _Expect(what)
        lo, hi = (_real(x) for x in v)
        return _Expect(what) if lo is None or hi is None or not lo < hi else (lo, hi)
    return check


def _reals(positive=True, what="a list of positive numbers"):
    def check(v):
        if not isinstance(v, list):
            return _Expect(what)
        out = [_real(x) for x in v]
        return _Expect(what) if any(x is None or (positive and x <= 0) for x in out) else tuple(out)
    return check


def _strings(v):
    return tuple(v) if isinstance(v, list) and all(isinstance(x, str) and x for x in v) else _Expect("a list of strings")


def _table(v):
    return v if isinstance(v, dict) else _Expect("a table")


# ---------------------------------------------------------------------- the schema
# section -> {key: (check, default)}; _REQUIRED: no default. Sub-tables are their own entries.
_CIRCUIT_KEYS = ("length", "width", "thickness", "d31", "d32", "d33", "eps_r", "Rf", "Cf", "Rd", "Cd", "Rs")
_SCHEMA: dict[str, dict] = {
    "pad": {"n_ridges": (_int(1, 64), 6)},
    "acquisition": {"fs": (_POS, 1000.0), "block_size": (_int(1, 100_000), 5), "buffer_blocks": (_int(2), 200),
                    "device": (_str, "Dev1"), "terminal_config": (_choice(*TERMINAL_CONFIGS), "default"),
                    "pvdf_range": (_pair(), (-10.0, 10.0)), "force_range": (_pair(), (-10.0, 10.0)),
                    "v_out": (_strings, _REQUIRED), "u_out": (_strings, _REQUIRED),
                    "force_y": (_str, _REQUIRED), "force_z": (_str, _REQUIRED)},
    "force_sensor": {"n_per_v_y": (_nonzero("N/V of the y amplifier (its range setting; not 0, the sign is "
                                            "the direction)"), _REQUIRED),
                     "n_per_v_z": (_nonzero("N/V of the z amplifier (its range setting; not 0)"), _REQUIRED)},
    "front_end": {k: (_ANY if k.startswith("d3") else _POS, None) for k in _CIRCUIT_KEYS},
    "amplifier_reset": {"kind": (_choice("manual", "digital", "none"), "manual"), "line": (_str, ""),
                        "pulse": (_POS, 0.01), "settle": (_NONNEG, 0.2)},
    "stage": {"kind": (_choice("analog", "serial"), _REQUIRED), "soft_limits": (_pair(), _REQUIRED),
              "v_max": (_POS, _REQUIRED), "a_max": (_POS, _REQUIRED), "lag": (_NONNEG, 0.002),
              "start": (_ANY, 0.0), "approach_speed": (_POS, 0.002), "home": (_bool, False),
              "analog": (_table, None), "serial": (_table, None)},
    "stage.analog": {"ao": (_str, _REQUIRED), "counter": (_str, _REQUIRED),
                     "encoder": (_choice("linear", "angular"), "linear"),
                     "counts_per_m": (_nonzero("encoder counts per metre (X4; the encoder's data sheet; not 0)"),
                                      _REQUIRED),
                     "mode": (_choice("velocity", "position"), "position"), "volts_per_m": (_nonzero(
                         "command volts per metre (the amplifier's setting; not 0)"), None),
                     "volts_per_m_s": (_nonzero("command volts per m/s (the amplifier's setting; not 0)"), None),
                     "volts_offset": (_ANY, 0.0), "gain": (_POS, 50.0), "ao_range": (_pair(), (-10.0, 10.0)),
                     "offset": (_ANY, 0.0)},
    "stage.serial": {"dialect": (_choice(*DIALECT_NAMES), _REQUIRED), "port": (_str, _REQUIRED),
                     "baud": (_int(300, 10_000_000), 115200),
                     "units_per_m": (_nonzero("controller units per metre (e.g. 1000 for mm; not 0)"), None),
                     "counts_per_m": (_nonzero("controller counts per metre (the data sheet; not 0)"), None),
                     "axis": (_str, "1"), "device": (_str, ""), "timeout": (_POS, 0.05),
                     "reply_overdue": (_POS, 0.01), "target_age": (_POS, 0.008),
                     "generic": (_table, None)},
    "loop": {"command_rate": (_POS, 1000.0), "sensor": (_choice("strips", "force"), "strips"),
             "weights": (_str, "paper"), "estimator_order": (_int(1, 8), 2), "estimator_bandwidth": (_POS, 100.0),
             "notch": (_reals(), ()), "arm_delay": (_NONNEG, 0.5), "phase_margin": (_NONNEG, 45.0),
             "gain_margin": (_NONNEG, 6.0), "max_sensitivity": (_number(1.0, lo_open=True, what="a number > 1"), 2.0),
             "planner": (_bool, True), "max_hold_ticks": (_int(1, 100_000), 50),
             "rt_priority": (_int(0, 99), 0), "max_error": (_POS, 1.0e-4)},
    "bringup": {"sensors_only": (_POS, 1.0),
                "calibration_amplitudes": (_reals(), (20e-6, 40e-6, 60e-6, 80e-6)),
                "calibration_speed": (_POS, 0.5e-3), "calibration_cycles": (_int(1, 100), 3),
                "calibration_band": (_pair("a pair [low, high] of Hz with 0 < low < high"), (0.3, 15.0)),
                "symmetric": (_bool, True), "delay_steps": (_int(1, 100), 3),
                "delay_step": (_POS, 20e-6), "phase_frequency": (_POS, 20.0), "phase_amplitude": (_POS, 10e-6),
                "phase_duration": (_POS, 1.0)},
    "safety": {"watchdog": (_POS, 0.015), "max_position_age": (_POS, None), "comm_timeout": (_POS, 0.1),
               "late_block": (_POS, 0.01), "late_blocks": (_int(1), 3), "position_margin": (_NONNEG, 0.5e-3)},
    "simulation": {"plant": (_choice("realtime", "fem", "brush"), "realtime"), "seed": (_int(0), 0),
                   "finger_speed": (_POS, 0.01), "finger_amplitude": (_POS, 0.01), "finger_bandwidth": (_POS, 2.0),
                   "finger_a_max": (_POS, 0.5), "finger_duration": (_POS, 120.0), "mu": (_POS, None),
                   "hum": (_NONNEG, 2e-3), "force_noise": (_NONNEG, 2e-3), "travel": (_pair(), (-0.02, 0.02)),
                   "x0": (_ANY, 0.0), "lead": (_POS, None), "baud": (_int(300, 10_000_000), None),
                   "processing": (_NONNEG, 0.5e-3), "rt_priority": (_int(0, 99), 0)},
}
_REQUIRED_SECTIONS = ("acquisition", "force_sensor", "stage")


def _section(raw: dict, name: str, source: str) -> dict:
    """The checked keys of section ``name`` (dotted) of the parsed file ``raw``."""
    table = raw
    for part in name.split("."):
        table = table.get(part, {}) if isinstance(table, dict) else {}
    if not isinstance(table, dict):
        raise ConfigError(name, f"expected a table, got {table!r}", source)
    spec = _SCHEMA[name]
    unknown = sorted(set(table) - set(spec))
    if unknown:
        raise ConfigError(f"{name}.{unknown[0]}", f"unknown key (the section [{name}] has: {', '.join(spec)})", source)
    out = {}
    for key, (check, default) in spec.items():
        if key not in table:
            if default is _REQUIRED:
                what = check(None)
                raise ConfigError(f"{name}.{key}", f"missing: expected {what}", source)
            out[key] = default
            continue
        value = check(table[key])
        if isinstance(value, _Expect):
            raise ConfigError(f"{name}.{key}", f"expected {value}, got {table[key]!r}", source)
        out[key] = value
    return out


@dataclass(frozen=True)
class RigConfig:
    """A checked rig configuration (:func:`parse_config`); each section a dict of its keys
    (defaults filled in), plus what is built from them.

    Attributes
    ----------
    n_ridges : int
    acquisition, force_sensor, front_end, amplifier_reset, stage, loop, bringup, safety, simulation : dict
        The sections' keys (``front_end``: only the component values given).
    analog, serial : dict or None
        ``[stage.analog]`` / ``[stage.serial]`` (None if the file has no such table; ``stage.kind``
        says which one drives the stage).
    limits : StageLimits
        Soft limits, ``v_max``, ``a_max``.
    channels : tuple of InputChannel
        Every acquisition input in :func:`~tactile_mirror.rig.daq.input_names` order
        (``v_out``, ``u_out`` per strip, ``force_y``, ``force_z``).
    source : str
        The file it was read from (``""``: a table).
    """

    n_ridges: int
    acquisition: dict
    force_sensor: dict
    front_end: dict
    amplifier_reset: dict
    stage: dict
    loop: dict
    bringup: dict
    safety: dict
    simulation: dict
    analog: dict | None
    serial: dict | None
    limits: StageLimits
    channels: tuple
    source: str = field(default="", compare=False)

    @property
    def fs(self) -> float:
        return self.acquisition["fs"]

    @property
    def block_size(self) -> int:
        return self.acquisition["block_size"]

    @property
    def block_period(self) -> float:
        """s"""
        return self.block_size / self.fs

    def circuit(self):
        """The front end's :class:`~tactile_mirror.circuit.PVDFCircuit` (defaults where ``[front_end]``
        gives no value)."""
        from tactile_mirror.circuit import PVDFCircuit

        return PVDFCircuit(**self.front_end)

    def pipeline_columns(self, sensor: str | None = None) -> list[int]:
        """Columns of an acquisition block that are the pipeline's inputs: ``v_out`` and ``u_out``
        of every strip, then (``sensor="force"``) ``force_y``."""
        sensor = sensor or self.loop["sensor"]
        cols = list(range(4 * self.n_ridges))
        return cols + [4 * self.n_ridges] if sensor == "force" else cols

    @property
    def command_interval(self) -> float:
        """Shortest interval between two stage commands the configuration allows, s."""
        return 1.0 / self.loop["command_rate"]


def parse_config(raw: dict, source: str = "") -> RigConfig:
    """Check a parsed configuration table (what ``tomllib.load`` returns) and build a
    :class:`RigConfig`. Raises :class:`ConfigError` (naming the key and what it expects) at
    the first problem; ``source`` (the file) leads the message."""
    if not isinstance(raw, dict):
        raise ConfigError("(file)", f"expected a table of sections, got {type(raw).__name__}", source)
    top = {"pad", "acquisition", "force_sensor", "front_end", "amplifier_reset", "stage", "loop", "bringup", "safety",
           "simulation"}
    for key in raw:
        if key not in top:
            raise ConfigError(key, f"unknown section (a rig file has: {', '.join(sorted(top))})", source)
    for name in _REQUIRED_SECTIONS:
        if name not in raw:
            raise ConfigError(name, "missing section", source)
    s = {name: _section(raw, name, source) for name in _SCHEMA if "." not in name}
    R = s["pad"]["n_ridges"]
    acq, stage = s["acquisition"], s["stage"]
    for key in ("v_out", "u_out"):
        if len(acq[key]) != 2 * R:
            raise ConfigError(f"acquisition.{key}", f"expected {2 * R} terminals (strips 0L, 0R, 1L, ... of "
                                                    f"{R} ridges), got {len(acq[key])}", source)
    terminals = list(acq["v_out"]) + list(acq["u_out"]) + [acq["force_y"], acq["force_z"]]
    seen = {}
    for name, t in zip(input_names(R), terminals):
        if t in seen:
            raise ConfigError("acquisition", f"terminal {t!r} is wired to both {seen[t]} and {name}", source)
        seen[t] = name
    front_end = {k: v for k, v in s["front_end"].items() if v is not None}
    try:
        _circuit(front_end)
    except (TypeError, ValueError) as exc:
        raise ConfigError("front_end", str(exc), source) from None
    lo, hi = stage["soft_limits"]
    limits = StageLimits(lo, hi, stage["v_max"], stage["a_max"])
    if not lo <= stage["start"] <= hi:
        raise ConfigError("stage.start", f"expected a position within stage.soft_limits [{lo:g}, {hi:g}] m, "
                                         f"got {stage['start']!r}", source)
    if not lo <= 0.0 <= hi:
        raise ConfigError("stage.soft_limits", f"expected limits around 0 m (the loop's start), got [{lo:g}, {hi:g}]",
                          source)
    kind = stage["kind"]
    if stage[kind] is None:
        raise ConfigError(f"stage.{kind}", f"missing: stage.kind = {kind!r} needs the table [stage.{kind}]", source)
    # (both tables may be there, to switch between them: both are checked)
    analog = _section(raw, "stage.analog", source) if stage["analog"] is not None else None
    serial = _section(raw, "stage.serial", source) if stage["serial"] is not None else None
    stage = {k: v for k, v in stage.items() if k not in ("analog", "serial")}
    if analog is not None:
        _check_analog(analog, limits, source)
    if serial is not None:
        _check_serial(serial, source)
    if s["amplifier_reset"]["kind"] == "digital" and not s["amplifier_reset"]["line"]:
        raise ConfigError("amplifier_reset.line", "missing: kind = 'digital' needs the digital line "
                                                  "(e.g. 'Dev1/port0/line0')", source)
    sim = s["simulation"]
    tlo, thi = sim["travel"]
    if not (tlo <= lo and hi <= thi):
        raise ConfigError("simulation.travel", f"expected the simulated axis's end stops outside the soft limits "
                                               f"[{lo:g}, {hi:g}] m, got [{tlo:g}, {thi:g}]", source)
    if not tlo <= sim["x0"] <= thi:
        raise ConfigError("simulation.x0", f"expected a position within simulation.travel, got {sim['x0']!r}", source)
    block_rate = acq["fs"] / acq["block_size"]
    if s["bringup"]["phase_frequency"] > block_rate / 4:
        raise ConfigError("bringup.phase_frequency", f"expected at most a quarter of the block rate ({block_rate / 4:g} "
                                                     f"Hz), got {s['bringup']['phase_frequency']!r}", source)
    if sim["lead"] is not None and sim["lead"] > acq["block_size"] / acq["fs"]:
        raise ConfigError("simulation.lead", f"expected at most one block ({acq['block_size'] / acq['fs']:g} s), "
                                             f"got {sim['lead']!r}", source)
    safety = s["safety"]
    if safety["max_position_age"] is None:
        safety["max_position_age"] = MAX_POSITION_AGE[kind]
    lo_b, hi_b = s["bringup"]["calibration_band"]
    if not 0 < lo_b < hi_b < acq["fs"] / 2:
        raise ConfigError("bringup.calibration_band", f"expected 0 < low < high < fs / 2 = {acq['fs'] / 2:g} Hz, "
                                                      f"got [{lo_b:g}, {hi_b:g}]", source)
    if safety["comm_timeout"] <= acq["block_size"] / acq["fs"]:
        raise ConfigError("safety.comm_timeout", f"expected more than one block period "
                                                 f"({acq['block_size'] / acq['fs']:g} s), got {safety['comm_timeout']!r}",
                          source)
    dev = acq["device"]
    pvdf, force = acq["pvdf_range"], acq["force_range"]
    fs_ = s["force_sensor"]
    channels = []
    for name, t in zip(input_names(R), terminals):
        physical = t if "/" in t or not dev else f"{dev}/{t}"
        if name.startswith("force_"):
            channels.append(InputChannel(name, physical, "force", fs_["n_per_v_" + name[-1]], force,
                                         acq["terminal_config"]))
        else:
            channels.append(InputChannel(name, physical, "pvdf", None, pvdf, acq["terminal_config"]))
    return RigConfig(n_ridges=R, acquisition=acq, force_sensor=fs_, front_end=front_end,
                     amplifier_reset=s["amplifier_reset"], stage=stage, loop=s["loop"], bringup=s["bringup"],
                     safety=safety, simulation=sim, analog=analog, serial=serial, limits=limits,
                     channels=tuple(channels), source=source)


def _circuit(values: dict):
    from tactile_mirror.circuit import PVDFCircuit

    return PVDFCircuit(**values)


def _check_analog(a: dict, limits: StageLimits, source: str) -> None:
    mode = a["mode"]
    need, other = ("volts_per_m", "volts_per_m_s") if mode == "position" else ("volts_per_m_s", "volts_per_m")
    if a[need] is None:
        raise ConfigError(f"stage.analog.{need}", f"missing: mode = {mode!r} needs the amplifier's scale", source)
    if a[other] is not None:
        raise ConfigError(f"stage.analog.{other}", f"not used in mode = {mode!r} (give {need})", source)
    lo, hi = a["ao_range"]
    if not lo < 0.0 < hi:
        raise ConfigError("stage.analog.ao_range", f"expected a range around 0 V, got [{lo:g}, {hi:g}]", source)
    if mode == "position":
        ends = [a["volts_offset"] + x * a["volts_per_m"] for x in (limits.x_min, limits.x_max)]
        what = "the soft limits"
    else:
        ends = [v * a["volts_per_m_s"] for v in (-limits.v_max, limits.v_max)]
        what = "the full speed stage.v_max"
    if not all(lo <= e <= hi for e in ends):
        raise ConfigError(f"stage.analog.{need}", f"{what} need commands of {min(ends):g} to {max(ends):g} V, "
                                                  f"outside stage.analog.ao_range [{lo:g}, {hi:g}] V", source)


def _check_serial(s: dict, source: str) -> None:
    if (s["units_per_m"] is None) == (s["counts_per_m"] is None):
        raise ConfigError("stage.serial.units_per_m", "expected exactly one of units_per_m (controller units per "
                                                      "metre, e.g. 1000 for a controller in mm) and counts_per_m "
                                                      "(counts per metre from the data sheet); never guessed", source)
    if s["units_per_m"] is None:
        s["units_per_m"] = s["counts_per_m"]
    del s["counts_per_m"]
    if s["dialect"] == "generic" and not s["generic"]:
        raise ConfigError("stage.serial.generic", "missing: dialect = 'generic' needs its command strings in "
                                                  "[stage.serial.generic] (move, query_position, position_reply, "
                                                  "stop, ...)", source)
    if s["dialect"] != "generic" and s["generic"] is not None:
        raise ConfigError("stage.serial.generic", f"only for dialect = 'generic' (the dialect is {s['dialect']!r})",
                          source)
    if s["generic"] is not None:
        bad = [k for k, v in s["generic"].items() if not isinstance(v, (str, int, float)) or isinstance(v, bool)]
        if bad:
            raise ConfigError(f"stage.serial.generic.{bad[0]}", "expected a string (a command template or a "
                                                                "reply pattern)", source)


def load_config(path) -> RigConfig:
    """Read and check the TOML rig configuration at ``path`` (:func:`parse_config`). A file that
    is not TOML raises :class:`ConfigError` with the parser's line and column; a path that
    cannot be opened, OSError."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    path = os.fspath(path)
    with open(path, "rb") as fh:
        try:
            raw = tomllib.load(fh)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError("(file)", f"not valid TOML: {exc}", path) from None
    return parse_config(raw, path)
