"""Stage drivers over a serial line: the command dialects byte for byte (what is sent, what is
parsed, what is refused) and the soft-limit checks every driver shares."""
from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from tactile_mirror.loop.stage import StageLimits
from tactile_mirror.rig import dialects
from tactile_mirror.rig.dialects import DIALECTS, PI_GCS2, ZABER_ASCII, ControllerError, Dialect, ReplyError
from tactile_mirror.rig.stage import check_reading, check_target

PI = PI_GCS2.with_units(1000.0)  # a linear stage whose controller speaks mm
ZABER_UNITS = 1.0 / 0.047625e-6  # microsteps per metre of a stage with 0.047625 um microsteps (its data sheet)
ZABER = ZABER_ASCII.with_units(ZABER_UNITS)
BAUD = 115200
BYTE = 10.0 / BAUD  # s per byte on the wire (8N1)

SIM_LIMITS = StageLimits(-0.05, 0.05, 0.1, 5.0)   # the controller's own travel
SOFT = StageLimits(-0.04, 0.04, 0.1, 5.0)         # the driver's soft limits (inside)
BOTH = [pytest.param(PI, id="pi_gcs2"), pytest.param(ZABER, id="zaber_ascii")]


# -- the dialects, byte for byte ----------------------------------------------------------


def test_pi_gcs2_commands_exact_bytes():
    assert PI.move_command(0.012345) == b"MOV 1 12.345000\n"
    assert PI.move_command(-0.003) == b"MOV 1 -3.000000\n"
    assert PI.move_command(0.0) == b"MOV 1 0.000000\n"
    assert PI.move_command(-1e-13) == b"MOV 1 0.000000\n"  # no "-0"
    assert PI.move_command(1.23456789e-3) == b"MOV 1 1.234568\n"  # 6 decimals of mm: 1 nm, rounded
    assert PI.move_command(250.0) == b"MOV 1 250000.000000\n"
    assert PI.command("query_position") == b"POS? 1\n"
    assert PI.command("stop") == b"HLT 1\n"
    assert PI.command("query_error") == b"ERR?\n"
    assert PI.command("enable") == b"SVO 1 1\n"
    assert PI.command("home") == b"FRF 1\n"
    assert PI.command("query_ready") == b"ONT? 1\n"
    assert PI.command("set_velocity", 0.0125) == b"VEL 1 12.500000\n"
    assert PI_GCS2.with_units(1000.0).__class__ is Dialect


def test_zaber_ascii_commands_exact_bytes():
    assert ZABER.move_command(0.012345) == b"/1 1 move abs 259213\n"  # 259212.6 counts, rounded
    assert ZABER.move_command(-0.003) == b"/1 1 move abs -62992\n"
    assert ZABER.move_command(0.0) == b"/1 1 move abs 0\n"
    assert ZABER.move_command(-1e-9) == b"/1 1 move abs 0\n"  # -0.02 counts: no "-0"
    assert ZABER.move_command(1.0) == b"/1 1 move abs 20997375\n"
    assert ZABER.command("query_position") == b"/1 1 get pos\n"
    assert ZABER.command("stop") == b"/1 1 stop\n"
    assert ZABER.command("home") == b"/1 1 home\n"
    assert ZABER.command("query_ready") == b"/1 1\n"
    with pytest.raises(ValueError, match="no 'enable' command"):
        ZABER.command("enable")
    other = dataclasses.replace(ZABER_ASCII.with_units(1000.0), device="12", axis="2")
    assert other.move_command(0.5) == b"/12 2 move abs 500\n"
    assert other.parse_position(b"@12 2 OK IDLE -- 500\r\n") == 0.5


