"""The ``tactile-mirror`` command.

    tactile-mirror demo                       the paper's scenes, figures and a summary
    tactile-mirror simulate --scene fig8      one contact scene -> .npz (+ figure)
    tactile-mirror figure 6 --out figures/    a paper figure reproduction (6, 7, 8, 10, 12, 13)
    tactile-mirror train / evaluate           slip-detector training and evaluation
    tactile-mirror bench --out report/        run time against error of every kernel (table + plot)
    tactile-mirror loop design / envelope     the default loop law from a stage's data sheet; its envelope

Every subcommand has ``--help``. Bad options print a message and exit with status 2;
errors while running print ``error: ...`` and exit with status 1.
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import time
import warnings

PAPER_SCENES = {"fig6": "no stop", "fig7": "stop at A (1.00-1.05 s)", "fig8": "stop at B (1.40-1.45 s)"}


class CommandError(Exception):
    """A failure to report as ``error: ...`` without a traceback."""


def _positive(kind, allow_zero=False):
    def parse(text):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {kind.__name__}, got {text!r}") from None
        if not (v >= 0 if allow_zero else v > 0):
            raise argparse.ArgumentTypeError(f"must be {'non-negative' if allow_zero else 'positive'}, got {text!r}")
        return v

    return parse


#: Seeds: non-negative integers (a negative one reached numpy as "expected non-negative integer").
_nonnegative_int = _positive(int, allow_zero=True)


def scene_from_args(args):
    from tactile_mirror import scenes

    kw = {}
    if args.friction is not None:
        kw["friction"] = args.friction
    if args.duration is not None:
        kw["duration"] = args.duration
    kw["n_ridges"] = args.ridges
    kw["noise"] = args.noise
    kw["seed"] = args.seed
    if args.scene == "random":
        # (the options given are fixed values of the random scene; the rest is drawn)
        return scenes.random(1, seed=args.seed, **{k: v for k, v in kw.items() if k != "seed"})[0]
    return scenes.paper(args.scene, **kw)


def _out_folder(path) -> pathlib.Path:
    """``--out`` as a folder, made now: a file there, or a folder that cannot be written,
    fails before the work, not after it."""
    import os

    out = pathlib.Path(path)
    if out.exists() and not out.is_dir():
        raise CommandError(f"--out {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise CommandError(f"--out {out} is not writable")
    return out


def _out_files(path, *names) -> pathlib.Path:
    """:func:`_out_folder`, and that each of the files ``names`` the command writes there can
    be written (not a folder, not read-only): checked before the work, not after it."""
    from tactile_mirror._io import check_figure_path, check_writable

    out = _out_folder(path)
    for name in names:
        (check_figure_path if name.endswith(".png") else check_writable)(out / name)
    return out


def _contact_figure(result, name, path):
    from tactile_mirror.lab.plots import contact_scene_figure, save

    slip = f"gross slip at {result.slip_time:.3f} s" if result.slip_time is not None else "no gross slip"
    title = f"{name}: {PAPER_SCENES.get(name, 'scene')}; {slip}"
    save(contact_scene_figure(result, title=title), path)


# ---------------------------------------------------------------- subcommands
def cmd_simulate(args) -> int:
    import numpy as np

    from tactile_mirror import simulate
    from tactile_mirror._io import check_figure_path, check_writable, save_npz

    scene = scene_from_args(args)
    out = pathlib.Path(args.out)
    check_writable(out, make_folder=True)  # fail before the work, not after
    if args.figure:
        check_figure_path(args.figure, make_folder=True)
    t0 = time.perf_counter()
    res = simulate(scene, progress=True, stepping=args.stepping)
    # written to exactly --out (no suffix added), atomically
    save_npz(out, compressed=True, t=res.t, fs=res.fs, plate_y=res.plate_y, indent=res.indent,
             stress=res.stress, v_out=res.v_out, u_out=res.u_out, slip_fraction=res.slip_fraction,
             force_y=res.force_y, force_z=res.force_z,
             slip_time=np.nan if res.slip_time is None else res.slip_time,
             friction=scene.friction, n_ridges=scene.n_ridges)
    print(f"simulated {res.t.size} steps in {time.perf_counter() - t0:.2f} s ({res.stepping} stepping: "
          f"{res.solves} solves, {res.events} events); gross slip: "
          f"{'none' if res.slip_time is None else f'{res.slip_time:.3f} s'}; wrote {out}")
    if args.figure:
        _contact_figure(res, args.scene, args.figure)
        print(f"wrote {args.figure}")
    return 0


def cmd_demo(args) -> int:
    from tqdm.auto import tqdm

    from tactile_mirror import scenes, simd_path, simulate_many

    out = _out_folder(args.out)  # fail before the work, not after
    t_start = time.perf_counter()
    print(f"tactile-mirror demo: C++ kernels on the {simd_path()} path; output folder {out}/")
    names = list(PAPER_SCENES)
    results = simulate_many([scenes.paper(n) for n in names], progress=True)
    import numpy as np

    from tactile_mirror.detector import SlipDetector
    from tactile_mirror.lab.detector import figure10, figure10_data
    from tactile_mirror.lab.loop import experiment
    from tactile_mirror.lab.loop.figures import loop_figure
    from tactile_mirror.lab.plots import save

    # Fig. 10 is the paper's net's figure; the table also gives the default (filter-bank) net.
    paper_det, default_det = SlipDetector.paper(), SlipDetector.default()
    stops = {"fig6": [], "fig7": [(1.00, 1.05)], "fig8": [(1.40, 1.45)]}

    def first_alarm(det, res, stops):
        d = figure10_data(det, res, stops=stops)
        alarm = np.flatnonzero(d["y_slip"] >= 0.8)
        return float(d["t"][alarm[0]]) if alarm.size else None

    rows = []
    for name, res in tqdm(list(zip(names, results)), desc="figures", unit="fig"):
        _contact_figure(res, name, out / f"{name}.png")
        rows.append((name, PAPER_SCENES[name], res.slip_time, first_alarm(paper_det, res, stops[name]),
                     first_alarm(default_det, res, stops[name])))
    save(figure10(paper_det, results[0], results[2], stops_b=stops["fig8"]), out / "fig10.png")
    fmt = lambda t: "none" if t is None else f"{t:.3f} s"
    print("\n| scene | plate motion | gross slip | first y_slip >= 0.8: paper's net | default (filter-bank) net |")
    print("|---|---|---|---|---|")
    for name, what, ts, ta, tb in rows:
        print(f"| {name} | {what} | {fmt(ts)} | {fmt(ta)} | {fmt(tb)} |")

    print("\nthe tactile mirror: a finger on the 6-ridge FEM pad, open loop, then with the stage in the loop")
    r_open, r_closed = experiment.open_and_closed(seed=0)
    loop_figure(r_open, out / "fig12.png", closed=False)
    loop_figure(r_closed, out / "fig13.png", closed=True, law="velocity")
    print("\n| loop | gross slips | tracking rms | max y_slip |")
    print("|---|---|---|---|")
    for label, r in (("open (stage still)", r_open), ("closed (shear loop + y_pred)", r_closed)):
        s = r.summary()
        print(f"| {label} | {r.gross_slips} | {s['tracking_rms_mm']:.3f} mm | {s['y_slip_max']:.2f} |")
    figs = [*(f"{n}.png" for n in names), "fig10.png", "fig12.png", "fig13.png"]
    print(f"\nfigures in {out}/: {', '.join(figs)}")
    print(f"done in {time.perf_counter() - t_start:.1f} s")
    return 0


#: Names ``--weights`` takes for the bundled nets (``SlipDetector.<name>()``); a weights file
#: of one of these names is given as a path, e.g. ``./pad``.
BUNDLED_NETS = ("default", "paper", "bank", "early", "pad", "memory")
_WEIGHTS_HELP = ("detector weights file, or a bundled net: " + ", ".join(BUNDLED_NETS) + " (default: %s)")


def load_detector(path):
    from tactile_mirror.detector import SlipDetector

    if path is None:
        return SlipDetector.default()
    if path in BUNDLED_NETS:
        return getattr(SlipDetector, path)()
    return SlipDetector.load(path)


def build_options_from_args(args):
    """The :class:`~tactile_mirror.lab.detector.build.BuildOptions` of ``tactile-mirror train``'s arguments."""
    from tactile_mirror.lab.detector.build import BuildOptions

    return BuildOptions(n_train=args.n_train, n_test=args.n_test, n_hidden=args.hidden, maxiter=args.maxiter,
                        candidates=args.candidates, n_validation=args.n_validation,
                        checkpoint_every=args.checkpoint_every)


