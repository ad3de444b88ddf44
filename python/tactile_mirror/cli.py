"""The ``tactile-mirror`` command.

    tactile-mirror demo                       the paper's scenes, figures and a summary
    tactile-mirror simulate --scene fig8      one contact scene -> .npz (+ figure)
    tactile-mirror figure 6 --out figures/    a paper figure reproduction

Every subcommand has ``--help``. Bad options print a message and exit with status 2;
errors while running print ``error: ...`` and exit with status 1.
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import time

PAPER_SCENES = {"fig6": "no stop", "fig7": "stop at A (1.00-1.05 s)", "fig8": "stop at B (1.40-1.45 s)"}


class CommandError(Exception):
    """A failure to report as ``error: ...`` without a traceback."""


def _positive(kind):
    def parse(text):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {kind.__name__}, got {text!r}") from None
        if not v > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
        return v

    return parse


def _scene_from_args(args):
    from . import scenes

    kw = {}
    if args.friction is not None:
        kw["friction"] = args.friction
    if args.duration is not None:
        kw["duration"] = args.duration
    kw["n_ridges"] = args.ridges
    kw["noise"] = args.noise
    kw["seed"] = args.seed
    if args.scene == "random":
        return scenes.random(1, seed=args.seed, **{k: v for k, v in kw.items() if k not in ("seed", "friction")})[0]
    return scenes.paper(args.scene, **kw)


def _contact_figure(result, name, path):
    from .plots import contact_scene_figure, save

    slip = f"gross slip at {result.slip_time:.3f} s" if result.slip_time is not None else "no gross slip"
    title = f"{name}: {PAPER_SCENES.get(name, 'scene')}; {slip}"
    save(contact_scene_figure(result, title=title), path)


# ---------------------------------------------------------------- subcommands
def cmd_simulate(args) -> int:
    import numpy as np

    from . import simulate

    scene = _scene_from_args(args)
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)  # fail before the work, not after
    t0 = time.perf_counter()
    res = simulate(scene, progress=True)
    np.savez_compressed(out, t=res.t, fs=res.fs, plate_y=res.plate_y, indent=res.indent, stress=res.stress,
                        v_out=res.v_out, u_out=res.u_out, slip_fraction=res.slip_fraction,
                        force_y=res.force_y, force_z=res.force_z,
                        slip_time=np.nan if res.slip_time is None else res.slip_time,
                        friction=scene.friction, n_ridges=scene.n_ridges)
    print(f"simulated {res.t.size} steps in {time.perf_counter() - t0:.2f} s; gross slip: "
          f"{'none' if res.slip_time is None else f'{res.slip_time:.3f} s'}; wrote {out}")
    if args.figure:
        _contact_figure(res, args.scene, args.figure)
        print(f"wrote {args.figure}")
    return 0


def cmd_figure(args) -> int:
    from . import scenes, simulate

    out = pathlib.Path(args.out)
    if args.number in (6, 7, 8):
        name = f"fig{args.number}"
        res = simulate(scenes.paper(name), progress=True)
        path = out / f"{name}.png"
        _contact_figure(res, name, path)
        print(f"wrote {path}")
        return 0
    raise CommandError(f"figure {args.number} is not available in this version (available: 6, 7, 8)")


def cmd_demo(args) -> int:
    from tqdm.auto import tqdm

    from . import scenes, simd_path, simulate_many

    out = pathlib.Path(args.out)
    t_start = time.perf_counter()
    print(f"tactile-mirror demo: C++ kernels on the {simd_path()} path; output folder {out}/")
    names = list(PAPER_SCENES)
    results = simulate_many([scenes.paper(n) for n in names], progress=True)
    rows = []
    for name, res in tqdm(list(zip(names, results)), desc="figures", unit="fig"):
        _contact_figure(res, name, out / f"{name}.png")
        rows.append((name, PAPER_SCENES[name], res.slip_time))
    print("\n| scene | plate motion | gross slip |")
    print("|---|---|---|")
    for name, what, ts in rows:
        print(f"| {name} | {what} | {'none' if ts is None else f'{ts:.3f} s'} |")
    print(f"\nfigures: {', '.join(str(out / f'{n}.png') for n in names)}")
    print(f"done in {time.perf_counter() - t_start:.1f} s")
    return 0


# ---------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tactile-mirror",
                                     description="Closed-loop tactile displays that render static friction.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="command")

    p = sub.add_parser("demo", help="the paper's scenes on the bundled defaults: summary and figures",
                       description="Simulate the paper's three contact scenes (Figs. 6-8), print a summary "
                                   "and write the figures.")
    p.add_argument("--out", default="tactile-mirror-output", help="output folder (default: %(default)s)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("simulate", help="simulate one contact scene", description="Simulate a contact scene "
                       "and save its signals (t, stress, v_out, u_out, slip_fraction, forces) as .npz.")
    p.add_argument("--scene", choices=[*PAPER_SCENES, "random"], default="fig6",
                   help="paper scene or a random one (default: %(default)s)")
    p.add_argument("--friction", type=_positive(float), default=None, help="Coulomb coefficient (default: 0.66)")
    p.add_argument("--duration", type=_positive(float), default=None, help="seconds (default: 2.0)")
    p.add_argument("--ridges", type=_positive(int), default=1, help="ridges in the pad (default: 1)")
    p.add_argument("--noise", type=float, default=0.0, help="sensor noise, V rms (default: 0)")
    p.add_argument("--seed", type=int, default=0, help="noise / random-scene seed (default: 0)")
    p.add_argument("--out", default="scene.npz", help="output .npz file (default: %(default)s)")
    p.add_argument("--figure", default=None, help="also write the Figs. 6-8 style plot to this file")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("figure", help="reproduce a figure of the paper",
                       description="Reproduce one of the paper's figures as a PNG.")
    p.add_argument("number", type=int, choices=[6, 7, 8], help="figure number")
    p.add_argument("--out", default="figures", help="output folder (default: %(default)s)")
    p.set_defaults(func=cmd_figure)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (CommandError, ValueError, TypeError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
