"""The ``rig`` commands: ``check`` (connect, print the limits, scales and the measured round
trip; nothing moves) and ``run`` (bring-up, then the loop, recorded), on the hardware a
``rig.toml`` describes or, with ``--simulate``, on the simulated rig."""
from __future__ import annotations

import math
import sys
import threading
import time

from tactile_mirror.cli.arguments import CommandError, add_command, out_folder, positive

__all__ = ["LiveView", "add_parser", "cmd_rig_check", "cmd_rig_run"]

#: Exit status of a run stopped by a signal (128 + its number, as a shell reports it).
_SIGNAL_STATUS = {"SIGINT": 130, "SIGTERM": 143}


def _config(path):
    from tactile_mirror.rig.config import load_config

    try:
        return load_config(path)
    except FileNotFoundError:
        raise CommandError(f"--config {path}: no such file (python/tactile_mirror/rig/example_rig.toml is an "
                           f"example)") from None


class LiveView:
    """A status line on the terminal, refreshed ``rate`` times a second by its own thread:
    time, ``v_out`` of strip 0L, the largest ``y_slip``, the force, the stage's position,
    blocks, lost samples and late blocks. The loop hands it each block (:meth:`__call__`,
    a few assignments); the thread formats and writes (never in the loop's path)."""

    def __init__(self, fs: float, n_ridges: int, force_column: int, stream=None, rate: float = 5.0):
        self.fs, self.R, self.force_column = fs, n_ridges, force_column
        self.stream = stream if stream is not None else sys.stdout
        self.period = 1.0 / rate
        self._last = None
        self._blocks = 0
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tactile-mirror-live", daemon=True)
        self.lines = 0

    def __call__(self, block, outputs, position) -> None:
        # (one tuple, replaced whole: the thread reads it without a lock)
        self._last = (block.index + block.samples.shape[0], float(block.samples[-1, 0]),
                      float(outputs[-1, 2::3].max()), float(block.samples[-1, self.force_column]), float(position))
        self._blocks += 1

    def start(self) -> LiveView:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._halt.set()
        self._thread.join()
        if self.lines:
            self.stream.write("\n")
            self.stream.flush()

    def _run(self) -> None:
        while not self._halt.wait(self.period):
            last = self._last
            if last is None:
                continue
            i, v, y, f, x = last
            self.stream.write(f"\r t {i / self.fs:6.1f} s | v_out 0L {v * 1e3:+7.2f} mV | y_slip max {y:4.2f} | "
                              f"F_y {f:+6.3f} N | stage {x * 1e3:+7.3f} mm | blocks {self._blocks}  ")
            self.stream.flush()
            self.lines += 1


class _SwitchInterval:
    """While inside: the interpreter switches threads every ``interval`` s (a stage driver's
    I/O thread must get it within a fraction of a millisecond of its reply, not after the
    default 5 ms the loop's thread may hold it)."""

    def __init__(self, interval: float = 2e-4):
        self.interval = interval

    def __enter__(self):
        self.previous = sys.getswitchinterval()
        sys.setswitchinterval(self.interval)

    def __exit__(self, *exc):
        sys.setswitchinterval(self.previous)


def cmd_rig_check(args) -> int:
    """``tactile-mirror rig check``: connect, print what the rig is, measure the position
    query's round trip and the first blocks; nothing moves. Returns the exit status."""
    with _SwitchInterval():
        return _rig_check(args)


def cmd_rig_run(args) -> int:
    """``tactile-mirror rig run``: bring-up, then the loop for ``--duration`` s, recorded in
    ``--out``. Returns the exit status (1 after a fault, 130 / 143 after SIGINT / SIGTERM). The
    process runs at a higher scheduling priority where the system permits it, in real time
    (``loop.rt_priority``) while bring-up's timed steps and the loop run
    (:func:`~tactile_mirror.rig.realtime.raised_priority`), its garbage collector off from the
    rig's opening to its closing (:func:`~tactile_mirror.rig.realtime.gc_paused`)."""
    import gc

    from tactile_mirror.rig.realtime import gc_paused, raised_priority

    c = _config(args.config)
    with raised_priority() as priority, _SwitchInterval():
        gc.collect()   # (before the rig's threads start: a collection holds them all up)
        try:
            with gc_paused():
                return _rig_run(args, c, dict(priority, rt_priority=c.loop["rt_priority"]))
        finally:
            gc.collect()