def cmd_train(args) -> int:
    from tactile_mirror._io import check_figure_path, check_writable
    from tactile_mirror.lab.detector.build import build_default

    options = build_options_from_args(args)  # bad combinations fail before any work
    out = pathlib.Path(args.out)
    for path in (out, args.report):  # fail before training, not after
        if path is not None:
            check_writable(path, make_folder=True)
    if args.figure is not None:
        check_figure_path(args.figure, make_folder=True)
    _, report = build_default(out, options, report_path=args.report, figure_path=args.figure)
    print(report["evaluation_table"])
    print(f"wrote {out} ({report['total_seconds']:.0f} s)")
    return 0


def cmd_evaluate(args) -> int:
    from tactile_mirror import simulate_many
    from tactile_mirror.lab.detector import evaluate
    from tactile_mirror.lab.detector.build import TEST_KWARGS, TEST_SEED
    from tactile_mirror.lab.detector.evaluation import detection_by_onset
    from tactile_mirror.scenes import random

    det = load_detector(args.weights)
    scenes = random(args.scenes, seed=TEST_SEED if args.seed is None else args.seed, **TEST_KWARGS)
    results = simulate_many(scenes, progress=True)
    report = evaluate(det, results)
    print(report.table())
    by = detection_by_onset(det, results)
    print("\ndetection by how gross slip starts (lab.detector.evaluation.onset_kinds):")
    for kind, what in (("release", "release of stored shear (a spike on both strips)"),
                       ("gradual", "gradual creep (the strips' rates only settle)")):
        n, rate = by[kind]
        print(f"  {what}: {n} slips, " + (f"{100 * rate:.1f} % detected" if n else "none"))
    return 0


