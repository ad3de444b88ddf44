"""Command dialects of stage controllers: the text a controller family reads and writes, as data.

A :class:`Dialect` holds the command templates and the reply patterns of one controller
family, formatted with ``{axis}``, ``{device}``, ``{pos}`` and ``{vel}`` in the controller's
own units. The scale ``units_per_m`` is never guessed: it comes from the rig's configuration
(the controller's unit setting, the stage's data sheet), and a dialect without it formats and
parses nothing (:meth:`Dialect.with_units` gives the copy that has it).

Built-ins: :data:`PI_GCS2` (Physik Instrumente's GCS 2.0) and :data:`ZABER_ASCII` (Zaber's
ASCII protocol); :meth:`Dialect.generic` builds another from a table of strings (a section
of the rig's configuration file). The parsers are strict: a reply that is truncated, carries
more than one line, is not in the dialect's encoding, or does not match the expected pattern
in full raises :class:`ReplyError` with the bytes shown; a controller's error or fault reply
raises :class:`ControllerError` with its code.

The same dialect also describes the controller's side (``*_answer``, ``bad_*_code``): what the
simulated controller (:class:`tactile_mirror.rig.sim.SerialAxis`) writes; the constructor
checks that the reply patterns accept those answers.

Neither built-in dialect has been run against a real controller here; they follow the
manuals named in their descriptions.
"""
from __future__ import annotations

import codecs
import dataclasses
import functools
import math
import numbers
import re
import string
import types
from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["DIALECTS", "PI_GCS2", "ZABER_ASCII", "ControllerError", "Dialect", "ReplyError"]

#: A number as the controllers write it (no ``nan``, ``inf``, ``_`` or blanks, which
#: ``float()`` would accept).
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_NUMBER = re.compile(NUMBER)
_REGEX_FIELD = re.compile(r"\{(axis|device)(?::([^{}]*))?\}")

# The commands the host sends: field name -> the placeholders its template may use.
_COMMANDS = {
    "move": ("axis", "device", "pos"),
    "query_position": ("axis", "device"),
    "stop": ("axis", "device"),
    "query_error": ("axis", "device"),
    "enable": ("axis", "device"),
    "home": ("axis", "device"),
    "query_ready": ("axis", "device"),
    "set_velocity": ("axis", "device", "vel"),
}
# The reply patterns: field name -> number of groups (None: any).
_PATTERNS = {"position_reply": 1, "ack_reply": None, "error_reply": 1, "fault_reply": 1, "ready_reply": 1}
# The controller's answers (the simulated controller's side).
_ANSWERS = ("position_answer", "ack_answer", "error_answer", "ready_answer")
_ANSWER_FIELDS = ("axis", "device", "pos", "code", "state", "flag", "ready")
_REQUIRED = {
    "name": "the dialect's name, e.g. 'PI GCS 2.0'",
    "move": "the command that moves the axis to {pos}, e.g. 'MOV {axis} {pos}'",
    "query_position": "the query of the axis position, e.g. 'POS? {axis}'",
    "position_reply": "the regex of the position reply with one group (the position), e.g. '{axis}=(\\S+)'",
    "stop": "the command that stops the axis, e.g. 'HLT {axis}'",
}
_SHOW = 120  # bytes of a reply shown in an error message


def _show(reply) -> str:
    b = bytes(reply)
    return repr(b) if len(b) <= _SHOW else f"{b[:_SHOW]!r}... ({len(b)} bytes)"


class ReplyError(ValueError):
    """A controller's reply that is malformed, truncated, unexpected or not text: the message
    shows the bytes (``reply``) and the request they answered (``request``)."""

    def __init__(self, what: str, reply: bytes = b"", request: str = ""):
        self.reply = bytes(reply)
        self.request = request
        super().__init__(f"{what}: {_show(reply)}" + (f" (reply to {request!r})" if request else ""))


class ControllerError(RuntimeError):
    """The controller reported an error or a fault: ``code`` (the dialect's error code, rejection
    reason or fault flag), ``reply`` (its bytes) and ``request`` (what it answered)."""

    def __init__(self, what: str, code: str, reply: bytes = b"", request: str = ""):
        self.code = code
        self.reply = bytes(reply)
        self.request = request
        super().__init__(f"{what}: {_show(reply)}" + (f" (reply to {request!r})" if request else ""))