def _rig_check(args) -> int:
    import numpy as np

    from tactile_mirror.rig.session import RigSession

    c = _config(args.config)
    lim = c.limits
    print(f"config {c.source}: {c.n_ridges} ridges, {c.fs:g} Hz in blocks of {c.block_size} "
          f"({c.block_period * 1e3:g} ms), stage {c.stage['kind']}")
    print(f"soft limits [{lim.x_min * 1e3:g}, {lim.x_max * 1e3:g}] mm, v_max {lim.v_max * 1e3:g} mm/s, a_max "
          f"{lim.a_max:g} m/s^2; start {c.stage['start'] * 1e3:g} mm")
    fy, fz = c.force_sensor["n_per_v_y"], c.force_sensor["n_per_v_z"]
    print(f"scales: force {fy:g} N/V (y), {fz:g} N/V (z); " + (
        f"encoder {c.analog['counts_per_m']:g} counts/m, command {c.analog['mode']}" if c.stage["kind"] == "analog"
        else f"{c.serial['dialect']} {c.serial['units_per_m']:g} units/m at {c.serial['baud']} baud"))
    session = RigSession(c, simulate=args.simulate, buffer_blocks=max(c.acquisition["buffer_blocks"], 200))
    with session:
        stage, src = session.stage, session.source
        print(f"connected: {session.adapters()['acquisition']}; {session.adapters()['stage']}")
        session.start_stage()   # (a serial driver reads the position from now on; no command is sent)
        session.start_acquisition()
        trips = []
        blocks = []
        t_end = time.monotonic() + 0.3
        while time.monotonic() < t_end:
            blocks.append(src.read_block(max(1.0, c.safety["comm_timeout"])))
            t = time.perf_counter()
            x = stage.position()
            trips.append(time.perf_counter() - t)
        rt = getattr(stage, "round_trip", None)
        round_trip = rt() if rt is not None else math.nan
        if not math.isfinite(round_trip):
            round_trip = float(np.median(trips))
        lost = sum(b.lost for b in blocks)
        late = [(time.monotonic_ns() - b.t_ns) / 1e6 for b in blocks[-1:]]
        print(f"stage position {x * 1e3:+.4f} mm (age {getattr(stage, 'position_age', lambda: math.nan)() * 1e3:.1f} "
              f"ms); position round trip {round_trip * 1e3:.3f} ms; command interval "
              f"{float(getattr(stage, 'command_interval', 0.0) or 0.0) * 1e3:.3f} ms; fault "
              f"{getattr(stage, 'fault', lambda: None)() or 'none'}")
        print(f"acquisition: {len(blocks)} blocks of {blocks[0].samples.shape} in 0.3 s, {lost} samples lost, "
              f"the last read {late[0]:.2f} ms after its last sample")
        if not lim.x_min <= x <= lim.x_max:
            print("warning: the stage stands outside the soft limits; bring-up will refuse to move it")
    for problem in session.close():
        print(f"warning: {problem}", file=sys.stderr)
    print("nothing was moved")
    return 0


