"""The ``loop`` commands: ``design`` (the default law from a stage's data sheet), ``envelope``
(gross slips and tracking error against finger speed), ``realtime`` (the loop paced by the
wall clock against the simulated pad) and ``experiment`` (the paper's section-4 experiment)."""
from __future__ import annotations

import argparse
import sys
import warnings

from tactile_mirror.cli.arguments import (
    WEIGHTS_HELP,
    CommandError,
    UsageError,
    add_command,
    add_workers_options,
    load_detector,
    names,
    nonnegative_int,
    open_workers,
    out_files,
    positive,
)

__all__ = [
    "add_parser",
    "cmd_loop_design",
    "cmd_loop_envelope",
    "cmd_loop_experiment",
    "cmd_loop_realtime",
    "experiment_options_from_args",
]


def _speeds_mm_s(text):
    try:
        v = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated mm/s, got {text!r}") from None
    if not v or any(not x > 0 for x in v):
        raise argparse.ArgumentTypeError(f"expected positive comma-separated mm/s, got {text!r}")
    return v


def _stage_from_args(args):
    from tactile_mirror.loop.stage import StageLimits

    return StageLimits(-args.travel * 1e-3, args.travel * 1e-3, args.v_max * 1e-3, args.a_max)


def cmd_loop_design(args) -> int:
    """``tactile-mirror loop design``: the default law from the stage's data sheet, the pad's
    calibration and the tick rate; its Bode plot and summary (JSON) in ``--out``. Returns the
    exit status."""
    import numpy as np

    from tactile_mirror.files import write_json
    from tactile_mirror.lab.loop.envelope import design_law
    from tactile_mirror.lab.loop.figures import design_figure

    limits = _stage_from_args(args)
    w = _weights(_loop_weights(args.weights, args.fs))
    stem = "loop_design_load_cell" if args.load_cell else "loop_design"
    out = out_files(args.out, f"{stem}.png", f"{stem}.json")  # before the FEM calibration, not after
    d = design_law(w, args.fs, limits, args.delay * 1e-3, args.lag * 1e-3, 6, "fem",
                sensor="force" if args.load_cell else "strips", planner=not args.streaming)
    design_figure(d, str(out / f"{stem}.png"))
    write_json(out / f"{stem}.json", d.summary(), indent=1)
    sign = d.controller.direction_sign
    if args.load_cell:
        print(f"calibration: load cell, direction_sign {sign:+g}, {d.asym_per_m / 1e3:.4g} N/mm")
    else:
        print(f"calibration: shear weights (L, R per ridge) {np.round(d.shear_weights, 3).tolist()}, direction_sign "
              f"{sign:+g}, shear signal {d.asym_per_m:.4g} per m")
    print(f"crossover {d.crossover_hz:.1f} Hz, phase margin {d.phase_margin_deg:.1f} deg, gain margin "
          f"{d.gain_margin_db:.1f} dB, max |S| {d.max_sensitivity:.2f}; Kp {d.kp:.1f} 1/s, integral {d.z:.1f} 1/s, "
          f"Kv {d.kv:.2f}; loop delay {d.delays['total'] * 1e3:.2f} ms")
    print(f"wrote {out / (stem + '.png')}, {out / (stem + '.json')}")
    return 0


def _weights(w):
    from tactile_mirror.lab.loop.experiment import weights_dict

    return weights_dict(w)


def cmd_loop_envelope(args) -> int:
    """``tactile-mirror loop envelope``: gross slips and tracking error against peak finger
    speed for each law and condition (JSON, plot, a table on stdout); the runs on
    ``--scheduler``'s or ``--workers``' workers if given (the same file). Returns the exit
    status."""
    from tactile_mirror.lab.loop.envelope import PATH_SETS, envelope_figure, run_envelope

    paths = PATH_SETS[args.paths]
    weights = None if args.weights is None else load_detector(args.weights).weights
    out = out_files(args.out, "loop_envelope.json", "loop_envelope.png")  # before the work, not after
    with warnings.catch_warnings(), open_workers(args) as executor:
        # run_envelope's notes (repeated values dropped, classes capped by the paths' acceleration)
        # as plain lines, when they arise: before the runs
        warnings.showwarning = lambda message, *_args, **_kw: print(f"warning: {message}", file=sys.stderr)
        data = run_envelope(str(out / "loop_envelope.json"), speeds=[v * 1e-3 for v in args.speeds],
                            n_seeds=args.seeds, conditions=args.conditions, laws=args.laws, paths=paths,
                            duration=args.duration, limits=_stage_from_args(args), stage_delay=args.delay * 1e-3,
                            stage_lag=args.lag * 1e-3, weights=weights, progress=not args.quiet,
                            **({} if executor is None else {"executor": executor}))
    envelope_figure(data, str(out / "loop_envelope.png"), paths=paths.name)
    # the class's asked peak speed, and the speeds its paths ran at (lower where the path set's
    # acceleration limit capped them)
    print("| condition | law | peak speed mm/s | peak speed run mm/s | paths | gross slips | "
          "tracking rms mm (mean / max) |")
    print("|---|---|---|---|---|---|---|")
    for t in data["table"]:
        if t["paths"] == paths.name:
            lo, hi = t["peak_speed_run_mm_s_min"], t["peak_speed_run_mm_s_max"]
            run = f"{lo:.3g}" if lo == hi else f"{lo:.3g}-{hi:.3g}"
            print(f"| {t['condition']} | {t['law']} | {t['speed_mm_s']:g} | {run} | {t['runs']} | "
                  f"{t['gross_slips']} | {t['tracking_rms_mm_mean']:.4f} / {t['tracking_rms_mm_max']:.4f} |")
    print(f"wrote {out / 'loop_envelope.json'}, {out / 'loop_envelope.png'}")
    return 0


