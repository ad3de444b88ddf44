"""The rig's goals, measured on the simulated rig: the loop's runs, the serial lines' top rates
and the faults' stops (run as ``python bench/rig_goals.py``).

    python bench/rig_goals.py --out bench-out/rig               # the goal table (30 s runs, faults x3)
    python bench/rig_goals.py --quick --out DIR                  # a smoke run (2.5 s, one path, one fault)

1. **The serial lines' top rate**, per dialect (PI GCS 2.0, Zaber ASCII, a generic table) at
   115200 Bd: a :class:`~tactile_mirror.rig.SerialStage` against the simulated controller
   (:class:`~tactile_mirror.rig.sim.SerialAxis`, 0.5 ms of processing per command) on a
   pseudo-terminal, targets streamed faster than the line carries them for 1 s: the driver's
   command interval and moves per position query, the moves the controller received per
   second and the reading's age.
2. **The goal runs**: ``tactile-mirror rig run --simulate`` (the command itself, in this
   process) with the example configuration (6-ridge FEM pad at its real-time resolution, 1 kHz
   in blocks of 5, the law designed by bring-up on the simulated rig on the force sensor, the
   finger path of ``[simulation]``, 10 mm/s peak) for ``--duration`` s (30) on the analog path,
   and on PI GCS 2.0 and Zaber ASCII at 115200 Bd with ``loop.command_rate`` their measured top
   rate: rig overruns and lost samples, simulator missed deadlines, gross slips, block-to-
   command latency, largest position age, the command interval, the commands the axis received.
   Beside each run, a probe process above the simulator's priority (:class:`StallProbe`)
   notes the machine's own stalls (a 1 ms sleep that took over 2.5 ms), and the table counts
   the simulator's missed deadlines that fell in one.
3. **The faults**: each fault of the supervisor injected into the simulated rig (``--repeats``
   times, 3): the cause the run ended with, what stopped the axis (the stop received, or the
   controller's watchdog where the line is down) and how long after the fault (the pipeline's
   fault status for the NaN burst), on the one monotonic clock both processes share.

Prints the tables (markdown) with the CPU model and the load average at the start; writes each
run's folder and ``rig_goals.json`` under ``--out``. The machine should be otherwise idle:
the simulated rig and the loop are two busy processes, and a loaded machine's stalls are
what the goals are about. ``--loose`` widens the supervisor's bounds (position age, late
blocks, the serial answer's overdue bound) so that a loaded machine's stalls do not end the
runs (``--quick`` uses them). ``main`` returns the number of checks missed: a goal run
stopped by a fault, a fault that did not end its run with its cause and the axis stopped.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import signal
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import header, table, write_json

BAUD = 115200
EXAMPLE = Path(__file__).resolve().parents[1] / "python" / "tactile_mirror" / "rig" / "example_rig.toml"
ZABER_COUNTS = 1.0 / 0.047625e-6      # microsteps per metre of a stage with 0.047625 um microsteps
#: A generic dialect (a table of strings, as ``[stage.serial.generic]`` gives it): a controller
#: that speaks mm with 5 decimals, answers no set command and reports errors to a query.
GENERIC = {"name": "generic table", "move": "{axis}PA{pos}", "query_position": "{axis}TP",
           "position_reply": r"{axis}TP([-+]?\d+\.\d+)", "stop": "{axis}ST", "line_end": "\r\n",
           "reply_terminator": "\r\n", "decimals": 5, "query_error": "{axis}TE", "error_reply": r"{axis}TE([@A-Z])",
           "no_error": "@", "position_answer": "{axis}TP{pos}", "error_answer": "{axis}TE{code}",
           "bad_target_code": "C", "bad_command_code": "A"}
SERIAL = {"pi_gcs2": {"units_per_m": 1000.0}, "zaber_ascii": {"counts_per_m": ZABER_COUNTS},
          "generic": {"units_per_m": 1000.0, "generic": GENERIC}}
NAMES = {"analog": "analog", "pi_gcs2": "PI GCS 2.0", "zaber_ascii": "Zaber ASCII", "generic": "generic"}


# ---------------------------------------------------------------- the configuration file
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return json.dumps(v)    # (a TOML basic string: JSON's escapes)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML for {type(v).__name__}")


def _toml(table_: dict, prefix: str = "") -> str:
    lines, subs = [], []
    for k, v in table_.items():
        (subs if isinstance(v, dict) else lines).append((k, v))
    out = [f"[{prefix}]"] if prefix and lines else []
    out += [f"{k} = {_toml_value(v)}" for k, v in lines]
    text = "\n".join(out) + ("\n\n" if out else "")
    for k, v in subs:
        text += _toml(v, f"{prefix}.{k}" if prefix else k)
    return text


def rig_config(path: Path, stage: str, command_rate: float | None = None, quick: bool = False,
               loose: bool = False, lead: float | None = None, simulation: dict | None = None,
               sensor: str | None = None) -> Path:
    """The example configuration on ``stage`` (``"analog"`` or a dialect's name), written to ``path``;
    ``simulation`` replaces keys of its ``[simulation]``."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib

    with open(EXAMPLE, "rb") as fh:
        raw = tomllib.load(fh)
    if stage != "analog":
        raw["stage"]["kind"] = "serial"
        raw["stage"]["serial"] = {"dialect": stage, "port": "/dev/null", "baud": BAUD, **SERIAL[stage]}
        if loose:
            raw["stage"]["serial"]["reply_overdue"] = 0.05
    if command_rate is not None:
        raw["loop"]["command_rate"] = float(command_rate)
    if quick:
        raw["bringup"].update(sensors_only=0.3, calibration_cycles=1, delay_steps=1)
        raw["stage"]["approach_speed"] = 0.004
    if loose:
        raw["safety"].update(max_position_age=0.1, late_block=0.05)
    if lead is not None:
        raw["simulation"]["lead"] = float(lead)
    raw["simulation"].update(simulation or {})
    if sensor is not None:
        raw["loop"]["sensor"] = sensor
    path.write_text(_toml(raw))
    return path


# ---------------------------------------------------------------- 1. the serial lines' top rate
def top_rate(name: str, seconds: float) -> dict:
    """Stream targets to the simulated controller through a pty for ``seconds``: the driver's
    command interval, the moves received per second and the position's age."""
    import numpy as np
    from tactile_mirror.loop.stage import StageLimits
    from tactile_mirror.rig.serial_stage import SerialStage
    from tactile_mirror.rig.sim.serial_axis import SerialAxis
    from tactile_mirror.rig.sim.serial_path import make_dialect

    s = SERIAL[name]
    d = make_dialect(s.get("generic", name), s.get("units_per_m") or s["counts_per_m"])
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)   # (the controller's thread and the driver's share this interpreter)
    sim = SerialAxis(d, StageLimits(-0.02, 0.02, 0.05, 2.0), baudrate=BAUD, latency=0.5e-3, watchdog=0.5).start()
    try:
        # (the rate, not the timeout, is measured here: an answer may come late on a busy machine)
        with SerialStage(sim.port, d, StageLimits(-0.015, 0.015, 0.03, 1.0), baudrate=BAUD,
                         reply_overdue=0.05) as stage:
            stage.start()
            ages = []
            n0 = len(sim.targets())
            t0 = time.monotonic()
            k = 0
            while time.monotonic() - t0 < seconds:
                stage.move_to(0.005 * math.sin(k / 200))
                ages.append(stage.position_age())
                k += 1
                time.sleep(2e-4)
            status = stage.status()
            t_moves = np.array([t for t, _, _ in sim.targets()[n0:]], dtype=np.int64)
    finally:
        sim.close()
        sys.setswitchinterval(switch)
    span = (t_moves[-1] - t_moves[0]) / 1e9 if t_moves.size > 1 else math.nan
    return {"dialect": d.name, "interval_ms": 1e3 * status["command_interval"], "moves_per_query":
            status["moves_per_query"], "received_per_s": (t_moves.size - 1) / span if span > 0 else math.nan,
            "spacing_p50_ms": float(np.median(np.diff(t_moves))) / 1e6 if t_moves.size > 1 else math.nan,
            "round_trip_ms": 1e3 * status["round_trip"], "processing_ms": 1e3 * status["processing"],
            "age_p50_ms": 1e3 * float(np.median(ages)), "age_max_ms": 1e3 * float(np.max(ages)),
            "fault": status["fault"]}