def _rig_run(args, c, priority) -> int:
    import numpy as np

    from tactile_mirror.cli.arguments import load_detector
    from tactile_mirror.files import write_json
    from tactile_mirror.rig.bringup import bring_up
    from tactile_mirror.rig.runner import RigRunner
    from tactile_mirror.rig.session import RigSession
    from tactile_mirror.rig.supervisor import RigError, Supervisor

    out = out_folder(args.out)
    detector = load_detector(c.loop["weights"])
    R = c.n_ridges
    # (the simulated finger's path lasts the run: its peak speed and acceleration fall within it)
    sim_kw = {"duration": min(args.duration, c.simulation["finger_duration"])} if args.simulate else {}
    session = RigSession(c, simulate=args.simulate, **sim_kw)
    summary = {"config": c.source, "simulated": args.simulate, "duration_s": args.duration, "priority": priority}
    status, result, error = 0, None, None
    live = None
    part = "bringup_partial"
    session.open()
    try:
        summary["adapters"] = session.adapters()
        with Supervisor.from_config(session.stage, c) as sup:
            try:
                bring = bring_up(session, sup, detector)
                summary["bringup"] = bring.summary()
                bring.sensors_only.to_recording({"rig": {"adapters": summary["adapters"], "part": "sensors only"}}
                                                ).save(out / "sensors_only.npz")
                sensor = bring.design.sensor
                cols = c.pipeline_columns(sensor)
                part = "recording"
                if args.live != "off" and (args.live == "text" or sys.stdout.isatty()):
                    live = LiveView(c.fs, R, 4 * R).start()
                runner = RigRunner(bring.pipeline, session.stage, session.source, sup, columns=cols,
                                   aux_columns=(4 * R, 4 * R + 1), aux_names=("force_y", "force_z"),
                                   command_interval=c.command_interval, on_block=live,
                                   rt_priority=c.loop["rt_priority"])
                # the finger starts once the law has armed (it holds the stage for arm_delay, then tares)
                result = runner.run(args.duration, cues=[(c.loop["arm_delay"] + 0.1, session.start_finger)])
            except RigError as exc:
                error = exc
                result = exc.partial if hasattr(exc.partial, "to_recording") else None
    finally:
        if live is not None:
            live.stop()
        problems = session.close()
    meta = {"rig": {"adapters": summary.get("adapters"), "block_size": c.block_size, "fs": c.fs,
                    "command_rate_hz": c.loop["command_rate"], "config": c.source}}
    if result is not None:
        summary["run" if part == "recording" else "bringup_partial"] = result.summary()
        try:
            result.to_recording(meta).save(out / f"{part}.npz")
        except (ValueError, OSError) as exc:
            print(f"warning: the recording was not written: {exc}", file=sys.stderr)
        else:
            print(f"wrote {out / (part + '.npz')} ({result.n_ticks} samples{', partial' if error is not None else ''})")
    if session.sim_log is not None:
        log = session.sim_log
        summary["simulator"] = _sim_summary(log, error)
        summary["simulator"]["commands"] = _commands_received(log, c)
        cmd = log.commands
        np.savez(out / "simulator.npz", t0_ns=log.t0_ns, fs=log.fs, block_size=log.block_size, finger_start=log.finger_start, finger=log.finger,
                 pad=log.pad, slip_fraction=log.slip_fraction, command_t_ns=np.asarray(cmd["t_ns"], dtype=np.int64),
                 command=np.asarray(cmd["volts"] if "volts" in cmd else cmd["x"], dtype=np.float64),
                 block_compute_ns=log.block_compute_ns, missed_blocks=log.missed_blocks, lateness_ns=log.lateness_ns)
    if error is not None:
        summary["stopped"] = {"cause": error.cause, "detail": error.trip.detail}
        status = _SIGNAL_STATUS.get(error.cause, 1)
        print(f"stopped: {error}", file=sys.stderr)
    for p in problems:
        print(f"warning: {p}", file=sys.stderr)
    write_json(out / "run.json", summary, indent=1)
    _print_summary(summary)
    print(f"wrote {out / 'run.json'}")
    return status


def _commands_received(log, c) -> dict:
    """What the simulated axis received: how many commands, the shortest interval between two
    (the last, the stop when the rig closes, left out: a stop never waits), the largest target,
    and how many lay outside the soft limits (none should)."""
    import numpy as np

    cmd = log.commands
    if "volts" in cmd:   # the analog path: each value written, as a target (position) or a speed
        t = np.asarray(cmd["t_ns"], dtype=np.int64)
        v = np.asarray(cmd["volts"], dtype=np.float64)
        a = c.analog or {}
        x = (v - a.get("volts_offset", 0.0)) / a["volts_per_m"] if a.get("mode") == "position" else None
    else:                # a serial controller: the moves it received
        t = np.asarray(cmd["t_ns"], dtype=np.int64)
        x = np.asarray(cmd["x"], dtype=np.float64)
    gaps = np.diff(np.sort(t))[:-1]
    out = {"received": int(t.size), "min_interval_ms": float(gaps.min()) / 1e6 if gaps.size else None}
    if x is not None and x.size:
        lim = c.limits
        out["largest_target_mm"] = 1e3 * float(np.abs(x).max())
        out["outside_soft_limits"] = int(np.count_nonzero((x < lim.x_min) | (x > lim.x_max)))
    return out