def cmd_loop_realtime(args) -> int:
    """``tactile-mirror loop realtime``: hardware in the loop without the hardware, the loop
    paced by the wall clock against a simulated finger on the 6-ridge FEM pad; can this
    machine hold the rate? Tick times, overruns and gross slips (JSON, plot, recording).
    Returns the exit status."""
    from tactile_mirror.contact.plants import FemPad
    from tactile_mirror.files import write_json
    from tactile_mirror.lab.loop.envelope import REPORT_PATHS, law_controllers
    from tactile_mirror.lab.loop.figures import paced_figure
    from tactile_mirror.lab.measure import environment
    from tactile_mirror.loop.scene import LoopScene, run_scene

    fs, limits = args.fs, _stage_from_args(args)
    weights = _loop_weights(args.weights, fs)
    # before the calibration and the paced run, not after them
    out = out_files(args.out, "realtime.json", "realtime_recording.npz", "realtime.png")
    seed = REPORT_PATHS.first_seed if args.seed is None else args.seed
    scene = LoopScene(seed=seed, duration=args.duration, fs=fs, plant="fem", stage_delay=args.delay * 1e-3,
                      stage_lag=args.lag * 1e-3, trajectory=REPORT_PATHS.trajectory(args.speed * 1e-3),
                      load_cell=args.law == "load cell")
    make = FemPad.realtime if args.pad == "realtime" else FemPad
    plant = make(6, fs=fs, threads=args.threads)
    controller, shear_weights = None, None
    if args.law != "open loop":
        laws, design = law_controllers(weights, fs, limits, scene.stage_delay, scene.stage_lag, 6, "fem",
                             load_cell=args.law == "load cell")
        controller = laws[args.law]
        shear_weights = design.shear_weights if args.law == "default" else None
    print(f"pacing {args.duration:g} s at {fs:g} Hz: {args.pad} pad ({plant.pad.model.n_nodes} contact "
          f"nodes a ridge, {args.threads} thread{'s' if args.threads > 1 else ''}), law {args.law}, finger up to "
          f"{args.speed:g} mm/s (seed {seed})", flush=True)
    r = run_scene(scene, weights, controller, limits, shear_weights=shear_weights, plant=plant, realtime=True)
    res = r.run
    tick, lat = res.tick_percentiles(), res.latency_percentiles()
    summary = {"environment": environment(), "fs_hz": fs, "ticks": int(r.t.size), "pad": args.pad,
               "contact_nodes": int(plant.pad.model.n_nodes), "threads": args.threads, "law": args.law,
               "detector": args.weights or "paper",
               "finger_peak_speed_mm_s": args.speed, "seed": seed, "tick_us": tick, "latency_us": lat,
               "overruns": int(res.overruns), "late_starts": int(res.late_starts), "gross_slips": int(r.gross_slips),
               "tracking_rms_mm": r.tracking_rms * 1e3}
    write_json(out / "realtime.json", summary, indent=1, default=float)
    res.to_recording(r.config, {"pad": args.pad, "law": args.law}).save(out / "realtime_recording.npz")
    paced_figure(res, r.log["slip_fraction"][:, : r.t.size], fs, out / "realtime.png",
                 f"{args.pad} pad, law {args.law}, finger up to {args.speed:g} mm/s")
    period = 1e6 / fs
    held = "held" if tick["p99"] < period else "NOT held"
    print(f"tick p50 / p99 / max {tick['p50']:.0f} / {tick['p99']:.0f} / {tick['max']:.0f} us (one tick {period:.0f} us: "
          f"p99 {held}); {res.overruns} overruns, {res.late_starts} late starts; {r.gross_slips} gross slips, "
          f"tracking rms {r.tracking_rms * 1e3:.4f} mm")
    print(f"wrote {out / 'realtime.json'}, {out / 'realtime.png'}, {out / 'realtime_recording.npz'}")
    return 0