def test_formatting_refuses_what_is_not_a_finite_position():
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match="not a finite"):
            PI.move_command(bad)
        with pytest.raises(ValueError, match="not a finite"):
            ZABER.move_command(bad)
    with pytest.raises(ValueError, match="beyond the range"):
        PI.move_command(1e10)  # 1e13 mm with 6 decimals: more digits than a double holds
    with pytest.raises(ValueError, match="beyond the range"):
        ZABER.move_command(1e9)
    with pytest.raises(TypeError):
        PI.move_command("1.0")
    with pytest.raises(TypeError):
        PI.move_command(True)
    with pytest.raises(ValueError, match="units_per_m"):
        PI_GCS2.move_command(0.01)  # the built-in has no scale: never guessed
    with pytest.raises(ValueError, match="units_per_m"):
        ZABER_ASCII.parse_position(b"@01 1 OK IDLE -- 5\r\n")


def test_pi_gcs2_replies_parsed_strictly():
    assert PI.parse_position(b"1=12.345000\n") == pytest.approx(0.012345, abs=1e-15)
    assert PI.parse_position(b"1=-3.5\n") == pytest.approx(-0.0035)
    assert PI.parse_position(b"1=1.5e1\n") == pytest.approx(0.015)
    assert PI.parse_position(b"1=+.5\n") == pytest.approx(0.0005)
    assert PI.parse_position(b"1=123456789012.5\n") == pytest.approx(123456789.0125)  # big: parsed (limits judge)
    cases = {
        b"1=1e400\n": "not a finite",          # too big for a double
        b"1=nan\n": "malformed",
        b"1=inf\n": "malformed",
        b"2=12.3\n": "malformed",               # another axis
        b"1=12.3": "truncated",                 # no LF
        b"1=12.": "truncated",
        b"": "truncated",
        b"1=\n": "malformed",
        b"\n": "malformed",
        b"1=12.3 \n": "malformed",              # GCS's continuation space: not a single reply
        b"1=1_000\n": "malformed",
        b"1= 12.3\n": "malformed",
        b"1=12.3\r\n": "control characters",
        b"1=12.3\n1=12.4\n": "more than one reply",
        b"\xff\xfe\n": "not ascii",
        b"garbage\n": "malformed",
        b"0\n": "malformed",                    # an ERR? reply where the position was asked
    }
    for reply, words in cases.items():
        with pytest.raises(ReplyError, match=words) as info:
            PI.parse_position(reply, "POS? 1")
        assert repr(reply)[:20] in str(info.value) and "'POS? 1'" in str(info.value)
        assert info.value.reply == reply
    PI.parse_error(b"0\n")
    with pytest.raises(ControllerError, match=r"error 7 \(position out of limits\)") as info:
        PI.parse_error(b"7\n", "MOV 1 60.000000 + ERR?")
    assert info.value.code == "7" and info.value.reply == b"7\n"
    with pytest.raises(ControllerError) as info:
        PI.parse_error(b"-1002\n")
    assert info.value.code == "-1002"
    for bad in (b"x\n", b"0", b"1=0\n", b"0 \n"):
        with pytest.raises(ReplyError):
            PI.parse_error(bad)
    assert PI.parse_ready(b"1=1\n") is True
    assert PI.parse_ready(b"1=0\n") is False
    for bad in (b"2=1\n", b"1=2\n", b"1=1"):
        with pytest.raises(ReplyError):
            PI.parse_ready(bad)
    with pytest.raises(ReplyError, match="answers no set command"):
        PI.parse_ack(b"0\n")


