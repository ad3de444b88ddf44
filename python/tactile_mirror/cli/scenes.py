"""The scene commands: ``demo`` (the paper's scenes, figures and a summary), ``simulate``
(one contact scene to .npz) and ``figure`` (a paper figure: 6, 7, 8, 10, 12, 13)."""
from __future__ import annotations

import pathlib
import time

from tactile_mirror.cli.arguments import (
    WEIGHTS_HELP,
    add_command,
    load_detector,
    nonnegative_int,
    out_folder,
    positive,
)

__all__ = ["PAPER_SCENES", "add_parser", "cmd_demo", "cmd_figure", "cmd_simulate", "scene_from_args"]

#: The paper's contact scenes (``scenes.paper(name)``) and how the plate moves in each.
PAPER_SCENES = {"fig6": "no stop", "fig7": "stop at A (1.00-1.05 s)", "fig8": "stop at B (1.40-1.45 s)"}


def scene_from_args(args):
    """The :class:`~tactile_mirror.scenes.Scene` of ``simulate``'s arguments: the paper scene
    ``--scene`` with the options given, or for ``random`` one random scene (seed ``--seed``)
    with the options given as fixed values."""
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


def _contact_figure(result, name, path):
    from tactile_mirror.lab.plots import contact_scene_figure, save

    slip = f"gross slip at {result.slip_time:.3f} s" if result.slip_time is not None else "no gross slip"
    title = f"{name}: {PAPER_SCENES.get(name, 'scene')}; {slip}"
    save(contact_scene_figure(result, title=title), path)


# ---------------------------------------------------------------- subcommands
def cmd_simulate(args) -> int:
    """``tactile-mirror simulate``: one contact scene to ``--out`` (.npz), a figure if asked.
    Returns the exit status."""
    import numpy as np

    from tactile_mirror import simulate
    from tactile_mirror.files import check_writable, save_npz
    from tactile_mirror.lab.figure_files import check_figure_path

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
    """``tactile-mirror demo``: the paper's scenes, the detector on them, the open and closed
    loop; a summary on stdout and the figures in ``--out``. Returns the exit status."""
    from tqdm.auto import tqdm

    from tactile_mirror import scenes, simd_path, simulate_many

    out = out_folder(args.out)  # fail before the work, not after
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


def cmd_figure(args) -> int:
    """``tactile-mirror figure N``: the paper's figure N as a PNG in ``--out``. Returns the exit
    status."""
    from tactile_mirror import scenes, simulate

    out = out_folder(args.out)
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


def add_parser(sub) -> None:
    """Add ``demo``, ``simulate`` and ``figure`` to the ``tactile-mirror`` subcommands ``sub``."""
    from tactile_mirror.scenes import DEFAULT_FRICTION

    p = add_command(sub, "demo", cmd_demo, help="the paper's scenes on the bundled defaults: summary and figures",
                    description="Simulate the paper's three contact scenes (Figs. 6-8), run the bundled "
                                "slip detector on them (Fig. 10), run a finger on the 6-ridge pad open and "
                                "closed loop (Figs. 12, 13), print a summary and write the figures.")
    p.add_argument("--out", default="tactile-mirror-output", help="output folder (default: %(default)s)")

    p = add_command(sub, "simulate", cmd_simulate, help="simulate one contact scene",
                    description="Simulate a contact scene "
                                "and save its signals (t, stress, v_out, u_out, slip_fraction, forces) as .npz.")
    p.add_argument("--scene", choices=[*PAPER_SCENES, "random"], default="fig6",
                   help="paper scene or a random one (default: %(default)s)")
    p.add_argument("--friction", type=positive(float), default=None,
                   help=f"static friction coefficient (default: {DEFAULT_FRICTION:g})")
    p.add_argument("--duration", type=positive(float), default=None, help="seconds (default: 2.0)")
    p.add_argument("--ridges", type=positive(int), default=1, help="ridges in the pad (default: 1)")
    p.add_argument("--noise", type=float, default=0.0, help="sensor noise, V rms (default: 0)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="noise / random-scene seed (default: 0)")
    p.add_argument("--out", default="scene.npz",
                   help="output file, npz format, written as named (default: %(default)s)")
    p.add_argument("--figure", default=None, help="also write the Figs. 6-8 style plot to this file")
    p.add_argument("--stepping", choices=["auto", "every"], default="auto",
                   help="contact stepping: 'auto' solves at contact events only, 'every' at every sample "
                        "(the reference; same results to round-off) (default: %(default)s)")

    p = add_command(sub, "figure", cmd_figure, help="reproduce a figure of the paper",
                    description="Reproduce one of the paper's figures as a PNG: 6, 7, 8 (contact "
                                "signals), 10 (the slip detector on the fig6 and fig8 scenes), 12 (a "
                                "finger on the 6-ridge pad, open loop) or 13 (the same finger, closed loop).")
    p.add_argument("number", type=int, choices=[6, 7, 8, 10, 12, 13], help="figure number")
    p.add_argument("--out", default="figures", help="output folder (default: %(default)s)")
    p.add_argument("--weights", default=None, help=WEIGHTS_HELP % "default; figures 12, 13: paper, the loop experiment's")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="figures 12, 13: finger path seed (default: 0)")
    p.add_argument("--law", default="velocity",
                   choices=["velocity", "paper", "velocity, y_pred ramp", "velocity, shear only"],
                   help="figure 13: stage controller (default: %(default)s)")