# ---------------------------------------------------------------- the machine's own stalls
#: A process of its own, above the simulated rig's priority, that sleeps 1 ms at a time and
#: notes every wake-up more than 1.5 ms late: the stalls of the machine itself (its
#: scheduler, a virtual machine's host), which no process on it can avoid. On SIGTERM it
#: prints them (monotonic_ns of the sleep's start, ns it took) as JSON.
_PROBE = r"""
import json, os, signal, sys, time
try:
    os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(int(sys.argv[1])))
except (AttributeError, OSError, ValueError):
    pass
stop = []
signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
stalls = []
last = time.monotonic_ns()
while not stop:
    time.sleep(1e-3)
    now = time.monotonic_ns()
    if now - last > 2_500_000:
        stalls.append((last, now - last))
    last = now
print(json.dumps(stalls))
"""


class StallProbe:
    """:data:`_PROBE` beside a run: ``with StallProbe(priority) as probe: ...``, then
    ``probe.stalls`` (list of ``(start ns, length ns)``, monotonic_ns)."""

    def __init__(self, priority: int = 30):
        self.priority = int(priority)
        self.stalls: list = []

    def __enter__(self):
        import subprocess

        self._proc = subprocess.Popen([sys.executable, "-c", _PROBE, str(self.priority)], stdout=subprocess.PIPE,
                                      text=True)
        return self

    def __exit__(self, *exc) -> None:
        self._proc.terminate()
        out, _ = self._proc.communicate(timeout=10)
        try:
            self.stalls = [tuple(x) for x in json.loads(out)]
        except ValueError:
            self.stalls = []