def cmd_figure(args) -> int:
    from tactile_mirror import scenes, simulate

    out = _out_folder(args.out)
    if args.number in (6, 7, 8):
        name = f"fig{args.number}"
        res = simulate(scenes.paper(name), progress=True)
        path = out / f"{name}.png"
        _contact_figure(res, name, path)
    elif args.number == 10:  # the detector on fig6 and fig8
        from tactile_mirror.lab.detector import figure10
        from tactile_mirror.lab.plots import save

        det = load_detector(args.weights)
        a, b = simulate(scenes.paper("fig6")), simulate(scenes.paper("fig8"))
        path = out / "fig10.png"
        save(figure10(det, a, b, stops_b=[(1.40, 1.45)]), path)
    else:  # 12, 13: the open / closed loop on the FEM pad
        from tactile_mirror.lab.loop import experiment
        from tactile_mirror.lab.loop.figures import loop_figure

        w = None if args.weights is None else load_detector(args.weights).weights
        r_open, r_closed = experiment.open_and_closed(args.seed, w, law=args.law)
        out.mkdir(parents=True, exist_ok=True)
        if args.number == 12:
            path = out / "fig12.png"
            loop_figure(r_open, path, closed=False)
        else:
            path = out / "fig13.png"
            loop_figure(r_closed, path, closed=True, law=args.law)
        print(f"gross slips: open loop {r_open.gross_slips}, closed loop {r_closed.gross_slips}; tracking rms "
              f"{r_open.tracking_rms * 1e3:.3f} mm open, {r_closed.tracking_rms * 1e3:.4f} mm closed")
    print(f"wrote {path}")
    return 0


def _bench_kernels(text):
    from tactile_mirror.lab.benchmark import KERNELS

    names = [k.strip() for k in text.split(",") if k.strip()]
    if names == ["all"]:
        return list(KERNELS)
    bad = [k for k in names if k not in KERNELS]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(KERNELS)} (or all), "
                                         f"got {text!r}")
    return names


def cmd_bench(args) -> int:
    from tactile_mirror.lab.benchmark import JSON_NAME, MD_NAME, PNG_NAME, bench_report

    out = _out_folder(args.out)
    print(f"tactile-mirror bench: {', '.join(args.kernels)} ({'quick' if args.quick else 'full'} run); "
          f"output folder {out}/")
    report = bench_report(out, kernels=args.kernels, quick=args.quick, progress=True)
    for k in report.kernels.values():
        best = "; ".join(v.label for v in k.variants if v.pareto)
        print(f"{k.name}: {len(k.variants)} variants, Pareto-optimal: {best}")
    print(f"wrote {out / MD_NAME}, {out / PNG_NAME}, {out / JSON_NAME} ({report.seconds:.0f} s)")
    return 0


def _speeds_mm_s(text):
    try:
        v = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated mm/s, got {text!r}") from None
    if not v or any(not x > 0 for x in v):
        raise argparse.ArgumentTypeError(f"expected positive comma-separated mm/s, got {text!r}")
    return v


