"""Stage drivers over a serial line: the command dialects byte for byte, then the driver end to
end through a real pseudo-terminal against the simulated controller, which paces every byte at
115200 Bd (so timings are those of the wire): moves reach their targets, the position stays
fresh, commands never come faster than the line carries them, every fault latches with its
cause and the axis is stopped, and ``move_to`` never blocks.

No real controller was available: the test against one (:func:`test_real_controller`) runs
only when ``TM_RIG_SERIAL_PORT``, ``TM_RIG_DIALECT`` and ``TM_RIG_UNITS_PER_M`` are set, and
has not been run against hardware.
"""
from __future__ import annotations

import dataclasses
import math
import os
import re
import socket
import sys
import threading
import time

import numpy as np
import pytest
from tactile_mirror.loop.stage import Stage, StageLimits
from tactile_mirror.rig import dialects
from tactile_mirror.rig.dialects import DIALECTS, PI_GCS2, ZABER_ASCII, ControllerError, Dialect, ReplyError
from tactile_mirror.rig.stage import COMMAND_MODES, StageDriver, check_reading, check_target

PI = PI_GCS2.with_units(1000.0)  # a linear stage whose controller speaks mm
ZABER_UNITS = 1.0 / 0.047625e-6  # microsteps per metre of a stage with 0.047625 um microsteps (its data sheet)
ZABER = ZABER_ASCII.with_units(ZABER_UNITS)
BAUD = 115200
BYTE = 10.0 / BAUD  # s per byte on the wire (8N1)

SIM_LIMITS = StageLimits(-0.05, 0.05, 0.1, 5.0)   # the controller's own travel
SOFT = StageLimits(-0.04, 0.04, 0.1, 5.0)         # the driver's soft limits (inside)
BOTH = [pytest.param(PI, id="pi_gcs2"), pytest.param(ZABER, id="zaber_ascii")]
pty_only = pytest.mark.skipif(os.name != "posix", reason="needs a pseudo-terminal (POSIX)")


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


# -- end to end through a pseudo-terminal -------------------------------------------------


def _wait(condition, timeout: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.002)
    return condition()


@pytest.fixture
def line():
    """``make(dialect, sim=..., stage=..., start=True) -> (sim, stage)``: a simulated controller
    on a pty and a driver on its other end; both closed after the test."""
    pytest.importorskip("serial")
    if os.name != "posix":
        pytest.skip("needs a pseudo-terminal (POSIX)")
    from tactile_mirror.rig.serial_stage import SerialStage
    from tactile_mirror.rig.sim.serial_axis import SerialAxis
    made = []

    def make(dialect, *, sim=None, stage=None, limits=SOFT, start=True, driver=True):
        sim_kw = {"limits": SIM_LIMITS, "baudrate": BAUD, **(sim or {})}
        axis = SerialAxis(dialect, **sim_kw).start()
        made.append(axis)
        if not driver:
            return axis, None
        # (the simulated controller is a thread of this process, on a machine the suite shares:
        # an answer may come 50 ms late without the controller having gone silent)
        kw = {"baudrate": BAUD, "timeout": 0.25, "reply_overdue": 0.05, **(stage or {})}
        driver = SerialStage(axis.port, dialect, limits, **kw)
        made.append(driver)
        if start:
            driver.start()
        return axis, driver

    # the controller's thread, the driver's and the test's share the interpreter: switch often,
    # as the command line and the simulated rig's process do, and no collection of this process's
    # heap (a test process's takes up to 250 ms) holds the controller and the driver up together
    import gc

    from tactile_mirror.rig.realtime import gc_paused
    previous = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)
    gc.collect()
    try:
        with gc_paused():
            yield make
    finally:
        sys.setswitchinterval(previous)
        for obj in reversed(made):
            obj.close()


def _confirmation_bytes(d: Dialect) -> tuple[int, int]:
    """The bytes confirming a set command, host to controller and back: its answer, or the
    error query and its reply."""
    if d.ack_reply:
        return 0, len(d.answer("ack"))
    return len(d.command("query_error")), len(d.answer("error", code=d.no_error))