@dataclass(frozen=True)
class Dialect:
    """The command templates and reply patterns of one controller family (data, not code).

    Command templates (``str.format`` with ``{axis}``, ``{device}``, ``{pos}`` / ``{vel}`` in
    the controller's units; ``""``: the controller has no such command): ``move`` (required),
    ``query_position`` (required), ``stop`` (required), ``query_error``, ``enable``, ``home``,
    ``query_ready``, ``set_velocity``.

    Reply patterns (regular expressions matched against a whole reply without its terminator;
    ``{axis}`` and ``{device}``, with an optional format spec such as ``{device:0>2}``, stand
    for the escaped values):

    - ``position_reply`` (required, one group: the position in units);
    - ``ack_reply``: the reply to every set command (move, stop, enable, home); ``""``: set
      commands are not answered, and a dialect with ``query_error`` confirms them with it;
    - ``error_reply`` (one group: the code): with ``query_error``, the pattern of its reply,
      ``no_error`` the code that means none; without, a reply that may come in place of any
      other (a rejection), every code but ``no_error`` being an error;
    - ``fault_reply`` (one group: the flag): a reply reporting a fault (checked in every reply);
    - ``ready_reply`` (one group), ready when it equals ``ready_value``.

    Framing: ``line_end`` ends each command, ``reply_terminator`` each reply, ``encoding``
    both. Units: ``units_per_m`` (controller units per metre, from the rig configuration, never
    guessed: None formats and parses nothing), ``decimals`` written (0: integer counts,
    rounded). ``axis`` and ``device`` are the values of their placeholders.

    Controller side (what a controller writes; used by the simulated controller): the answers
    ``position_answer``, ``ack_answer``, ``error_answer``, ``ready_answer`` (``str.format``
    with ``axis``, ``device``, ``pos``, ``code``, ``state`` (``IDLE``/``BUSY``), ``flag``
    (warning flag, ``--`` for none) and ``ready`` (``1``/``0``)), the codes ``bad_target_code``
    (a target outside the controller's limits) and ``bad_command_code`` (an unknown command),
    and ``error_meanings`` (code -> words, for messages).
    """

    name: str
    move: str
    query_position: str
    position_reply: str
    stop: str
    units_per_m: float | None = None
    axis: str = "1"
    device: str = ""
    decimals: int = 6
    line_end: str = "\n"
    reply_terminator: str = "\n"
    encoding: str = "ascii"
    ack_reply: str = ""
    query_error: str = ""
    error_reply: str = ""
    no_error: str = "0"
    fault_reply: str = ""
    enable: str = ""
    home: str = ""
    query_ready: str = ""
    ready_reply: str = ""
    ready_value: str = "1"
    set_velocity: str = ""
    position_answer: str = ""
    ack_answer: str = ""
    error_answer: str = ""
    ready_answer: str = ""
    bad_target_code: str = ""
    bad_command_code: str = ""
    error_meanings: tuple = ()

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name not in ("units_per_m", "decimals", "error_meanings") and not isinstance(value, str):
                raise TypeError(f"{f.name} must be a string, got {type(value).__name__}")
        for name, what in _REQUIRED.items():
            if not getattr(self, name):
                raise ValueError(f"{name} must not be empty: {what}")
        if self.units_per_m is not None:
            u = self.units_per_m
            if isinstance(u, bool) or not isinstance(u, numbers.Real) or not (math.isfinite(u) and u > 0):
                raise ValueError(f"units_per_m must be a positive finite number (controller units per metre) "
                                 f"or None, got {u!r}")
            object.__setattr__(self, "units_per_m", float(u))
        if isinstance(self.decimals, bool) or not isinstance(self.decimals, numbers.Integral) \
                or not 0 <= self.decimals <= 9:
            raise ValueError(f"decimals must be an int in [0, 9], got {self.decimals!r}")
        object.__setattr__(self, "decimals", int(self.decimals))
        for name in ("line_end", "reply_terminator"):
            if not getattr(self, name):
                raise ValueError(f"{name} must not be empty")
        try:
            codecs.lookup(self.encoding)
        except LookupError:
            raise ValueError(f"encoding {self.encoding!r} is not a known text encoding") from None
        meanings = self.error_meanings.items() if isinstance(self.error_meanings, Mapping) else self.error_meanings
        try:
            meanings = tuple((str(k), str(v)) for k, v in meanings)
        except (TypeError, ValueError):
            raise ValueError("error_meanings must be pairs (code, words)") from None
        object.__setattr__(self, "error_meanings", meanings)
        if "pos" not in self._placeholders("move", self.move):
            raise ValueError(f"move must contain {{pos}}, got {self.move!r}")
        for name, allowed in _COMMANDS.items():
            unknown = self._placeholders(name, getattr(self, name)) - set(allowed)
            if unknown:
                raise ValueError(f"{name}: unknown placeholder {{{min(unknown)}}} in {getattr(self, name)!r} "
                                 f"(allowed: {', '.join('{' + a + '}' for a in allowed)})")
        if self.set_velocity and "vel" not in self._placeholders("set_velocity", self.set_velocity):
            raise ValueError(f"set_velocity must contain {{vel}}, got {self.set_velocity!r}")
        _ = self._compiled  # (compiles and checks the reply patterns now)
        if self.query_error and not self.error_reply:
            raise ValueError("query_error needs error_reply (the regex of its reply, one group: the code)")
        if bool(self.query_ready) != bool(self.ready_reply):
            raise ValueError("query_ready and ready_reply come together (the query and the regex of its reply)")
        for name in _ANSWERS:
            unknown = self._placeholders(name, getattr(self, name)) - set(_ANSWER_FIELDS)
            if unknown:
                raise ValueError(f"{name}: unknown placeholder {{{min(unknown)}}} in {getattr(self, name)!r}")
        self._check_answers()

    @functools.cached_property
    def _compiled(self) -> dict[str, re.Pattern]:
        """The reply patterns, placeholders filled in, compiled and checked (ValueError naming a bad one)."""
        compiled = {}
        for name, groups in _PATTERNS.items():
            text = getattr(self, name)
            if not text:
                continue
            try:
                pattern = re.compile(_REGEX_FIELD.sub(self._regex_value, text))
            except re.error as exc:
                raise ValueError(f"{name}: {text!r} is not a valid regular expression ({exc})") from None
            if groups is not None and pattern.groups != groups:
                raise ValueError(f"{name}: {text!r} must have exactly {groups} group(s), has {pattern.groups}")
            compiled[name] = pattern
        return compiled

    @functools.cached_property
    def _term(self) -> bytes:
        return self.reply_terminator.encode(self.encoding)

    # -- construction --------------------------------------------------------------------

    @classmethod
    def generic(cls, table: Mapping | None = None, /, **strings) -> Dialect:
        """A dialect from a table of strings (a configuration section) and/or keyword strings.

        The keys are the field names (see the class); ``name``, ``move``, ``query_position``,
        ``position_reply`` and ``stop`` are required; ``units_per_m`` (a number), ``decimals``
        (an int) and ``error_meanings`` (a table code -> words) are the only values that are
        not strings. A missing, unknown or bad key raises ValueError naming it.
        """
        items = dict(table) if table is not None else {}
        items.update(strings)
        fields = {f.name for f in dataclasses.fields(cls)}
        for key in sorted(items):
            if key not in fields:
                raise ValueError(f"dialect table: unknown key {key!r} (the keys are: {', '.join(sorted(fields))})")
        for key, what in _REQUIRED.items():
            if key not in items or items[key] in ("", None):
                raise ValueError(f"dialect table: missing key {key!r}: {what}")
        for key, value in items.items():
            if key in ("units_per_m", "decimals", "error_meanings"):
                continue
            if not isinstance(value, str):  # (ValueError for every bad entry of a table, as for a bad value)
                raise ValueError(  # noqa: TRY004
                    f"dialect table: key {key!r} must be a string, got {type(value).__name__} {value!r}")
        try:
            return cls(**items)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"dialect table: {exc}") from None

    def with_units(self, units_per_m: float) -> Dialect:
        """This dialect with ``units_per_m`` controller units per metre (from the rig config)."""
        return dataclasses.replace(self, units_per_m=units_per_m)

    # -- the host's side: commands -------------------------------------------------------

    def units_text(self, x: float) -> str:
        """Position ``x`` (m) in the controller's units as written (``decimals`` digits)."""
        return self.format_units(self._to_units(x, "position"))

    def format_units(self, value: float) -> str:
        """``value`` (controller units) with ``decimals`` digits (0: an integer, rounded).

        Refuses NaN, infinity and values beyond the range where the written digits are exact
        (``|value| * 10**decimals >= 2**53``), with ValueError."""
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"{self.name}: refusing to write {v!r} (not a finite number)")
        if abs(v) * 10.0 ** self.decimals >= 2.0 ** 53:
            raise ValueError(f"{self.name}: refusing to write {v!r} units: beyond the range written exactly "
                             f"with {self.decimals} decimals")
        text = f"{v:.{self.decimals}f}"
        if text.startswith("-") and not text.strip("-0."):
            text = text[1:]  # no "-0"
        return text

    def command(self, kind: str, x: float | None = None) -> bytes:
        """The bytes of command ``kind`` (a template field: ``"move"`` and ``"set_velocity"``
        take ``x``, m or m/s), with ``line_end``."""
        if kind not in _COMMANDS:
            raise ValueError(f"unknown command {kind!r}; the commands are {', '.join(_COMMANDS)}")
        template = getattr(self, kind)
        if not template:
            raise ValueError(f"the {self.name} dialect has no {kind!r} command")
        values = {"axis": self.axis, "device": self.device}
        if kind in ("move", "set_velocity"):
            if x is None:
                raise ValueError(f"the {kind!r} command needs x")
            if kind == "move":
                values["pos"] = self.units_text(x)
            else:
                values["vel"] = self.format_units(self._to_units(x, "velocity"))
        return (template.format(**values) + self.line_end).encode(self.encoding)

    def move_command(self, x: float) -> bytes:
        """The bytes of the move to ``x`` (m)."""
        return self.command("move", x)

    # -- the host's side: replies --------------------------------------------------------

    def reply_text(self, reply: bytes, request: str = "") -> str:
        """One whole reply (its terminator included) as text, checked: terminated, one line,
        in the encoding, printable; an inline error or fault raises :class:`ControllerError`."""
        if not isinstance(reply, (bytes, bytearray)):
            raise TypeError(f"a reply must be bytes, got {type(reply).__name__}")
        term = self._term
        if not reply.endswith(term):
            raise ReplyError(f"truncated reply (no {self.reply_terminator!r} at its end)", reply, request)
        body = bytes(reply[:-len(term)])
        if term in body:
            raise ReplyError("more than one reply", reply, request)
        try:
            text = body.decode(self.encoding)
        except UnicodeDecodeError:
            raise ReplyError(f"reply is not {self.encoding} text", reply, request) from None
        if not text.isprintable():
            raise ReplyError("reply holds control characters", reply, request)
        if not self.query_error and self.error_reply:
            m = self._compiled["error_reply"].fullmatch(text)
            if m and m.group(1) != self.no_error:
                raise ControllerError(self._error_words(m.group(1), "rejected the command"), m.group(1), reply,
                                      request)
        if self.fault_reply:
            m = self._compiled["fault_reply"].fullmatch(text)
            if m:
                raise ControllerError(f"controller fault {m.group(1)}", m.group(1), reply, request)
        return text

    def parse_position(self, reply: bytes, request: str = "") -> float:
        """The position (m) in a reply to ``query_position``."""
        units = self._need_units()
        text = self.reply_text(reply, request)
        m = self._compiled["position_reply"].fullmatch(text)
        if m is None:
            raise ReplyError(f"malformed position reply (expected {self.position_reply!r})", reply, request)
        group = m.group(1)
        if group is None or not _NUMBER.fullmatch(group):
            raise ReplyError("malformed position reply (not a number)", reply, request)
        value = float(group)
        if not math.isfinite(value):
            raise ReplyError("position reply out of range (not a finite number)", reply, request)
        return value / units

    def parse_ack(self, reply: bytes, request: str = "") -> None:
        """Check the reply to a set command against ``ack_reply``."""
        text = self.reply_text(reply, request)
        if not self.ack_reply:
            raise ReplyError(f"unexpected reply (the {self.name} dialect answers no set command)", reply, request)
        if self._compiled["ack_reply"].fullmatch(text) is None:
            raise ReplyError(f"malformed reply (expected {self.ack_reply!r})", reply, request)

    def parse_error(self, reply: bytes, request: str = "") -> None:
        """Check the reply to ``query_error``: ControllerError unless the code is ``no_error``."""
        text = self.reply_text(reply, request)
        if not self.error_reply:
            raise ReplyError(f"unexpected reply (the {self.name} dialect has no error reply)", reply, request)
        m = self._compiled["error_reply"].fullmatch(text)
        if m is None:
            raise ReplyError(f"malformed error reply (expected {self.error_reply!r})", reply, request)
        if m.group(1) != self.no_error:
            raise ControllerError(self._error_words(m.group(1), "reports error"), m.group(1), reply, request)

    def parse_ready(self, reply: bytes, request: str = "") -> bool:
        """True if a reply to ``query_ready`` says the axis is ready (on target, idle)."""
        text = self.reply_text(reply, request)
        if not self.ready_reply:
            raise ReplyError(f"unexpected reply (the {self.name} dialect has no ready query)", reply, request)
        m = self._compiled["ready_reply"].fullmatch(text)
        if m is None:
            raise ReplyError(f"malformed ready reply (expected {self.ready_reply!r})", reply, request)
        return m.group(1) == self.ready_value

    # -- the controller's side -----------------------------------------------------------

    def command_pattern(self, kind: str) -> re.Pattern | None:
        """The regex a controller matches command ``kind`` with (groups ``pos`` / ``vel``: the
        number), or None if the dialect has no such command."""
        if kind not in _COMMANDS:
            raise ValueError(f"unknown command {kind!r}; the commands are {', '.join(_COMMANDS)}")
        template = getattr(self, kind)
        if not template:
            return None
        parts = []
        for literal, field, spec, _conv in string.Formatter().parse(template):
            parts.append(re.escape(literal))
            if field in ("axis", "device"):
                parts.append(re.escape(format(getattr(self, field), spec or "")))
            elif field is not None:
                parts.append(f"(?P<{field}>{NUMBER})")
        return re.compile("".join(parts))

    def answer(self, kind: str, **fields) -> bytes:
        """The bytes a controller writes for answer ``kind`` (``"position"``, ``"ack"``,
        ``"error"``, ``"ready"``), with the reply terminator; ``fields`` fill its template
        (``axis`` and ``device`` default to the dialect's)."""
        name = f"{kind}_answer"
        if name not in _ANSWERS:
            raise ValueError(f"unknown answer {kind!r}; the answers are position, ack, error, ready")
        template = getattr(self, name)
        if not template:
            raise ValueError(f"the {self.name} dialect has no {name}")
        values = {"axis": self.axis, "device": self.device, "pos": "", "code": "", "state": "IDLE", "flag": "--",
                  "ready": "1"}
        values.update(fields)
        return (template.format(**values) + self.reply_terminator).encode(self.encoding)

    # -- helpers -------------------------------------------------------------------------

    def _placeholders(self, name: str, template: str) -> set[str]:
        try:
            return {f for _, f, _, _ in string.Formatter().parse(template) if f is not None}
        except ValueError as exc:
            raise ValueError(f"{name}: {template!r} is not a valid template ({exc})") from None

    def _regex_value(self, m: re.Match) -> str:
        return re.escape(format(getattr(self, m.group(1)), m.group(2) or ""))

    def _need_units(self) -> float:
        if self.units_per_m is None:
            raise ValueError(f"the {self.name} dialect has no units_per_m: give the controller's units per metre "
                             "from the rig configuration (Dialect.with_units), it is never guessed")
        return self.units_per_m

    def _to_units(self, x, what: str) -> float:
        units = self._need_units()
        if isinstance(x, bool) or not isinstance(x, numbers.Real):
            raise TypeError(f"a {what} must be a real number, got {type(x).__name__}")
        x = float(x)
        if not math.isfinite(x):
            raise ValueError(f"{self.name}: refusing to write the {what} {x!r} (not a finite number)")
        return x * units

    def _error_words(self, code: str, verb: str) -> str:
        meaning = dict(self.error_meanings).get(code)
        return f"controller {verb} {code}" + (f" ({meaning})" if meaning else "")

    def _check_answers(self) -> None:
        """The reply patterns accept the dialect's own answers (a table that contradicts itself
        is refused here, not on the line)."""
        sample = {"pos": self.format_units(-1234.5), "code": self.bad_target_code or "1", "state": "BUSY"}
        checks = [("position_answer", "position_reply", sample), ("ack_answer", "ack_reply", sample),
                  ("ready_answer", "ready_reply", sample), ("error_answer", "error_reply", sample)]
        for answer, pattern, fields in checks:
            if getattr(self, answer) and pattern in self._compiled:
                text = self.answer(answer[:-len("_answer")], **fields)[:-len(self._term)].decode(self.encoding)
                if self._compiled[pattern].fullmatch(text) is None:
                    raise ValueError(f"{answer}: its answer {text!r} does not match {pattern} {getattr(self, pattern)!r}")