def stall_summary(stalls: list, sim: Path | None) -> dict:
    """The probe's stalls over the simulator's run (all of them without its log), and how many
    of the simulator's missed deadlines a probe stall overlapped: one that began in the 10 ms
    before the block was due, or while it was late."""
    import numpy as np

    out = {"stalls": len(stalls), "largest_ms": max((g for _, g in stalls), default=0) / 1e6,
           "misses_in_a_machine_stall": None}
    if sim is None or not sim.exists():
        return out
    with np.load(sim) as d:
        t0, fs, size = int(d["t0_ns"]), float(d["fs"]), int(d["block_size"])
        missed, late = d["missed_blocks"], d["lateness_ns"]
        n = d["block_compute_ns"].size
    block_ns = round(1e9 * size / fs)
    end = t0 + n * block_ns
    inside = [(a, g) for a, g in stalls if t0 <= a <= end]
    due = t0 + (missed + 1) * block_ns
    hit = sum(any(d0 - 10_000_000 <= a <= d0 + dl for a, _ in inside) for d0, dl in zip(due.tolist(), late.tolist()))
    out.update(stalls=len(inside), largest_ms=max((g for _, g in inside), default=0) / 1e6,
               misses_in_a_machine_stall=int(hit))
    return out


# ---------------------------------------------------------------- 2. the goal runs
def goal_run(stage: str, out: Path, duration: float, command_rate: float | None, quick: bool, loose: bool,
             lead: float | None = None, sensor: str | None = None) -> dict:
    """``tactile-mirror rig run --simulate`` on ``stage``; its run.json, the command's output in run.log."""
    from tactile_mirror.cli import main as cli

    out.mkdir(parents=True, exist_ok=True)
    cfg = rig_config(out / "rig.toml", stage, command_rate, quick, loose, lead, sensor=sensor)
    text = io.StringIO()
    t = time.monotonic()
    with StallProbe() as probe, contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
        status = cli(["rig", "run", "--config", str(cfg), "--duration", str(duration), "--out", str(out / "run"),
                      "--simulate", "--live", "off"])
    (out / "run.log").write_text(text.getvalue())
    summary = json.loads((out / "run" / "run.json").read_text())
    summary["machine_stalls"] = stall_summary(probe.stalls, out / "run" / "simulator.npz")
    summary["exit_status"] = status
    summary["wall_s"] = time.monotonic() - t
    return summary