def _per_move_bytes(d: Dialect, move: int, k: int) -> tuple[float, float]:
    """Bytes per move on each direction of the line: the move and its confirmation, and a
    ``1 / k`` share of a position query and its shortest answer."""
    tx, rx = _confirmation_bytes(d)
    query = len(d.command("query_position"))
    answer = len(d.answer("position", pos=d.format_units(0.0)))
    return move + tx + query / k, rx + answer / k


@pty_only
def test_the_simulated_controller_paces_each_direction_on_its_own(line):
    # three commands in one write: they come in back to back at the baud rate (the answers going
    # out meanwhile hold nothing up), are handled one at a time (0.5 ms each) and answered in order
    import serial
    sim, _ = line(PI, sim={"latency": 0.0005}, driver=False)
    port = serial.serial_for_url(sim.port, baudrate=BAUD, timeout=0.5)
    q, e = PI.command("query_position"), PI.command("query_error")
    got, done = b"", []
    try:
        t0 = time.monotonic()
        port.write(q + e + q)
        while len(done) < 3 and time.monotonic() < t0 + 2.0:
            data = port.read(1)
            got += data
            if data == b"\n":
                done.append(time.monotonic() - t0)
    finally:
        port.close()
    assert got.split(b"\n")[:3] == [b"1=0.000000", b"0", b"1=0.000000"]
    arrivals = np.array([t for t, _ in sim.commands()], dtype=np.float64) / 1e9
    assert np.allclose(np.diff(arrivals), [len(e) * BYTE, len(q) * BYTE], atol=2e-6)
    # no answer before its command was in and handled, nor before the answers ahead of it were out
    answers = [len(PI.answer("position", pos="0.000000")), len(PI.answer("error", code="0"))] + \
        [len(PI.answer("position", pos="0.000000"))]
    arrive = np.cumsum([len(q), len(e), len(q)]) * BYTE
    ready = out = 0.0
    for k in range(3):
        ready = max(ready, arrive[k]) + 0.0005   # (one command at a time)
        out = max(out, ready) + answers[k] * BYTE
        assert done[k] >= out - 2e-4, (k, done, out)   # (the host's clock read after the write: 0.2 ms)


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_moves_stream_pipelined_at_the_pace_of_the_line(line, d):
    sim, stage = line(d, sim={"watchdog": 0.5})
    assert isinstance(stage, StageDriver) and isinstance(stage, Stage)
    assert stage.command_mode in COMMAND_MODES
    assert stage.position() == 0.0 and stage.position_age() < 0.5
    stage.move_to(0.01)
    resolution = 1.0 / d.units_per_m
    assert _wait(lambda: abs(stage.position() - 0.01) <= resolution), stage.status()
    assert abs(sim.position() - 0.01) <= resolution
    # stream targets faster than the line carries them: they are coalesced
    ages = []
    n0 = len(sim.targets())
    t_end = time.monotonic() + 0.4
    k = 0
    while time.monotonic() < t_end:
        stage.move_to(0.01 + 0.005 * math.sin(k / 100))
        ages.append(stage.position_age())
        k += 1
        time.sleep(0.0005)
    streamed = len(sim.targets()) - n0
    stage.move_to(-0.02)
    assert _wait(lambda: abs(stage.position() + 0.02) <= resolution), stage.status()
    status = stage.status()
    assert sim.watchdog_stops() == []  # a driver that polls keeps the watchdog quiet
    stage.close()
    assert stage.fault() is None, stage.fault()
    assert status["coalesced"] > 0 and status["moves"] >= 3
    # pipelined: commands went out while answers to earlier ones were still due
    assert status["max_in_flight"] >= 2, status
    # the interval: a move's share of the busier direction of the line, never less
    k = stage.moves_per_query
    move = min(len(text) + len(d.line_end) for _, text in sim.commands() if d.command_pattern("move").fullmatch(text))
    per_move = max(_per_move_bytes(d, move, k)) * BYTE
    assert stage.command_interval >= per_move and status["min_move_spacing"] >= per_move, (status, per_move)
    # and less than one exchange at a time: the move, its confirmation, a query and its answer in turn
    tx, rx = _confirmation_bytes(d)
    one_at_a_time = (move + tx + rx + len(d.command("query_position")) + len(d.answer("position", pos="0"))) * BYTE
    assert stage.command_interval - stage.processing() < one_at_a_time, (stage.command_interval, one_at_a_time)
    # k moves per query keep the reading's age at the top rate within the driver's target (8 ms)
    assert k == 1 or k * stage.command_interval <= 0.008
    print(f"{d.name}: {k} moves per query, command interval {stage.command_interval * 1e3:.2f} ms (one exchange at "
          f"a time: {one_at_a_time * 1e3:.2f} ms), {streamed / 0.4:.0f} moves/s streamed, position age median "
          f"{np.median(ages) * 1e3:.1f} ms, max {max(ages) * 1e3:.1f} ms")
    assert streamed >= 0.2 * 0.4 / stage.command_interval   # (a shared machine starves threads now and then)
    # a few ms on a quiet machine; the suite's sanitizer builds beside it starved the driver's
    # thread to a median of 57 ms once: the bound is what a driver that polls keeps under that load
    assert np.median(ages) < 0.1 and max(ages) < 0.5, (np.median(ages), max(ages))
    assert stage.round_trip() >= (len(d.command("query_position")) + len(d.answer("position", pos="0"))) * BYTE
    # what the controller saw: no target outside the soft limits, no two moves closer than a
    # move's bytes on the wire, no command before the previous one's bytes could have arrived
    assert _wait(lambda: sim.stop_times() != [])
    targets = sim.targets()
    assert all(SOFT.x_min <= x <= SOFT.x_max and ok for _, x, ok in targets)
    t_moves = np.array([t for t, _, _ in targets])
    assert np.diff(t_moves).min() >= move * BYTE * 1e9 - 1.0
    log = sim.commands()
    gaps = np.diff([t for t, _ in log])
    wire = np.array([(len(text) + len(d.line_end)) * BYTE * 1e9 for _, text in log[1:]])
    assert np.all(gaps >= wire - 1.0), (gaps - wire).min()
    assert log[-1][1] == d.command("stop").decode().strip()
    assert sim.rejected() == []


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_a_longer_target_age_puts_more_moves_per_query(line, d):
    sim, stage = line(d, stage={"target_age": 0.05, "poll_interval": 0.02})
    t_end = time.monotonic() + 0.3
    k = 0
    while time.monotonic() < t_end:
        stage.move_to(0.01 * math.sin(k / 50))
        k += 1
        time.sleep(0.0005)
    status = stage.status()
    stage.close()
    assert stage.fault() is None, stage.fault()
    k = stage.moves_per_query
    assert k > 1 and status["moves"] > status["polls"], status
    assert status["polls"] <= status["moves"] / k + 0.3 / 0.02 + 5, status
    move = len(d.move_command(0.0))  # (0: the shortest move)
    per_move = max(_per_move_bytes(d, move, k)) * BYTE
    assert stage.command_interval >= per_move and status["min_move_spacing"] >= per_move
    t_moves = np.array([t for t, _, _ in sim.targets()])
    assert np.diff(t_moves).min() >= move * BYTE * 1e9 - 1.0


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_move_to_returns_in_microseconds_while_the_line_is_busy(line, d):
    _, stage = line(d)
    # A call that waited for the line would take an exchange's time (1.5-4 ms at 115200 Bd)
    # every time: the median and the 99th percentile stay far below that. Not the largest
    # call: on a loaded machine a few of 1000 calls wait for the interpreter (the I/O thread
    # holds it up to its 5 ms switch interval) or are preempted, which is not a blocking call.
    quantiles = []
    for _ in range(3):
        status = stage.status()
        exchanges0 = status["moves"] + status["polls"]
        calls = np.empty(1000, dtype=np.int64)
        for k in range(1000):
            x = 0.002 * math.sin(k / 30)
            t0 = time.perf_counter_ns()
            stage.move_to(x)
            calls[k] = time.perf_counter_ns() - t0
            time.sleep(0.0001)
        status = stage.status()
        assert status["moves"] + status["polls"] - exchanges0 >= 3  # the line was busy meanwhile
        quantiles.append((np.median(calls), np.percentile(calls, 99)))
        if quantiles[-1][0] < 100_000 and quantiles[-1][1] < 1_000_000:
            break
    assert min(m for m, _ in quantiles) < 100_000 and min(p for _, p in quantiles) < 1_000_000, quantiles
    assert stage.fault() is None


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_targets_outside_the_soft_limits_are_never_sent(line, d):
    sim, stage = line(d)
    for bad in (0.0401, -0.05, 1.0):
        with pytest.raises(ValueError, match=re.escape(f"{bad!r} m lies outside the soft limits")):
            stage.move_to(bad)
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match="not a finite"):
            stage.move_to(bad)
    with pytest.raises(TypeError):
        stage.move_to("0.01")
    stage.move_to(0.04)
    assert _wait(lambda: len(sim.targets()) == 1)
    time.sleep(0.02)
    stage.close()
    assert [x for _, x, _ in sim.targets()] == [pytest.approx(0.04, abs=1 / d.units_per_m)]
    assert stage.fault() is None