PI_GCS2 = Dialect(
    name="PI GCS 2.0",
    move="MOV {axis} {pos}",
    query_position="POS? {axis}",
    position_reply=r"{axis}=(" + NUMBER + ")",
    stop="HLT {axis}",
    decimals=6,
    query_error="ERR?",
    error_reply=r"(-?\d+)",
    no_error="0",
    enable="SVO {axis} 1",
    home="FRF {axis}",
    query_ready="ONT? {axis}",
    ready_reply=r"{axis}=([01])",
    ready_value="1",
    set_velocity="VEL {axis} {vel}",
    position_answer="{axis}={pos}",
    error_answer="{code}",
    ready_answer="{axis}={ready}",
    bad_target_code="7",
    bad_command_code="2",
    error_meanings=(("1", "parameter syntax error"), ("2", "unknown command"),
                    ("5", "move attempted on an unreferenced axis or with the servo off"),
                    ("7", "position out of limits"), ("10", "controller was stopped by command"),
                    ("15", "invalid axis identifier")),
)
"""Physik Instrumente's GCS 2.0 (the "GCS Commands" chapter of PI's controller manuals, e.g.
the C-863 Mercury or C-884: ``MOV 1 12.345`` + LF, ``POS? 1`` -> ``1=12.345`` + LF, ``HLT 1``
(halt the axis with the controller's deceleration; ``STP`` stops all axes abruptly), ``ERR?``
-> ``0`` (errors latch until read), ``SVO 1 1``, ``FRF 1``, ``ONT? 1`` -> ``1=1``, ``VEL 1 v``).
Set commands get no reply: the driver confirms each with ``ERR?``. Units: mm on a linear stage
whose controller is set so (``units_per_m = 1000`` from the rig config); 6 decimals (1 nm)."""