# ---------------------------------------------------------------- 3. the faults
ANALOG_FAULTS = {"silent": "stale position", "error_reply": "controller error",
                 "out_of_limit": "position outside soft limits", "closed_port": "closed port",
                 "nan_burst": "pipeline fault", "stall": "overrun", "SIGINT": "SIGINT"}
SERIAL_FAULTS = {"silent": "communication timeout", "error_reply": "controller error",
                 "out_of_limit": "position outside soft limits", "closed_port": "closed port"}


def fault_run(stage: str, fault: str, config_dir: Path, plant: str, loose: bool) -> dict:
    """One run of the loop (detection only: the stage holds) into which ``fault`` is injected
    0.6 s in: its cause, what stopped the axis and when (ms after the fault)."""
    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.rig.bringup import build_pipeline
    from tactile_mirror.rig.config import load_config
    from tactile_mirror.rig.runner import RigRunner
    from tactile_mirror.rig.session import RigSession
    from tactile_mirror.rig.supervisor import RigError, Supervisor

    config = load_config(rig_config(config_dir / f"fault-{stage}.toml", stage, loose=loose))
    session = RigSession(config, simulate=True, prompt=lambda text: "", plant=plant, duration=30.0,
                         **({"buffer_blocks": 12} if fault == "stall" else {}))
    session.open()
    err, stall = None, {}

    def on_block(block, outputs, position):
        if fault == "stall" and block.index > 600 and not stall:
            stall["t_ns"] = time.monotonic_ns()
            time.sleep(12 * config.block_period * 1.5)   # more than the 12 blocks the buffer holds

    try:
        pipe = build_pipeline(config, SlipDetector.paper())
        session.start_stage()
        session.start_acquisition()
        end = time.monotonic() + 0.3
        while time.monotonic() < end:    # (the simulator's first blocks are slow: lazy set-up)
            session.source.read_block(1.0)
        with Supervisor.from_config(session.stage, config, signals=fault == "SIGINT") as sup:
            runner = RigRunner(pipe, session.stage, session.source, sup, command_interval=config.command_interval,
                               on_block=on_block)
            timer = None
            if fault == "SIGINT":
                timer = threading.Timer(0.6, lambda: os.kill(os.getpid(), signal.SIGINT))
            elif fault != "stall":
                timer = threading.Timer(0.6, lambda: session.sim.inject(fault))
            if timer is not None:
                timer.start()
            try:
                runner.run(4.0)
            except RigError as exc:
                err = exc
            if timer is not None:
                timer.join()
            time.sleep(config.safety["watchdog"] + 0.1)   # (a stop that could not be sent: the watchdog's turn)
    finally:
        session.close()
    log = session.sim_log
    row = {"stage": stage, "fault": fault, "cause": err.cause if err else None, "stop_ms": math.nan, "how": None}
    if err is None or log is None:
        return row
    if fault == "stall":
        # the loop itself is held up: the controller's watchdog stops the axis during the stall;
        # the supervisor stops it once the loop sees the loss
        first = log.stop_after(stall["t_ns"])
        seen = log.stop_after(err.trip.t_detect_ns)
        row.update(stop_ms=(first[0] - stall["t_ns"]) / 1e6 if first else math.nan, how=first[1] if first else None,
                   after_detection_ms=(seen[0] - err.trip.t_detect_ns) / 1e6 if seen else math.nan,
                   lost=int(err.partial.lost_samples))
        return row
    t_fault = min([t for t, _ in log.faults], default=err.trip.t_fault_ns)
    if err.cause in ("pipeline fault", "SIGINT"):
        t_fault = err.trip.t_fault_ns
    # a serial driver sends the stop itself the moment it finds the fault, before the supervisor
    # sees it (the stops are logged as such: from the fault); on the analog path every output
    # written counts as a command, and the stop is the first written after the supervisor saw it
    stop = log.stop_after(t_fault if "stop_ns" in log.commands else err.trip.t_detect_ns)
    if stop is not None:
        row.update(stop_ms=(stop[0] - t_fault) / 1e6, how=stop[1])
    return row