def _names(choices):
    def parse(text):
        names = [x.strip() for x in text.split(",") if x.strip()]
        bad = [x for x in names if x not in choices]
        if bad or not names:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(choices)}, got {text!r}")
        return names

    return parse


def _stage_from_args(args):
    from tactile_mirror.loop.stage import StageLimits

    return StageLimits(-args.travel * 1e-3, args.travel * 1e-3, args.v_max * 1e-3, args.a_max)


def cmd_loop_design(args) -> int:
    import numpy as np

    from tactile_mirror._io import write_json
    from tactile_mirror.lab.loop.envelope import design_law
    from tactile_mirror.lab.loop.figures import design_figure

    limits = _stage_from_args(args)
    w = _weights(_loop_weights(args.weights, args.fs))
    stem = "loop_design_load_cell" if args.load_cell else "loop_design"
    out = _out_files(args.out, f"{stem}.png", f"{stem}.json")  # before the FEM calibration, not after
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
    from tactile_mirror.lab.loop.envelope import PATH_SETS, envelope_figure, run_envelope

    paths = PATH_SETS[args.paths]
    weights = None if args.weights is None else load_detector(args.weights).weights
    out = _out_files(args.out, "loop_envelope.json", "loop_envelope.png")  # before the work, not after
    with warnings.catch_warnings():
        # run_envelope's notes (repeated values dropped, classes capped by the paths' acceleration)
        # as plain lines, when they arise: before the runs
        warnings.showwarning = lambda message, *_args, **_kw: print(f"warning: {message}", file=sys.stderr)
        data = run_envelope(str(out / "loop_envelope.json"), speeds=[v * 1e-3 for v in args.speeds],
                            n_seeds=args.seeds, conditions=args.conditions, laws=args.laws, paths=paths,
                            duration=args.duration, limits=_stage_from_args(args), stage_delay=args.delay * 1e-3,
                            stage_lag=args.lag * 1e-3, weights=weights, progress=not args.quiet)
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
    """Hardware in the loop without the hardware: the loop paced by the wall clock against
    a simulated finger on the 6-ridge FEM pad; can this machine hold the rate?"""
    from tactile_mirror._io import write_json
    from tactile_mirror.contact.plants import FemPad
    from tactile_mirror.lab.loop.envelope import REPORT_PATHS, law_controllers
    from tactile_mirror.lab.loop.figures import paced_figure
    from tactile_mirror.lab.measure import environment
    from tactile_mirror.loop.scene import LoopScene, run_scene

    fs, limits = args.fs, _stage_from_args(args)
    weights = _loop_weights(args.weights, fs)
    # before the calibration and the paced run, not after them
    out = _out_files(args.out, "realtime.json", "realtime_recording.npz", "realtime.png")
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