ZABER_ASCII = Dialect(
    name="Zaber ASCII",
    device="1",
    move="/{device} {axis} move abs {pos}",
    query_position="/{device} {axis} get pos",
    position_reply=r"@{device:0>2} {axis} OK (?:IDLE|BUSY) (?:--|[A-Z]{2}) (-?\d+)",
    stop="/{device} {axis} stop",
    decimals=0,
    reply_terminator="\r\n",
    ack_reply=r"@{device:0>2} {axis} OK (?:IDLE|BUSY) (?:--|[A-Z]{2}) 0",
    error_reply=r"@{device:0>2} {axis} RJ (?:IDLE|BUSY) (?:--|[A-Z]{2}) ([A-Z]+)",
    no_error="",
    fault_reply=r"@{device:0>2} {axis} (?:OK|RJ) (?:IDLE|BUSY) (F[A-Z]) \S+",
    home="/{device} {axis} home",
    query_ready="/{device} {axis}",
    ready_reply=r"@{device:0>2} {axis} OK (IDLE|BUSY) (?:--|[A-Z]{2}) 0",
    ready_value="IDLE",
    position_answer="@{device:0>2} {axis} OK {state} {flag} {pos}",
    ack_answer="@{device:0>2} {axis} OK {state} {flag} 0",
    error_answer="@{device:0>2} {axis} RJ {state} {flag} {code}",
    ready_answer="@{device:0>2} {axis} OK {state} {flag} 0",
    bad_target_code="BADDATA",
    bad_command_code="BADCOMMAND",
)
"""Zaber's ASCII protocol (Zaber's "ASCII Protocol Manual", firmware 6 and 7): commands
``/1 1 move abs 12345`` + LF, every command answered by a reply ``@01 1 OK IDLE -- 0`` + CR LF
(device, axis, ``OK``/``RJ``, ``IDLE``/``BUSY``, the highest warning flag or ``--``, data);
``/1 1 get pos`` -> ``@01 1 OK IDLE -- 12345``; ``/1 1 stop`` (decelerates), ``/1 1 home``,
``/1 1`` (the status: ready when ``IDLE``); a rejection ``@01 1 RJ IDLE -- BADDATA`` is an
error; a warning flag of the fault class (``F`` + a letter, e.g. ``FS`` stalled, ``FQ``
encoder error) is a fault, the other flags (``W*`` warnings, ``N*`` notices such as ``NI``, a
move interrupted by the next) are not. Message ids and checksums are not used. Units: the
device's data units (microsteps or encoder counts): ``units_per_m`` from the stage's data
sheet; integers, rounded. Axes are driver-enabled at power-up: ``enable`` is empty."""

#: The built-in dialects by the names a rig configuration uses.
DIALECTS = types.MappingProxyType({"pi_gcs2": PI_GCS2, "zaber_ascii": ZABER_ASCII})