@pty_only
def test_a_target_at_a_soft_limit_is_written_inside_it(line):
    # 15 mm is 314960.63 microsteps: rounded to the controller's resolution it would lie 8 nm
    # outside; the driver writes the step inside instead
    limits = StageLimits(-0.015, 0.015, 0.1, 5.0)
    sim, stage = line(ZABER, limits=limits)
    for x in (0.015, -0.015):
        stage.move_to(x)
        time.sleep(0.02)
    assert _wait(lambda: len(sim.targets()) == 2)
    stage.close()
    written = [t for _, t, _ in sim.targets()]
    assert all(limits.x_min <= t <= limits.x_max for t in written), written
    assert written == pytest.approx([0.015, -0.015], abs=1.0 / ZABER_UNITS)


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_the_controller_refuses_a_target_outside_its_own_limits(line, d):
    wide = StageLimits(-0.08, 0.08, 0.1, 5.0)  # soft limits wider than the controller's travel
    sim, stage = line(d, limits=wide)
    stage.move_to(0.06)
    assert _wait(lambda: stage.fault() is not None)
    assert "controller" in stage.fault() and d.bad_target_code in stage.fault(), stage.fault()
    assert [code for _, _, code in sim.rejected()] == [d.bad_target_code]
    assert _wait(lambda: sim.stop_times() != [])
    assert sim.stop_times()[-1] > sim.rejected()[0][0]
    assert abs(sim.position()) < 1e-9  # it never moved
    with pytest.raises(RuntimeError, match="has faulted"):
        stage.move_to(0.01)
    assert isinstance(stage.position(), float)