def _sim_summary(log, error) -> dict:
    s = log.summary()
    s["gross_slips"] = log.gross_slips()
    tr = log.tracking()
    s["tracking_rms_mm"], s["tracking_max_mm"] = 1e3 * tr["rms"], 1e3 * tr["max"]
    s["faults"] = [[t, k] for t, k in log.faults]
    if error is not None:
        t_fault = min([t for t, _ in log.faults], default=error.trip.t_fault_ns)
        # (a serial driver stops the axis itself before the supervisor looks; on the analog path
        # the stop is the first output written after the supervisor saw the fault)
        stop = log.stop_after(min(t_fault, error.trip.t_detect_ns) if "stop_ns" in log.commands
                              else error.trip.t_detect_ns)
        if stop is not None:
            s["stop"] = {"how": stop[1], "after_fault_ms": (stop[0] - t_fault) / 1e6}
    return s


def _print_summary(summary: dict) -> None:
    run = summary.get("run")
    if run:
        lat = run["block_to_command_ms"]
        print(f"run: {run['ticks']} samples in {run['blocks']} blocks, {run['commands']} commands "
              f"({run['command_mode']}, interval {run['command_interval_ms']:.2f} ms); lost samples "
              f"{run['lost_samples']}, overruns {run['overruns']}, late blocks {run['late_blocks']}; block to "
              f"command p50 {lat['p50']:.2f} / p99 {lat['p99']:.2f} / max {lat['max']:.2f} ms; largest position age "
              f"{run['largest_position_age_ms']:.2f} ms")
    sim = summary.get("simulator")
    if sim:
        print(f"simulated rig: {sim['missed_deadlines']} missed deadlines of {sim['blocks']} blocks, "
              f"{sim['gross_slips']} gross slips, tracking rms {sim['tracking_rms_mm']:.4f} mm, "
              f"{sim['watchdog_trips']} watchdog trips")


def add_parser(sub) -> None:
    """Add ``rig`` and its subcommands to the ``tactile-mirror`` subcommands ``sub``."""
    p = sub.add_parser("rig", help="the mirror on a rig: check the connection, bring up and run the loop",
                       description="The mirror on a real rig (or, with --simulate, on the simulated rig that "
                                   "stands in for the devices): 'check' connects and prints the limits, scales and "
                                   "round trip, moving nothing; 'run' brings the rig up (start position, command "
                                   "delay, amplifier reset, sensors-only run, calibration, the law) and runs the loop, "
                                   "recorded. docs/rig.md: connect your rig.")
    rsub = p.add_subparsers(dest="rig_command", required=True, metavar="command")
    q = add_command(rsub, "check", cmd_rig_check, help="connect and print the rig's limits, scales and round trip; "
                                                        "nothing moves")
    q.add_argument("--config", required=True, help="the rig's TOML configuration")
    q.add_argument("--simulate", action="store_true", help="the simulated rig in place of the devices")
    q = add_command(rsub, "run", cmd_rig_run, help="bring-up, then the loop for --duration s, recorded in --out")
    q.add_argument("--config", required=True, help="the rig's TOML configuration")
    q.add_argument("--duration", type=positive(float), default=30.0, help="seconds of the loop (default: 30)")
    q.add_argument("--out", required=True, help="output folder: recording.npz, sensors_only.npz, run.json (and "
                                                "with --simulate the simulator's finger, pad and slip: simulator.npz)")
    q.add_argument("--simulate", action="store_true", help="the simulated rig in place of the devices")
    q.add_argument("--live", choices=("auto", "text", "off"), default="auto",
                   help="the live status line (auto: when the output is a terminal)")
