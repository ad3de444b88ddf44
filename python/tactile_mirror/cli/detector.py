"""The detector commands: ``train`` (simulate scenes, train, select and evaluate a slip
detector) and ``evaluate`` (a detector on held-out scenes)."""
from __future__ import annotations

import pathlib

from tactile_mirror.cli.arguments import (
    WEIGHTS_HELP,
    add_command,
    load_detector,
    nonnegative_int,
    positive,
)

__all__ = ["add_parser", "build_options_from_args", "cmd_evaluate", "cmd_train"]


def build_options_from_args(args):
    """The :class:`~tactile_mirror.lab.detector.build.BuildOptions` of ``tactile-mirror train``'s
    arguments (its defaults: the bundled detector's)."""
    from tactile_mirror.lab.detector.build import BuildOptions

    return BuildOptions(n_train=args.n_train, n_test=args.n_test, n_hidden=args.hidden, maxiter=args.maxiter,
                        candidates=args.candidates, n_validation=args.n_validation,
                        checkpoint_every=args.checkpoint_every)


def cmd_train(args) -> int:
    """``tactile-mirror train``: simulate the scene sets, train, select among the candidates,
    evaluate on the held-out scenes and write the weights to ``--out`` (the evaluation table
    on stdout). Returns the exit status."""
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
    """``tactile-mirror evaluate``: a detector on random held-out scenes; the evaluation table
    and the detection by onset kind on stdout. Returns the exit status."""
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


def add_parser(sub) -> None:
    """Add ``train`` and ``evaluate`` to the ``tactile-mirror`` subcommands ``sub``."""
    p = add_command(sub, "train", cmd_train, help="simulate scenes, train and evaluate a slip detector",
                    description="Simulate randomized training and held-out scenes, train the recurrent "
                                "detector (and the baselines), evaluate and save the weights.")
    p.add_argument("--out", default="detector.npz", help="weights file to write (default: %(default)s)")
    p.add_argument("--n-train", type=positive(int), default=64, help="training scenes (default: 64)")
    p.add_argument("--n-test", type=positive(int), default=200, help="held-out scenes (default: 200)")
    p.add_argument("--hidden", type=positive(int), default=16, help="hidden units (default: 16)")
    p.add_argument("--maxiter", type=positive(int), default=800, help="L-BFGS-B iterations (default: 800)")
    p.add_argument("--candidates", type=positive(int), default=4,
                   help="initial seeds to train from; the best on the validation scenes is kept (default: 4)")
    p.add_argument("--checkpoint-every", type=positive(int, allow_zero=True), default=25,
                   help="also score checkpoints every this many iterations (0: final weights only; default: 25)")
    p.add_argument("--n-validation", type=positive(int), default=120,
                   help="validation scenes for choosing among candidates (default: 120)")
    p.add_argument("--report", default=None, help="also write the evaluation report here")
    p.add_argument("--figure", default=None, help="also write Figure 10 here")

    p = add_command(sub, "evaluate", cmd_evaluate, help="evaluate a slip detector on held-out scenes",
                    description="Simulate randomized held-out scenes and report detection rate, false "
                                "alarms, latency and y_pred lead.")
    p.add_argument("--weights", default=None, help=WEIGHTS_HELP % "default")
    p.add_argument("--scenes", type=positive(int), default=20, help="held-out scenes (default: 20)")
    p.add_argument("--seed", type=nonnegative_int, default=None, help="scene seed (default: the held-out seed)")