FAULTS = ["silent", "error", "malformed", "truncated", "unsolicited", "position", "closed", "fault flag"]
WORDS = {"silent": "communication timeout", "error": "controller", "malformed": "malformed",
         "truncated": "truncated reply|malformed", "unsolicited": "unexpected bytes|malformed|implausible", "position": "position out of limits",
         "closed": "port closed", "fault flag": "controller fault FS"}


@pty_only
@pytest.mark.parametrize("d, fault", [pytest.param(d, f, id=f"{name}-{f}") for d, name in ((PI, "pi_gcs2"),
                                      (ZABER, "zaber_ascii")) for f in FAULTS if f != "fault flag" or d.fault_reply])
def test_every_fault_latches_with_its_cause_and_stops_the_axis(line, d, fault):
    sim, stage = line(d)
    stage.move_to(0.005)
    assert _wait(lambda: sim.targets() != [])
    t_inject = time.monotonic_ns()
    if fault == "silent":
        sim.go_silent()
    elif fault == "error":
        sim.answer_error("5" if d is PI else "BADDATA")
        stage.move_to(0.006)
    elif fault == "malformed":
        sim.send_malformed()
    elif fault == "truncated":
        sim.truncate_next()
    elif fault == "unsolicited":
        sim.send_unsolicited(d.answer("position", pos="0"))
    elif fault == "position":
        sim.report_position(0.045)
    elif fault == "closed":
        sim.close_port()
    else:
        sim.set_flag("FS")
    assert _wait(lambda: stage.fault() is not None), stage.status()
    words = stage.fault()
    assert re.search(WORDS[fault], words), words
    if fault == "error":
        assert ("5" if d is PI else "BADDATA") in words
    if fault in ("malformed", "truncated", "unsolicited", "position"):
        assert "b'" in words  # the bytes are shown
    # the driver sends nothing but the stop, which the controller receives if the line works
    assert _wait(lambda: stage.status()["state"] == "stopped")
    if fault == "closed":
        assert sim.stop_times() == [] and stage.status()["stops_sent"] == 0
    else:
        assert _wait(lambda: sim.stop_times() != [])
        assert sim.stop_times()[-1] > t_inject
        time.sleep(0.05)
        after = [text for t, text in sim.commands() if t > sim.stop_times()[-1]]
        assert after == [], after
    with pytest.raises(RuntimeError, match="has faulted"):
        stage.move_to(0.001)
    assert stage.fault() == words  # latched: the first cause stays
    assert isinstance(stage.position(), float) and stage.position_age() > 0
    stage.stop()  # again: harmless


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_a_silent_controller_is_found_once_its_answer_is_overdue(line, d):
    # an answer 5 ms past its due time (its bytes at the baud rate behind those before it, and
    # the controller's processing) is a communication timeout
    for _ in range(3):   # (a loaded machine may hold the controller's thread longer: try again)
        sim, stage = line(d, stage={"reply_overdue": 0.005}, sim={"latency": 0.0005})
        stage.move_to(0.002)
        time.sleep(0.1)
        if stage.fault() is None:
            break
    assert stage.fault() is None, stage.fault()
    t0 = time.monotonic_ns()
    sim.go_silent()
    assert _wait(lambda: stage.fault() is not None)
    assert re.search("communication timeout: no reply to .* ms after it was due", stage.fault()), stage.fault()
    assert _wait(lambda: sim.stop_times() != [])
    found = (sim.stop_times()[-1] - t0) / 1e6
    print(f"{d.name}: silent controller, stop received {found:.1f} ms after it fell silent")
    # a few answers on their way (at most 4, some ms of the line) and the 5 ms bound: about 10 ms
    assert found < 100.0


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_stop_goes_ahead_of_the_queued_target(line, d):
    sim, stage = line(d)
    stage.move_to(0.03)
    assert _wait(lambda: len(sim.targets()) == 1)
    stage.move_to(-0.03)
    t0 = time.monotonic()
    stage.stop()
    assert time.monotonic() - t0 < 0.5
    assert stage.status()["state"] == "stopped" and stage.fault() is None
    assert _wait(lambda: sim.stop_times() != [])
    time.sleep(0.05)
    log = sim.commands()
    stop_text = d.command("stop").decode().strip()
    assert log[-1][1] == stop_text and sim.stop_times() == [log[-1][0]]
    assert abs(sim.position()) < 0.03  # stopped on its way
    with pytest.raises(RuntimeError, match="stopped"):
        stage.move_to(0.0)
    with pytest.raises(RuntimeError, match="stopped"):
        stage.start()


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_the_watchdog_stops_an_axis_the_host_left(line, d):
    import serial
    sim, _ = line(d, sim={"watchdog": 0.05, "limits": StageLimits(-0.05, 0.05, 0.02, 1.0)}, driver=False)
    port = serial.serial_for_url(sim.port, baudrate=BAUD, timeout=0.2)
    try:
        port.write(d.move_command(0.04))  # 2 s of travel at 20 mm/s; then the host falls silent
        assert _wait(lambda: sim.watchdog_stops() != [], 1.0)
        time.sleep(0.3)
        x = sim.position()
        assert 0 < x < 0.01
        assert sim.stop_times() == [] and len(sim.watchdog_stops()) == 1
    finally:
        port.close()


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_bring_up_enable_and_home_before_the_loop(line, d):
    sim, stage = line(d, sim={"x0": 0.02, "home_position": 0.0}, start=False)
    stage.enable()
    assert sim.enabled == bool(d.enable)
    stage.home(timeout=2.0)
    assert abs(sim.position()) < 1e-9
    if d.set_velocity:
        stage.set_velocity(0.05)
        assert sim.velocity_setting == pytest.approx(0.05)
    with pytest.raises(ValueError, match="v_max"):
        stage.set_velocity(1.0)
    with pytest.raises(RuntimeError, match="not started"):
        stage.move_to(0.01)
    stage.start()
    assert stage.position() == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(RuntimeError, match="before start"):
        stage.home()
    texts = [text for _, text in sim.commands()]
    assert d.command("home").decode().strip() in texts
    assert stage.fault() is None