# ---------------------------------------------------------------- the tables
def _f(v, fmt=".2f") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)


def print_tables(env: dict, rates: dict, runs: dict, faults: list) -> None:
    print(f"\nCPU {env['cpu']}; load average at the start {env['load']}")
    if rates:
        table("The serial lines' top rate at 115200 Bd (targets streamed through a pty, 0.5 ms processing)",
              ["dialect", "moves per query", "driver's command interval, ms", "moves received per s",
               "median spacing, ms", "round trip, ms", "position age p50 / max, ms"],
              [[r["dialect"], r["moves_per_query"], _f(r["interval_ms"]), _f(r["received_per_s"], ".0f"),
                _f(r["spacing_p50_ms"]), _f(r["round_trip_ms"]), f"{_f(r['age_p50_ms'], '.1f')} / "
                f"{_f(r['age_max_ms'], '.1f')}"] for r in rates.values()])
    if runs:
        rows = []
        for name, s in runs.items():
            run, sim = s.get("run") or {}, s.get("simulator") or {}
            lat = run.get("block_to_command_ms", {})
            cmd = sim.get("commands", {})
            stopped = (s.get("stopped") or {}).get("cause", "")
            ms = s.get("machine_stalls") or {}
            rows.append([name, f"{run.get('overruns', '-')} / {run.get('lost_samples', '-')}",
                         f"{sim.get('missed_deadlines', '-')} of {sim.get('blocks', '-')}",
                         (f"{ms.get('stalls', '-')} ({_f(ms.get('largest_ms'), '.1f')} ms), "
                          f"{ms.get('misses_in_a_machine_stall', '-')}"),
                         f"{sim.get('gross_slips', '-')} ({_f(sim.get('tracking_rms_mm'), '.3f')} mm)",
                         f"{_f(lat.get('p50'))} / {_f(lat.get('p99'))} / {_f(lat.get('max'))}",
                         _f(run.get("largest_position_age_ms"), ".1f"), _f(run.get("command_interval_ms")),
                         f"{_f(cmd.get('min_interval_ms'))}, {cmd.get('outside_soft_limits', '-')}",
                         _f(s["bringup"]["stage_delay_ms"]) if s.get("bringup") else "-", stopped or "no"])
        table("Goal runs: rig run --simulate, 6-ridge FEM pad (real time), 1 kHz in blocks of 5, the law from "
              f"bring-up on the {'strips' if env.get('sensor') == 'strips' else 'force sensor'}, 10 mm/s finger path",
              ["stage path", "overruns / lost samples", "simulator missed deadlines (of blocks)",
               "machine stalls > 2.5 ms (largest), simulator misses during one", "gross slips (tracking rms)", "block to command p50 / p99 / max, ms", "largest position age, ms",
               "command interval, ms", "commands received: shortest interval ms, outside soft limits",
               "designed stage delay, ms", "stopped by a fault"], rows)
    if faults:
        groups: dict = {}
        for r in faults:
            groups.setdefault((r["stage"], r["fault"]), []).append(r)
        rows = []
        for (stage, fault), rr in groups.items():
            v = [r["stop_ms"] for r in rr if not math.isnan(r["stop_ms"])]
            causes = sorted({str(r["cause"]) for r in rr})
            hows = sorted({str(r["how"]) for r in rr})
            extra = ""
            if fault == "stall":
                d = [r.get("after_detection_ms", math.nan) for r in rr]
                extra = (f" (from the stall's start; the supervisor's stop {_f(statistics.median(d), '.1f')} ms "
                         f"after the loop saw the loss of {rr[0].get('lost', '?')} samples)")
            rows.append([NAMES[stage], fault, ", ".join(causes), ", ".join(hows),
                         (f"{_f(min(v), '.1f')} / {_f(statistics.median(v), '.1f')} / {_f(max(v), '.1f')}" if v
                          else "-") + extra, len(rr)])
        table("Faults injected into the simulated rig: fault to the axis' stop on the shared monotonic clock",
              ["stage path", "fault", "cause", "stopped by", "fault to stop min / median / max, ms", "runs"], rows)


