"""The loop through the host's own stalls, on the simulated rig (run as ``python bench/rig_stalls.py``).

    python bench/rig_stalls.py --out bench-out/stalls                # 3 stage paths x 2 laws, 20 s each
    python bench/rig_stalls.py --stall 0.010 --every 1.3 --seed 3 --finger-speed 0.015   # held out
    python bench/rig_stalls.py --quick --out DIR                     # a smoke run (3 s, analog)

A general-purpose computer holds a process up now and then for a few milliseconds (the
scheduler, a virtual machine's host): the loop's command for a block then comes late, the
stage holds its last target meanwhile, and the finger moves on. Each run here is ``rig run
--simulate`` as the command does it (bring-up on the simulated rig, the law it designs, the
example configuration's finger path at 10 mm/s) with the loop made to stall for ``--stall``
s (6 ms) every ``--every`` s (1.5 s) once the finger moves: a stall in the loop's thread
right after a block's command, as the machine's own stalls fall. The laws compared, per stage path:

* ``designed``: the law bring-up designs (on the force sensor: no slip guard);
* ``slip guard``: the same with the strips' slip guard (``slip_hold`` 0.1 s: hold the stage
  after a detected slip, then re-tare), as the force law had it before;
* ``previous``: the law bring-up designed before: for the step fit's delay (plus the block's
  hold and the host's latency) instead of the sine's, with no bound on its crossover from
  ``a_max`` (``loop.max_error``), and the slip guard.

``main`` returns the designed law's gross slips plus its runs stopped by a fault. Prints,
per run: the stalls made, gross slips, the tracking rms and largest error, the force
sensor's largest |F_y| over the run (the contact carries about 9 N before it slides) and its
mean |F_y| over the last second; writes ``rig_stalls.json`` under ``--out``. The machine
should be otherwise idle (the stalls are the ones made here).
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import header, table, write_json
from rig_goals import NAMES, rig_config, top_rate


def _previous_law(c, bring):
    """The law bring-up designed before: for the stage delay of the step fit (plus the block's
    hold and the host's latency), no bound on the crossover from ``a_max``, and the slip
    guard on the force too."""
    from tactile_mirror.loop.design import design_loop

    lp, cal = c.loop, bring.calibration
    sensor = bring.design.sensor
    calibration = (cal["force_sign"], cal["force_n_per_m"]) if sensor == "force" else \
        (cal["direction_sign"], cal["asym_per_m"])
    d = design_loop(c.limits, calibration, c.fs, stage_delay=bring.phase["steps_estimate_ms"] / 1e3,
                    stage_lag=c.stage["lag"], estimator_order=lp["estimator_order"],
                    estimator_bandwidth=lp["estimator_bandwidth"], arm_delay=lp["arm_delay"],
                    phase_margin=lp["phase_margin"], gain_margin=lp["gain_margin"],
                    max_sensitivity=lp["max_sensitivity"], planner=lp["planner"], sensor=sensor,
                    shear_weights=None if sensor == "force" else cal["shear_weights"])
    return dataclasses.replace(d.controller, slip_hold=max(0.1, d.controller.slip_hold)), d


def stall_run(stage: str, law: str, out: Path, duration: float, stall: float, every: float,
              command_rate: float | None, simulation: dict | None = None, quick: bool = False) -> dict:
    """One run of ``law`` on ``stage`` with the loop stalled ``stall`` s every ``every`` s."""
    import numpy as np
    from tactile_mirror.cli.arguments import load_detector
    from tactile_mirror.rig.bringup import bring_up, build_pipeline
    from tactile_mirror.rig.config import load_config
    from tactile_mirror.rig.runner import RigRunner
    from tactile_mirror.rig.session import RigSession
    from tactile_mirror.rig.supervisor import RigError, Supervisor

    out.mkdir(parents=True, exist_ok=True)
    c = load_config(rig_config(out / "rig.toml", stage, command_rate, quick=quick, loose=quick, simulation=simulation))
    detector = load_detector(c.loop["weights"])
    session = RigSession(c, simulate=True, prompt=lambda text: "",
                         duration=min(duration, c.simulation["finger_duration"]))
    stalls: list[int] = []
    start = c.loop["arm_delay"] + 0.1     # the finger's start (s into the run)
    next_stall = [math.inf]

    def on_block(block, outputs, position):
        t = time.monotonic()
        if t >= next_stall[0]:
            stalls.append(time.monotonic_ns())
            next_stall[0] = t + every
            end = t + stall
            while time.monotonic() < end:   # (held up, as by the machine: not sleeping, not reading)
                pass

    def begin():
        session.start_finger(log=lambda *a: None)
        next_stall[0] = time.monotonic() + every / 2

    error = None
    session.open()
    try:
        with Supervisor.from_config(session.stage, c) as sup:
            bring = bring_up(session, sup, detector, log=lambda *a: None)
            ctrl, design = bring.design.controller, bring.design
            if law == "slip guard":
                ctrl = dataclasses.replace(ctrl, slip_hold=0.1)
            elif law == "previous":
                ctrl, design = _previous_law(c, bring)
            pipe = build_pipeline(c, detector, ctrl, force_input=bring.design.sensor == "force",
                                  shear_weights=None if bring.design.sensor == "force" else bring.design.shear_weights)
            R = c.n_ridges
            runner = RigRunner(pipe, session.stage, session.source, sup, columns=c.pipeline_columns(bring.design.sensor),
                               aux_columns=(4 * R, 4 * R + 1), aux_names=("force_y", "force_z"),
                               command_interval=c.command_interval, on_block=on_block,
                               rt_priority=c.loop["rt_priority"])
            try:
                result = runner.run(duration, cues=[(start, begin)])
            except RigError as exc:
                error, result = exc, exc.partial
    finally:
        session.close()
    log = session.sim_log
    if log is not None and result is not None:   # the traces, to look at
        np.savez(out / "traces.npz", finger=log.finger, pad=log.pad, slip_fraction=log.slip_fraction,
                 finger_start=log.finger_start, force_y=result.aux[:, 0], command=result.outputs[:, 0],
                 stage_position=result.stage_position, stalls_ns=np.asarray(stalls, dtype=np.int64),
                 block_t_ns=result.block_t_ns, t0_ns=log.t0_ns)
    fy = np.abs(result.aux[:, 0]) if result is not None and result.aux.size else np.zeros(1)
    last = fy[-round(c.fs):]
    track = log.tracking() if log is not None else {"rms": math.nan, "max": math.nan}
    return {"stage": NAMES[stage], "law": law, "stalls": len(stalls), "stall_ms": 1e3 * stall,
            "gross_slips": log.gross_slips() if log is not None else None,
            "tracking_rms_mm": 1e3 * track["rms"], "tracking_max_mm": 1e3 * track["max"],
            "force_max_N": float(fy.max()), "force_last_s_N": float(last.mean()),
            "late_blocks": int(result.late_blocks) if result is not None else None,
            "stopped": error.cause if error is not None else None,
            "designed_stage_delay_ms": 1e3 * design.stage_delay, "crossover_hz": design.crossover_hz}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="folder of the runs and rig_stalls.json (default: a temporary one)")
    ap.add_argument("--duration", type=float, default=20.0, help="s of each run (default 20)")
    ap.add_argument("--stall", type=float, default=0.006, help="s each stall lasts (default 0.006)")
    ap.add_argument("--every", type=float, default=1.5, help="s between stalls (default 1.5)")
    ap.add_argument("--stages", default="analog,pi_gcs2,zaber_ascii", help="the stage paths")
    ap.add_argument("--laws", default="designed,previous",
                    help="the laws: designed, slip guard, previous (default: designed,previous)")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke run: the analog path, the designed law, 3 s stalled 6 ms every 1 s, a short "
                         "bring-up, loose bounds")
    ap.add_argument("--seed", type=int, default=0, help="the simulated finger path's seed (default 0, the example's)")
    ap.add_argument("--finger-speed", type=float, default=0.01, help="its peak speed, m/s (default 0.01)")
    args = ap.parse_args(argv)
    if args.quick:
        args.stages, args.laws, args.duration, args.stall, args.every = "analog", "designed", 3.0, 0.006, 1.0
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="rig_stalls-"))
    from tactile_mirror.lab.measure import cpu_model

    header("the loop through the host's stalls, on the simulated rig")
    print(f"# CPU {cpu_model()}; load average at the start "
          f"{' '.join(f'{v:.2f}' for v in os.getloadavg())}", flush=True)
    rows = []
    for stage in [s.strip() for s in args.stages.split(",") if s.strip()]:
        rate = None if stage == "analog" else 1e3 / top_rate(stage, 1.0)["interval_ms"]
        for law in [s.strip() for s in args.laws.split(",") if s.strip()]:
            r = stall_run(stage, law, out / f"{stage}-{law.replace(' ', '_')}", args.duration, args.stall,
                          args.every, rate, {"seed": args.seed, "finger_speed": args.finger_speed}, args.quick)
            print(f"{r['stage']}, {law}: {r['gross_slips']} gross slips", flush=True)
            rows.append(r)
    table(f"The loop stalled {1e3 * args.stall:g} ms every {args.every:g} s, {args.duration:g} s runs, finger seed "
          f"{args.seed} at {1e3 * args.finger_speed:g} mm/s",
          ["stage path", "law", "stalls", "gross slips", "tracking rms / max, mm", "largest |F_y|, N",
           "mean |F_y| over the last s, N", "late blocks", "designed stage delay, ms (crossover, Hz)", "stopped by"],
          [[r["stage"], r["law"], r["stalls"], r["gross_slips"], f"{r['tracking_rms_mm']:.3f} / {r['tracking_max_mm']:.3f}",
            f"{r['force_max_N']:.2f}", f"{r['force_last_s_N']:.2f}", r["late_blocks"],
            f"{r['designed_stage_delay_ms']:.2f} ({r['crossover_hz']:.1f})", r["stopped"] or "-"] for r in rows])
    write_json(out / "rig_stalls.json", {"stall_s": args.stall, "every_s": args.every, "duration_s": args.duration,
                                         "seed": args.seed, "finger_speed": args.finger_speed, "runs": rows}, indent=1, default=str)
    print(f"\nwrote {out / 'rig_stalls.json'}")
    return sum(int(r["gross_slips"] or 0) + (r["stopped"] is not None) for r in rows if r["law"] == "designed")


if __name__ == "__main__":
    sys.exit(main())