@pty_only
def test_an_error_left_from_before_is_cleared_at_start(line):
    sim, stage = line(PI, start=False)
    sim.answer_error("10")  # the last session's stop
    stage.start()
    assert stage.status()["cleared_error"] == "10" and stage.fault() is None
    stage.move_to(0.001)
    assert _wait(lambda: abs(stage.position() - 0.001) < 1e-9)
    assert stage.fault() is None


@pty_only
def test_a_latched_controller_error_is_found_without_a_move(line):
    sim, stage = line(PI, stage={"error_interval": 0.05})
    sim.answer_error("1024")  # e.g. a following error, reported by nobody until asked
    assert _wait(lambda: stage.fault() is not None, 1.0)
    assert "error 1024" in stage.fault(), stage.fault()
    assert _wait(lambda: sim.stop_times() != [])


@pty_only
@pytest.mark.parametrize("d", BOTH)
def test_start_refuses_a_position_outside_the_soft_limits(line, d):
    sim, stage = line(d, sim={"x0": 0.045}, start=False)
    with pytest.raises(RuntimeError, match="position out of limits"):
        stage.start()
    assert "position out of limits" in stage.fault()
    assert _wait(lambda: sim.stop_times() != [])


def test_a_driver_needs_the_scale_and_the_limits():
    pytest.importorskip("serial")
    from tactile_mirror.rig.serial_stage import SerialStage
    with pytest.raises(ValueError, match="units_per_m"):
        SerialStage("loop://", PI_GCS2, SOFT)
    with pytest.raises(TypeError, match="StageLimits"):
        SerialStage("loop://", PI, (0, 1))
    with pytest.raises(TypeError, match="Dialect"):
        SerialStage("loop://", "pi_gcs2", SOFT)
    with pytest.raises(ValueError, match="timeout"):
        SerialStage("loop://", PI, SOFT, timeout=0)