def _missed(runs: dict, faults: list) -> int:
    missed = sum(1 for s in runs.values() if s.get("stopped") or not s.get("run"))
    for r in faults:
        want = (ANALOG_FAULTS if r["stage"] == "analog" else SERIAL_FAULTS)[r["fault"]]
        if r["cause"] != want and not (r["fault"] == "silent" and r["cause"] == "stale position"):
            missed += 1
        elif r["how"] is None:
            missed += 1
    return missed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="folder of the runs and rig_goals.json (default: a temporary one)")
    ap.add_argument("--duration", type=float, default=None, help="s of each goal run (default 30; --quick 2.5)")
    ap.add_argument("--stages", default="analog,pi_gcs2,zaber_ascii", help="the goal runs' stage paths")
    ap.add_argument("--repeats", type=int, default=None, help="runs per fault (default 3; --quick 1)")
    ap.add_argument("--skip-runs", action="store_true", help="no goal runs")
    ap.add_argument("--skip-faults", action="store_true", help="no fault runs")
    ap.add_argument("--lead", type=float, default=None,
                    help="s the simulator computes its ticks ahead of their time (simulation.lead: its slack "
                         "against the machine's stalls, and the simulated stage's dead time; default 2 ticks)")
    ap.add_argument("--sensor", choices=("force", "strips"), default=None,
                    help="the law's shear signal (loop.sensor; default the example's, the force sensor)")
    ap.add_argument("--loose", action="store_true", help="the supervisor's bounds widened for a loaded machine")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke run: short top-rate streams, one 2.5 s goal run (PI GCS 2.0) with a short "
                         "bring-up, one fault (a silent PI controller), loose bounds")
    args = ap.parse_args(argv)
    quick = args.quick
    duration = args.duration or (2.5 if quick else 30.0)
    repeats = args.repeats or (1 if quick else 3)
    loose = args.loose or quick
    stages = ["pi_gcs2"] if quick else [s.strip() for s in args.stages.split(",") if s.strip()]
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="rig_goals-"))
    out.mkdir(parents=True, exist_ok=True)
    from tactile_mirror.lab.measure import cpu_model

    env = {"cpu": cpu_model(), "load": " ".join(f"{v:.2f}" for v in os.getloadavg()), "cpus": os.cpu_count(),
           "sensor": args.sensor or "force"}
    header("the rig's goals on the simulated rig")
    print(f"# load average at the start: {env['load']} ({env['cpus']} CPUs)", flush=True)

    rates = {}
    for name in ("pi_gcs2", "zaber_ascii", "generic"):
        rates[name] = top_rate(name, 0.3 if quick else 1.0)
    runs = {}
    if not args.skip_runs:
        for stage in stages:
            rate = None if stage == "analog" else 1e3 / rates[stage]["interval_ms"]
            runs[NAMES[stage]] = goal_run(stage, out / stage, duration, rate, quick, loose, args.lead, args.sensor)
            print(f"goal run {NAMES[stage]}: done in {runs[NAMES[stage]]['wall_s']:.0f} s", flush=True)
    faults = []
    if not args.skip_faults:
        plan = [("pi_gcs2", "silent")] if quick else (
            [("analog", f) for f in ANALOG_FAULTS] + [(s, f) for s in ("pi_gcs2", "zaber_ascii") for f in SERIAL_FAULTS])
        for _ in range(repeats):
            for stage, fault in plan:
                faults.append(fault_run(stage, fault, out, "brush" if quick else "realtime", loose))
    print_tables(env, rates, runs, faults)
    write_json(out / "rig_goals.json", {"environment": env, "top_rate": rates, "runs": runs, "faults": faults},
               indent=1, default=str)
    missed = _missed(runs, faults)
    print(f"\nchecks missed: {missed}; wrote {out / 'rig_goals.json'}")
    return missed


if __name__ == "__main__":
    sys.exit(main())