# ---------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    from tactile_mirror.scenes import DEFAULT_FRICTION

    parser = argparse.ArgumentParser(prog="tactile-mirror",
                                     description="Closed-loop tactile displays that render static friction.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="command")

    p = sub.add_parser("demo", help="the paper's scenes on the bundled defaults: summary and figures",
                       description="Simulate the paper's three contact scenes (Figs. 6-8), run the bundled "
                                   "slip detector on them (Fig. 10), run a finger on the 6-ridge pad open and "
                                   "closed loop (Figs. 12, 13), print a summary and write the figures.")
    p.add_argument("--out", default="tactile-mirror-output", help="output folder (default: %(default)s)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("simulate", help="simulate one contact scene", description="Simulate a contact scene "
                       "and save its signals (t, stress, v_out, u_out, slip_fraction, forces) as .npz.")
    p.add_argument("--scene", choices=[*PAPER_SCENES, "random"], default="fig6",
                   help="paper scene or a random one (default: %(default)s)")
    p.add_argument("--friction", type=_positive(float), default=None,
                   help=f"static friction coefficient (default: {DEFAULT_FRICTION:g})")
    p.add_argument("--duration", type=_positive(float), default=None, help="seconds (default: 2.0)")
    p.add_argument("--ridges", type=_positive(int), default=1, help="ridges in the pad (default: 1)")
    p.add_argument("--noise", type=float, default=0.0, help="sensor noise, V rms (default: 0)")
    p.add_argument("--seed", type=_nonnegative_int, default=0, help="noise / random-scene seed (default: 0)")
    p.add_argument("--out", default="scene.npz",
                   help="output file, npz format, written as named (default: %(default)s)")
    p.add_argument("--figure", default=None, help="also write the Figs. 6-8 style plot to this file")
    p.add_argument("--stepping", choices=["auto", "every"], default="auto",
                   help="contact stepping: 'auto' solves at contact events only, 'every' at every sample "
                        "(the reference; same results to round-off) (default: %(default)s)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("figure", help="reproduce a figure of the paper",
                       description="Reproduce one of the paper's figures as a PNG: 6, 7, 8 (contact "
                                   "signals), 10 (the slip detector on the fig6 and fig8 scenes), 12 (a "
                                   "finger on the 6-ridge pad, open loop) or 13 (the same finger, closed loop).")
    p.add_argument("number", type=int, choices=[6, 7, 8, 10, 12, 13], help="figure number")
    p.add_argument("--out", default="figures", help="output folder (default: %(default)s)")
    p.add_argument("--weights", default=None, help=_WEIGHTS_HELP % "default; figures 12, 13: paper, the loop experiment's")
    p.add_argument("--seed", type=_nonnegative_int, default=0, help="figures 12, 13: finger path seed (default: 0)")
    p.add_argument("--law", default="velocity",
                   choices=["velocity", "paper", "velocity, y_pred ramp", "velocity, shear only"],
                   help="figure 13: stage controller (default: %(default)s)")
    p.set_defaults(func=cmd_figure)

    p = sub.add_parser("train", help="simulate scenes, train and evaluate a slip detector",
                       description="Simulate randomized training and held-out scenes, train the recurrent "
                                   "detector (and the baselines), evaluate and save the weights.")
    p.add_argument("--out", default="detector.npz", help="weights file to write (default: %(default)s)")
    p.add_argument("--n-train", type=_positive(int), default=64, help="training scenes (default: 64)")
    p.add_argument("--n-test", type=_positive(int), default=200, help="held-out scenes (default: 200)")
    p.add_argument("--hidden", type=_positive(int), default=16, help="hidden units (default: 16)")
    p.add_argument("--maxiter", type=_positive(int), default=800, help="L-BFGS-B iterations (default: 800)")
    p.add_argument("--candidates", type=_positive(int), default=4,
                   help="initial seeds to train from; the best on the validation scenes is kept (default: 4)")
    p.add_argument("--checkpoint-every", type=_positive(int, allow_zero=True), default=25,
                   help="also score checkpoints every this many iterations (0: final weights only; default: 25)")
    p.add_argument("--n-validation", type=_positive(int), default=120,
                   help="validation scenes for choosing among candidates (default: 120)")
    p.add_argument("--report", default=None, help="also write the evaluation report here")
    p.add_argument("--figure", default=None, help="also write Figure 10 here")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("evaluate", help="evaluate a slip detector on held-out scenes",
                       description="Simulate randomized held-out scenes and report detection rate, false "
                                   "alarms, latency and y_pred lead.")
    p.add_argument("--weights", default=None, help=_WEIGHTS_HELP % "default")
    p.add_argument("--scenes", type=_positive(int), default=20, help="held-out scenes (default: 20)")
    p.add_argument("--seed", type=_nonnegative_int, default=None, help="scene seed (default: the held-out seed)")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("bench", help="run time against error of every kernel: markdown table and Pareto plot",
                       description="Time every kernel (filters, stress-rate estimator, slip detector, contact "
                                   "model) in several variants and measure each variant's error against a "
                                   "reference computed in the same run; write bench_report.md, "
                                   "bench_pareto.png and bench_report.json. The full run takes a few minutes "
                                   "(set OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 on small machines).")
    p.add_argument("--out", default="bench-report", help="output folder (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="small sizes, fewer mesh sizes: a smoke run (~20 s)")
    p.add_argument("--kernels", type=_bench_kernels, default="all",
                   help="comma-separated subset of filters,estimator,detector,contact (default: all)")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("loop", help="the closed loop: design the default law, measure its envelope, pace it",
                       description="The stage loop on the 6-ridge FEM pad. 'design': the default law from the "
                                   "stage's data sheet, the pad's shear calibration and the sample rate (Bode "
                                   "plot, margins). 'envelope': gross slips and tracking error against peak finger "
                                   "speed for open loop, the paper's law and the default law (JSON + plot; an "
                                   "interrupted run resumes). 'realtime': the loop paced by the wall clock against a "
                                   "simulated finger on the pad (hardware in the loop without the hardware): tick "
                                   "times, overruns, gross slips (JSON, plot, recording).")
    lsub = p.add_subparsers(dest="loop_command", required=True, metavar="loop_command")
    for name, helptext, func in (("design", "design the default law and plot its loop", cmd_loop_design),
                                 ("envelope", "run the envelope (seeded paths per speed class)", cmd_loop_envelope),
                                 ("realtime", "pace the loop by the wall clock against the simulated pad",
                                  cmd_loop_realtime)):
        q = lsub.add_parser(name, help=helptext)
        q.add_argument("--out", default="loop-output", help="output folder (default: %(default)s)")
        q.add_argument("--v-max", type=_positive(float), default=30.0, help="stage speed limit, mm/s (default: 30)")
        q.add_argument("--a-max", type=_positive(float), default=1.0, help="stage acceleration limit, m/s^2 "
                       "(default: 1)")
        q.add_argument("--travel", type=_positive(float), default=20.0, help="stage travel each way, mm (default: 20)")
        q.add_argument("--delay", type=_positive(float, allow_zero=True), default=1.0,
                       help="stage command dead time, ms (default: 1)")
        q.add_argument("--lag", type=_positive(float, allow_zero=True), default=2.0,
                       help="stage servo time constant, ms (default: 2)")
        q.add_argument("--weights", default=None, help=_WEIGHTS_HELP % "paper, the loop experiment's")
        q.set_defaults(func=func)
        if name == "design":
            q.add_argument("--fs", type=_positive(float), default=1000.0, help="tick rate, Hz (default: 1000)")
            q.add_argument("--streaming", action="store_true",
                           help="the stage follows streamed set points (default: its move command plans a braking "
                                "move to each target at --a-max, and the command leads by the braking distance)")
            q.add_argument("--load-cell", action="store_true",
                           help="design for a load cell under the pad (MirrorPipeline(force_input=True)) instead of "
                                "the strips' shear signal; writes loop_design_load_cell.png/.json")
        elif name == "realtime":
            q.add_argument("--fs", type=_positive(float), default=1000.0, help="tick rate, Hz (default: 1000)")
            q.add_argument("--pad", choices=["realtime", "default"], default="realtime",
                           help="FemPad.realtime() (contact elements of 0.2 mm) or the default FEM pad "
                                "(default: %(default)s)")
            q.add_argument("--threads", type=int, choices=[1, 2], default=1, help="threads stepping the ridges "
                           "(default: 1)")
            q.add_argument("--law", choices=["default", "load cell", "open loop"], default="default",
                           help="the default law, the same law on a load cell under the pad, or the stage held "
                                "still (the pad's worst case) (default: %(default)s)")
            q.add_argument("--speed", type=_positive(float), default=5.0,
                           help="the finger's peak speed, mm/s (a report path; default: 5)")
            q.add_argument("--seed", type=_nonnegative_int, default=None, help="finger path seed (default: the first report seed)")
            q.add_argument("--duration", type=_positive(float), default=3.0, help="seconds, 0.5 s press included "
                           "(default: 3)")
        else:
            from tactile_mirror.lab.loop.envelope import CONDITIONS, DEFAULT_LAWS, LAWS

            q.add_argument("--speeds", type=_speeds_mm_s, default=[2.0, 5.0, 10.0, 20.0],
                           help="peak finger speeds of the classes, mm/s (default: 2,5,10,20)")
            q.add_argument("--seeds", type=_positive(int), default=10, help="paths per class (default: 10)")
            q.add_argument("--conditions", type=_names(list(CONDITIONS)), default=["nominal"],
                           help=f"comma-separated subset of: {', '.join(CONDITIONS).replace('%', '%%')} (default: nominal)")
            q.add_argument("--laws", type=_names(list(LAWS)), default=list(DEFAULT_LAWS),
                           help="comma-separated subset of: open loop,paper,default,load cell (the default law "
                                "on a load cell under the pad) (default: open loop,paper,default)")
            q.add_argument("--paths", choices=["report", "tuning", "report-fast", "tuning-fast", "report-fast2",
                                              "tuning-fast2"], default="report",
                           help="path set: a reported one or a disjoint tuning one; the -fast sets reach 0.5 m/s^2 "
                                "(default: %(default)s)")
            q.add_argument("--duration", type=_positive(float), default=3.0, help="seconds per run, 0.5 s press "
                           "included (default: 3)")
            q.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (CommandError, ValueError, TypeError, OSError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