def test_zaber_ascii_replies_parsed_strictly():
    z = ZABER
    assert z.parse_position(b"@01 1 OK IDLE -- 259213\r\n") == pytest.approx(259213 / ZABER_UNITS)
    assert z.parse_position(b"@01 1 OK BUSY -- -5\r\n") == pytest.approx(-5 / ZABER_UNITS)
    assert z.parse_position(b"@01 1 OK IDLE WR 0\r\n") == 0.0      # a warning (no reference) is no fault
    assert z.parse_position(b"@01 1 OK BUSY NI 7\r\n") == pytest.approx(7 / ZABER_UNITS)  # a notice neither
    big = b"@01 1 OK IDLE -- 99999999999999999999\r\n"
    assert z.parse_position(big) == pytest.approx(1e20 / ZABER_UNITS)
    z.parse_ack(b"@01 1 OK BUSY -- 0\r\n")
    z.parse_ack(b"@01 1 OK IDLE NI 0\r\n")
    with pytest.raises(ControllerError, match="rejected the command BADDATA") as info:
        z.parse_ack(b"@01 1 RJ IDLE -- BADDATA\r\n", "/1 1 move abs 99999999")
    assert info.value.code == "BADDATA"
    with pytest.raises(ControllerError, match="rejected the command BADCOMMAND"):
        z.parse_position(b"@01 1 RJ IDLE -- BADCOMMAND\r\n")
    with pytest.raises(ControllerError, match="controller fault FS") as info:
        z.parse_position(b"@01 1 OK IDLE FS 12\r\n")   # stalled: a fault flag
    assert info.value.code == "FS"
    with pytest.raises(ControllerError, match="controller fault FQ"):
        z.parse_ack(b"@01 1 OK BUSY FQ 0\r\n")
    cases = {
        b"@01 2 OK IDLE -- 5\r\n": "malformed",        # another axis
        b"@02 1 OK IDLE -- 5\r\n": "malformed",        # another device
        b"@1 1 OK IDLE -- 5\r\n": "malformed",         # the device in two digits
        b"@01 1 OK IDLE -- 5.5\r\n": "malformed",      # counts are integers
        b"@01 1 OK IDLE -- \r\n": "malformed",
        b"@01 1 OK IDLE --\r\n": "malformed",          # truncated inside the line
        b"@01 1 OK IDLE -- 5": "truncated",
        b"@01 1 OK IDLE -- 5\n": "truncated",          # CR LF it must be
        b"@01 1 OK IDLE -- 5\r": "truncated",
        b"@01 1 OK WAIT -- 5\r\n": "malformed",
        b"#01 1 info\r\n": "malformed",                # an info message
        b"!01 1 IDLE --\r\n": "malformed",             # an alert
        b"@01 1 OK IDLE -- 5:AB\r\n": "malformed",     # a checksum (not used)
        b"\x00\x01\r\n": "control characters",
        b"@01 1 OK IDLE -- \xb55\r\n": "not ascii",
    }
    for reply, words in cases.items():
        with pytest.raises(ReplyError, match=words):
            z.parse_position(reply, "/1 1 get pos")
    with pytest.raises(ReplyError, match="malformed"):
        z.parse_ack(b"@01 1 OK IDLE -- 12\r\n")
    assert z.parse_ready(b"@01 1 OK IDLE -- 0\r\n") is True
    assert z.parse_ready(b"@01 1 OK BUSY -- 0\r\n") is False


@pytest.mark.parametrize("d", BOTH)
def test_the_controller_side_reads_what_the_host_writes(d):
    for x in (0.0123456, -0.0399, 0.04):
        text = d.move_command(x).decode().rstrip("\n")
        m = d.command_pattern("move").fullmatch(text)
        assert m is not None and float(m.group("pos")) / d.units_per_m == pytest.approx(x, abs=1 / d.units_per_m)
        answer = d.answer("position", pos=d.units_text(x))
        assert d.parse_position(answer) == pytest.approx(x, abs=1 / d.units_per_m)
    assert d.command_pattern("query_position").fullmatch(d.command("query_position").decode().strip())
    assert d.command_pattern("move").fullmatch("MOV 1 abc") is None
    refusal = d.answer("error", code=d.bad_target_code)
    with pytest.raises(ControllerError):
        d.parse_error(refusal) if d.query_error else d.parse_ack(refusal)