def test_a_tcp_bridge_through_socket_url():
    """``socket://`` reaches a controller behind a TCP bridge (here a minimal PI answerer)."""
    pytest.importorskip("serial")
    from tactile_mirror.rig.serial_stage import SerialStage
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    seen = []

    def answer():
        conn, _ = server.accept()
        with conn:
            buf = b""
            while True:
                data = conn.recv(256)
                if not data:
                    return
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    seen.append(line)
                    if line == b"POS? 1":
                        conn.sendall(b"1=1.500000\n")
                    elif line == b"ERR?":
                        conn.sendall(b"0\n")

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        with SerialStage(f"socket://127.0.0.1:{port}", PI, SOFT, timeout=1.0) as stage:
            stage.start()
            assert stage.position() == pytest.approx(0.0015)
            stage.move_to(0.002)
            assert _wait(lambda: b"MOV 1 2.000000" in seen)
            assert stage.fault() is None
        thread.join(2.0)
        assert seen[-1] == b"HLT 1"
    finally:
        server.close()


@pytest.mark.skipif(not (os.environ.get("TM_RIG_SERIAL_PORT") and os.environ.get("TM_RIG_DIALECT")
                         and os.environ.get("TM_RIG_UNITS_PER_M")),
                    reason="no real controller (set TM_RIG_SERIAL_PORT, TM_RIG_DIALECT, TM_RIG_UNITS_PER_M)")
def test_real_controller():
    """Read-only check of a real controller: the position, the round trip, no error. It commands
    no move (only the stop at the end). Not run against hardware when written: no controller was
    at hand. ``TM_RIG_BAUD`` sets the baud rate (default 115200); the soft limits are +-1 m."""
    pytest.importorskip("serial")
    from tactile_mirror.rig.serial_stage import SerialStage
    d = DIALECTS[os.environ["TM_RIG_DIALECT"]].with_units(float(os.environ["TM_RIG_UNITS_PER_M"]))
    baud = int(os.environ.get("TM_RIG_BAUD", "115200"))
    with SerialStage(os.environ["TM_RIG_SERIAL_PORT"], d, StageLimits(-1.0, 1.0, 0.1, 1.0), baudrate=baud) as stage:
        stage.start()
        time.sleep(0.2)
        assert stage.fault() is None, stage.fault()
        assert math.isfinite(stage.position()) and stage.position_age() < 0.1
        assert stage.round_trip() >= (len(d.command("query_position")) + 4) * 10.0 / baud