def _loop_weights(path, fs):
    from tactile_mirror.lab.loop.experiment import default_weights

    w = default_weights("fem", fs) if path is None else load_detector(path).weights
    # checked here, before the pad is calibrated and simulated at --fs (which the
    # pipeline would refuse only afterwards, and which at MHz rates exhausts memory)
    if float(w.fs) != float(fs):
        raise CommandError(f"--fs {fs:g} Hz does not match the {float(w.fs):g} Hz the detector was trained for")
    return w


def experiment_options_from_args(args):
    """The :class:`~tactile_mirror.lab.loop.experiment.ExperimentOptions` of ``tactile-mirror
    loop experiment``'s arguments: ``--seeds N`` runs the finger paths of seeds 0 .. N-1,
    with a progress line per seed. ValueError/TypeError (naming the field) for bad values."""
    from tactile_mirror.lab.loop.experiment import ExperimentOptions

    return ExperimentOptions(seeds=tuple(range(args.seeds)), duration=args.duration, plant=args.plant,
                             robustness=not args.no_robustness, robustness_seeds=args.robustness_seeds,
                             progress=True)


def cmd_loop_experiment(args) -> int:
    """``tactile-mirror loop experiment``: open against closed loop over seeded finger paths
    and the robustness scenes (:func:`~tactile_mirror.lab.loop.experiment.run_experiment`);
    the totals on stdout, ``experiment.json``, the figures, the detector and a recording in
    ``--out``. Returns the exit status."""
    from tactile_mirror.lab.loop.experiment import run_experiment

    try:
        options = experiment_options_from_args(args)
    except (TypeError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    weights = None if args.weights is None else load_detector(args.weights).weights
    out = out_files(args.out, "experiment.json")  # before the work, not after
    res = run_experiment(options, weights=weights, out_dir=str(out))
    print(f"plant {res['plant']}; direction_sign {res['direction_sign']:+g}; asymmetry {res['asymmetry_per_m']:.3g} "
          f"per m; shear_gain {res['shear_gain']:.3g}; detector: {res['detector']}")
    if "recording" in res:
        print(f"closed-loop recording replayed bit-identical: {res['recording']['replay_bit_identical']}")
    print(f"{'scene':<34} {'controller':<22} {'runs':>4} {'slips':>6} {'runs w/ slip':>12} {'slip s':>7} "
          f"{'max y_slip':>10} {'track rms mm':>12}")
    for t in res["totals"]:
        print(f"{t['label']:<34} {t['controller']:<22} {t['runs']:>4} {t['gross_slips']:>6} "
              f"{t['runs_with_slip']:>12} {t['gross_slip_time_s']:>7.2f} {t['y_slip_max']:>10.2f} "
              f"{t['tracking_rms_mm']:>12.3f}")
    return 0


def add_parser(sub) -> None:
    """Add ``loop`` and its subcommands to the ``tactile-mirror`` subcommands ``sub``."""
    p = sub.add_parser("loop", help="the closed loop: design the default law, measure its envelope, pace it, "
                                    "run the experiment",
                       description="The stage loop on the 6-ridge FEM pad. 'design': the default law from the "
                                   "stage's data sheet, the pad's shear calibration and the sample rate (Bode "
                                   "plot, margins). 'envelope': gross slips and tracking error against peak finger "
                                   "speed for open loop, the paper's law and the default law (JSON + plot; an "
                                   "interrupted run resumes). 'realtime': the loop paced by the wall clock against a "
                                   "simulated finger on the pad (hardware in the loop without the hardware): tick "
                                   "times, overruns, gross slips (JSON, plot, recording). 'experiment': the "
                                   "paper's section-4 experiment on the brush model or the FEM pad: open against "
                                   "closed loop for each law over seeded finger paths and the robustness scenes "
                                   "(tables, JSON, Figs. 12/13, a recording).")
    lsub = p.add_subparsers(dest="loop_command", required=True, metavar="loop_command")
    for name, helptext, func in (("design", "design the default law and plot its loop", cmd_loop_design),
                                 ("envelope", "run the envelope (seeded paths per speed class)", cmd_loop_envelope),
                                 ("realtime", "pace the loop by the wall clock against the simulated pad",
                                  cmd_loop_realtime)):
        q = add_command(lsub, name, func, help=helptext)
        q.add_argument("--out", default="loop-output", help="output folder (default: %(default)s)")
        q.add_argument("--v-max", type=positive(float), default=30.0, help="stage speed limit, mm/s (default: 30)")
        q.add_argument("--a-max", type=positive(float), default=1.0, help="stage acceleration limit, m/s^2 "
                       "(default: 1)")
        q.add_argument("--travel", type=positive(float), default=20.0, help="stage travel each way, mm (default: 20)")
        q.add_argument("--delay", type=positive(float, allow_zero=True), default=1.0,
                       help="stage command dead time, ms (default: 1)")
        q.add_argument("--lag", type=positive(float, allow_zero=True), default=2.0,
                       help="stage servo time constant, ms (default: 2)")
        q.add_argument("--weights", default=None, help=WEIGHTS_HELP % "paper, the loop experiment's")
        if name == "design":
            q.add_argument("--fs", type=positive(float), default=1000.0, help="tick rate, Hz (default: 1000)")
            q.add_argument("--streaming", action="store_true",
                           help="the stage follows streamed set points (default: its move command plans a braking "
                                "move to each target at --a-max, and the command leads by the braking distance)")
            q.add_argument("--load-cell", action="store_true",
                           help="design for a load cell under the pad (MirrorPipeline(force_input=True)) instead of "
                                "the strips' shear signal; writes loop_design_load_cell.png/.json")
        elif name == "realtime":
            q.add_argument("--fs", type=positive(float), default=1000.0, help="tick rate, Hz (default: 1000)")
            q.add_argument("--pad", choices=["realtime", "default"], default="realtime",
                           help="FemPad.realtime() (contact elements of 0.2 mm) or the default FEM pad "
                                "(default: %(default)s)")
            q.add_argument("--threads", type=int, choices=[1, 2], default=1, help="threads stepping the ridges "
                           "(default: 1)")
            q.add_argument("--law", choices=["default", "load cell", "open loop"], default="default",
                           help="the default law, the same law on a load cell under the pad, or the stage held "
                                "still (the pad's worst case) (default: %(default)s)")
            q.add_argument("--speed", type=positive(float), default=5.0,
                           help="the finger's peak speed, mm/s (a report path; default: 5)")
            q.add_argument("--seed", type=nonnegative_int, default=None, help="finger path seed (default: the first report seed)")
            q.add_argument("--duration", type=positive(float), default=3.0, help="seconds, 0.5 s press included "
                           "(default: 3)")
        else:
            from tactile_mirror.lab.loop.envelope import CONDITIONS, DEFAULT_LAWS, LAWS

            q.add_argument("--speeds", type=_speeds_mm_s, default=[2.0, 5.0, 10.0, 20.0],
                           help="peak finger speeds of the classes, mm/s (default: 2,5,10,20)")
            q.add_argument("--seeds", type=positive(int), default=10, help="paths per class (default: 10)")
            q.add_argument("--conditions", type=names(list(CONDITIONS)), default=["nominal"],
                           help=f"comma-separated subset of: {', '.join(CONDITIONS).replace('%', '%%')} (default: nominal)")
            q.add_argument("--laws", type=names(list(LAWS)), default=list(DEFAULT_LAWS),
                           help="comma-separated subset of: open loop,paper,default,load cell (the default law "
                                "on a load cell under the pad) (default: open loop,paper,default)")
            q.add_argument("--paths", choices=["report", "tuning", "report-fast", "tuning-fast", "report-fast2",
                                              "tuning-fast2"], default="report",
                           help="path set: a reported one or a disjoint tuning one; the -fast sets reach 0.5 m/s^2 "
                                "(default: %(default)s)")
            q.add_argument("--duration", type=positive(float), default=3.0, help="seconds per run, 0.5 s press "
                           "included (default: 3)")
            q.add_argument("--quiet", action="store_true", help="no progress bar")
            add_workers_options(q)

    q = add_command(lsub, "experiment", cmd_loop_experiment,
                    help="open against closed loop over seeded finger paths and the robustness scenes")
    q.add_argument("--out", default="tactile-mirror-output/experiment", help="output folder (default: %(default)s)")
    q.add_argument("--plant", default="brush",
                   help="contact model: brush (the reduced brush model) or fem (the 6-ridge FEM pad) "
                        "(default: %(default)s)")
    q.add_argument("--seeds", type=positive(int), default=5,
                   help="finger paths (seeds 0 .. N-1), each run open loop and with every law (default: 5)")
    q.add_argument("--duration", type=positive(float), default=3.0, help="seconds per run (default: 3)")
    q.add_argument("--no-robustness", action="store_true",
                   help="skip the robustness scenes (sweat, compliant mounting, sensor noise, dropped samples)")
    q.add_argument("--robustness-seeds", type=nonnegative_int, default=2,
                   help="how many of the first seeds each robustness scene runs (default: 2)")
    q.add_argument("--weights", default=None,
                   help=WEIGHTS_HELP % "the plant's: for fem the paper's net, for brush one trained on the "
                                       "brush model's open-loop runs")