def test_generic_dialect_from_a_table():
    table = {"name": "my controller", "units_per_m": 1e6, "decimals": 3, "move": "MA{axis} {pos}",
             "query_position": "TP{axis}", "position_reply": r"{axis}TP(-?\d+\.\d+)", "stop": "ST{axis}",
             "line_end": "\r", "reply_terminator": "\r\n", "query_error": "TE", "error_reply": r"E(\d+)",
             "error_meanings": {"12": "travel limit"}}
    d = Dialect.generic(table)
    assert d.move_command(0.0012345) == b"MA1 1234.500\r"
    assert d.parse_position(b"1TP-5.250\r\n") == pytest.approx(-5.25e-6)
    with pytest.raises(ControllerError, match=r"error 12 \(travel limit\)"):
        d.parse_error(b"E12\r\n")
    assert Dialect.generic(table, axis="2").command("stop") == b"ST2\r"
    # the errors name the key
    bad = [({k: v for k, v in table.items() if k != "move"}, "missing key 'move'"),
           ({**table, "stop": ""}, "missing key 'stop'"),
           ({**table, "mvoe": "x"}, "unknown key 'mvoe'"),
           ({**table, "position_reply": r"TP(\d+"}, "position_reply: .* not a valid regular expression"),
           ({**table, "position_reply": r"TP\d+"}, "position_reply: .* exactly 1 group"),
           ({**table, "position_reply": r"TP(\d)(\d)"}, "position_reply: .* exactly 1 group"),
           ({**table, "move": "MA{axis} {position}"}, r"move must contain \{pos\}"),
           ({**table, "stop": "ST{axes}"}, r"stop: unknown placeholder \{axes\}"),
           ({**table, "move": "MA{axis {pos}"}, "move: .* not a valid template"),
           ({**table, "units_per_m": "1e6"}, "units_per_m must be a positive finite number"),
           ({**table, "units_per_m": -1.0}, "units_per_m must be a positive finite number"),
           ({**table, "units_per_m": math.nan}, "units_per_m must be a positive finite number"),
           ({**table, "decimals": 12}, "decimals must be an int"),
           ({**table, "decimals": 2.0}, "decimals must be an int"),
           ({**table, "stop": 5}, "key 'stop' must be a string"),
           ({**table, "error_reply": ""}, "query_error needs error_reply"),
           ({**table, "query_ready": "TR"}, "query_ready and ready_reply come together"),
           ({**table, "encoding": "klingon"}, "encoding 'klingon'"),
           ({**table, "position_answer": "{axis}POS {pos}"}, "position_answer: its answer .* does not match")]
    for t, words in bad:
        with pytest.raises(ValueError, match=words):
            Dialect.generic(t)
    # a dialect without an error query: every code but no_error in an error reply is an error
    inline = Dialect.generic(name="inline", move="M {pos}", query_position="P", position_reply=r"P=(\S+)",
                             stop="S", ack_reply="OK", error_reply=r"ERR (\d+)", units_per_m=1.0)
    inline.parse_ack(b"OK\n")
    with pytest.raises(ControllerError, match="rejected the command 3"):
        inline.parse_ack(b"ERR 3\n")
    with pytest.raises(ReplyError, match="not a number"):
        inline.parse_position(b"P=ERR\n")


def test_builtin_dialects_by_name():
    assert DIALECTS["pi_gcs2"] is PI_GCS2 and DIALECTS["zaber_ascii"] is ZABER_ASCII
    with pytest.raises(TypeError):
        DIALECTS["x"] = PI_GCS2
    assert PI_GCS2.units_per_m is None and ZABER_ASCII.units_per_m is None  # from the rig config only
    assert dialects.NUMBER


def test_soft_limit_checks():
    lim = StageLimits(-0.01, 0.02, 0.05, 1.0)
    assert check_target(0.015, lim) == 0.015 and type(check_target(np.float32(0.01), lim)) is float
    assert check_target(-0.01, lim) == -0.01 and check_target(1, StageLimits(-2, 2, 1, 1)) == 1.0
    for bad in (0.0201, -0.011, 1e300):
        with pytest.raises(ValueError, match=re.escape(f"{bad!r} m lies outside the soft limits [-0.01, 0.02] m")):
            check_target(bad, lim)
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match="not a finite number"):
            check_target(bad, lim)
    for bad in ("0.01", None, True, [0.01]):
        with pytest.raises(TypeError):
            check_target(bad, lim)
    assert check_reading(0.02, lim) is None and check_reading(0.0205, lim, margin=1e-3) is None
    assert "position out of limits" in check_reading(0.0205, lim)
    assert "not a finite" in check_reading(math.nan, lim)
