"""The ``tactile-mirror`` command.

    tactile-mirror demo                       the paper's scenes, figures and a summary
    tactile-mirror simulate --scene fig8      one contact scene -> .npz (+ figure)
    tactile-mirror figure 6 --out figures/    a paper figure reproduction (6, 7, 8, 10, 12, 13)
    tactile-mirror train / evaluate           slip-detector training (and calibration) and evaluation
    tactile-mirror bench --out report/        run time against error of every kernel (table + plot)
    tactile-mirror loop design / envelope     the default loop law from a stage's data sheet; its envelope
    tactile-mirror loop realtime / experiment the loop paced by the wall clock; the paper's experiment
    tactile-mirror rig check / run            the mirror on a rig (or --simulate): connect; bring up and run

Every subcommand has ``--help``. Bad options print a message and exit with status 2;
errors while running print ``error: ...`` and exit with status 1. The sweeps (``train``,
``evaluate``, ``loop envelope``) run on N local worker processes with ``--workers N`` or on
a dask scheduler's workers with ``--scheduler ADDRESS``, with the same results.

Each command group is a module with an ``add_parser(subparsers)`` that adds its
subcommands: :mod:`.scenes` (demo, simulate, figure), :mod:`.detector` (train, evaluate),
:mod:`.bench` and :mod:`.loop` (design, envelope, realtime, experiment); :mod:`.arguments`
holds what they share. The group modules import the lab and the runtime inside their
command functions, so ``tactile-mirror --help`` stays fast.
"""
from __future__ import annotations

import argparse
import sys

from tactile_mirror.cli import bench, detector, loop, rig, scenes
from tactile_mirror.cli.arguments import BUNDLED_NETS, CommandError, UsageError, load_detector
from tactile_mirror.cli.detector import build_options_from_args
from tactile_mirror.cli.scenes import scene_from_args

__all__ = ["BUNDLED_NETS", "build_options_from_args", "build_parser", "load_detector", "main", "scene_from_args"]

#: The command groups, in the order ``tactile-mirror --help`` lists their subcommands.
GROUPS = (scenes, detector, bench, loop, rig)


def build_parser() -> argparse.ArgumentParser:
    """The ``tactile-mirror`` argument parser: every group's subcommands (:data:`GROUPS`)."""
    parser = argparse.ArgumentParser(prog="tactile-mirror",
                                     description="Closed-loop tactile displays that render static friction.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="command")
    for group in GROUPS:
        group.add_parser(sub)
    return parser


def main(argv=None) -> int:
    """Run ``tactile-mirror`` with the arguments ``argv`` (default: the command line's).

    Returns the exit status: 0, or 1 after ``error: ...`` on stderr for a failure while
    running. Bad arguments exit (``SystemExit``) with status 2 after the usage line.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except UsageError as exc:
        getattr(args, "command_parser", parser).error(str(exc))
    except (CommandError, ValueError, TypeError, OSError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
