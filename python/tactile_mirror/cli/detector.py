"""The detector commands: ``train`` (simulate scenes, train, select, calibrate and evaluate a
slip detector; or calibrate a trained one anew) and ``evaluate`` (a detector on held-out scenes)."""
from __future__ import annotations

import pathlib

from tactile_mirror.cli.arguments import (
    WEIGHTS_HELP,
    UsageError,
    add_command,
    add_workers_options,
    load_detector,
    nonnegative_int,
    open_workers,
    positive,
)

__all__ = ["add_parser", "build_options_from_args", "calibration_goals", "cmd_evaluate", "cmd_train"]

#: ``train``'s option for each BuildOptions field (named in the messages of its errors).
_OPTIONS = {"n_train": "--n-train", "n_test": "--n-test", "n_hidden": "--hidden", "maxiter": "--maxiter",
            "study_sizes": "--study", "candidates": "--candidates", "n_extra_train": "--extra-train",
            "checkpoint_every": "--checkpoint-every", "noise_range": "--noise-range", "calibrate_fa": "--calibrate-fa",
            "calibrate_conditions": "--calibrate-goals / --calibrate-condition", "n_validation": "--n-validation",
            "bank": "--lp-taus / --abs-taus", "compress": "--compress", "kind": "--kind",
            "select_conditions": "--select-conditions", "select_fa": "--select-fa"}


def _option_error(exc: Exception) -> UsageError:
    """The usage error of a value BuildOptions refused, naming ``train``'s option for its field."""
    msg = str(exc)
    for field, option in _OPTIONS.items():
        if msg.startswith(field):
            return UsageError(f"argument {option}: {msg}")
    return UsageError(msg)


def _train_options(args) -> dict:
    """The training options of ``train``'s loss arguments over the bundled net's (checked here:
    the training would refuse them only after the scenes were simulated)."""
    from tactile_mirror.checks import real_number
    from tactile_mirror.lab.detector.build_options import TRAIN_OPTIONS

    options = dict(TRAIN_OPTIONS)
    for option, key, value in (("--negative-weight", "negative_weight", args.negative_weight),
                               ("--pred-weight", "pred_weight", args.pred_weight),
                               ("--onset-weight", "onset_weight", args.onset_weight)):
        if value is None:
            continue
        try:
            real_number(value, option, nonnegative=True)
        except ValueError as exc:
            raise UsageError(f"argument {exc}") from None
        if key != "onset_weight" or value:  # (no onset weight: none in the options)
            options[key] = float(value)
    if args.normalisation is not None:
        options["normalisation"] = args.normalisation
    return options


def _bank(args):
    """The filter bank of ``--lp-taus`` / ``--abs-taus`` (the default bank's other settings),
    or None for the default bank."""
    if args.lp_taus is None and args.abs_taus is None:
        return None
    from tactile_mirror.detector.bank import DEFAULT_BANK

    bank = dict(DEFAULT_BANK)
    if args.lp_taus is not None:
        bank["lp_taus"] = list(args.lp_taus)
    if args.abs_taus is not None:
        bank["abs_taus"] = list(args.abs_taus)
    return bank


def calibration_goals(args):
    """The false-alarm bound per sensor condition that ``train``'s ``--calibrate-goals FA_CLEAN
    FA_NOISY`` (FA_CLEAN noise-free, FA_NOISY in every noisy condition) or
    ``--calibrate-condition CONDITION FA`` (repeated) give: a dict of condition names
    (:data:`~tactile_mirror.lab.detector.evaluation.NOISE_CONDITIONS`) to rates in [0, 1),
    or None without either. :class:`~tactile_mirror.cli.arguments.UsageError` for an unknown
    or repeated condition, a bad rate, or the two options (or ``--calibrate-fa`` and
    ``--calibrate-condition``) together."""
    if args.calibrate_goals is not None and args.calibrate_condition:
        raise UsageError("--calibrate-goals and --calibrate-condition exclude each other")
    if args.calibrate_fa is not None and args.calibrate_condition:
        raise UsageError("--calibrate-fa and --calibrate-condition exclude each other")
    if args.calibrate_goals is None and not args.calibrate_condition:
        return None
    from tactile_mirror.lab.detector.evaluation import NOISE_CONDITIONS

    if args.calibrate_goals is not None:
        clean_fa, noisy_fa = args.calibrate_goals
        return {name: (clean_fa if name == "noise-free" else noisy_fa) for name in NOISE_CONDITIONS}
    goals = {}
    for name, fa in args.calibrate_condition:
        if name not in NOISE_CONDITIONS:
            raise UsageError(f"--calibrate-condition: unknown condition {name!r}; known: {sorted(NOISE_CONDITIONS)}")
        if name in goals:
            raise UsageError(f"--calibrate-condition: {name!r} given twice")
        try:
            rate = float(fa)
        except ValueError:
            rate = float("nan")
        if not 0.0 <= rate < 1.0:
            raise UsageError(f"--calibrate-condition {name!r}: the false-alarm rate must be a number in [0, 1), "
                             f"got {fa!r}")
        goals[name] = rate
    return goals


def build_options_from_args(args):
    """The :class:`~tactile_mirror.lab.detector.build_options.BuildOptions` of ``tactile-mirror
    train``'s arguments (its defaults: the bundled detector's). A value the options refuse is a
    :class:`~tactile_mirror.cli.arguments.UsageError` naming the option, before any work."""
    from tactile_mirror.lab.detector.build_options import BuildOptions

    train_options = _train_options(args)
    bank = _bank(args)
    goals = calibration_goals(args)
    extra = {} if args.noise_range is None else {"noise_range": tuple(args.noise_range)}
    try:
        return BuildOptions(n_train=args.n_train, n_test=args.n_test, n_hidden=args.hidden, maxiter=args.maxiter,
                            bank=bank, study_sizes=args.study or None, kind=args.kind, candidates=args.candidates,
                            n_extra_train=args.extra_train, checkpoint_every=args.checkpoint_every,
                            calibrate_fa=args.calibrate_fa, calibrate_conditions=goals,
                            n_validation=args.n_validation, compress=args.compress,
                            select_conditions=args.select_conditions, select_fa=args.select_fa,
                            train_options=train_options, **extra)
    except (TypeError, ValueError) as exc:
        raise _option_error(exc) from None


#: Where ``train`` and ``evaluate`` run their tasks without ``--scheduler`` or ``--workers``.
_SCENES_ON_CORES = "the scenes on a pool of this machine's cores, the rest in this process"


def _on(executor) -> dict:
    """``executor=`` for a lab function when ``--scheduler`` / ``--workers`` gave one (else its default)."""
    return {} if executor is None else {"executor": executor}


def _recalibrate(args) -> int:
    """``train --recalibrate WEIGHTS``: the net in WEIGHTS calibrated anew, written to ``--out``."""
    import json

    from tactile_mirror.files import check_writable
    from tactile_mirror.lab.detector.calibration import recalibrate

    goals = calibration_goals(args)
    if goals is None:
        raise UsageError("--recalibrate needs --calibrate-goals or --calibrate-condition")
    check_writable(args.out, make_folder=True)  # fail before the work, not after
    with open_workers(args) as executor:
        _w, info = recalibrate(args.recalibrate, args.out, goals, args.n_validation, args.n_test, args.cache,
                               **_on(executor))
    print(json.dumps(info, indent=1))
    print(f"wrote {args.out}")
    return 0


def cmd_train(args) -> int:
    """``tactile-mirror train``: simulate the scene sets, train, select among the candidates,
    calibrate if asked, evaluate on the held-out scenes and write the weights to ``--out``
    (the evaluation table, and the hidden-size study if asked, on stdout); with
    ``--recalibrate``, calibrate a trained net anew instead. ``--scheduler`` / ``--workers``:
    where the build's tasks run (the weights are the same bits). Returns the exit status."""
    from tactile_mirror.files import check_writable
    from tactile_mirror.lab.detector.build import build_default
    from tactile_mirror.lab.figure_files import check_figure_path

    if args.recalibrate is not None:
        return _recalibrate(args)
    options = build_options_from_args(args)  # bad combinations fail before any work
    out = pathlib.Path(args.out)
    for path in (out, args.report):  # fail before training, not after
        if path is not None:
            check_writable(path, make_folder=True)
    if args.figure is not None:
        check_figure_path(args.figure, make_folder=True)
    extra = {} if args.cache is None else {"cache_dir": args.cache}
    with open_workers(args) as executor:
        _, report = build_default(out, options, report_path=args.report, figure_path=args.figure, **extra,
                                  **_on(executor))
    print(report["evaluation_table"])
    for row in report.get("hidden_size_study", ()):
        print(row)
    print(f"wrote {out} ({report['total_seconds']:.0f} s)")
    return 0


def cmd_evaluate(args) -> int:
    """``tactile-mirror evaluate``: a detector on random held-out scenes; the evaluation table
    and the detection by onset kind on stdout. The scenes are simulated on ``--scheduler``'s
    or ``--workers``' workers if given, else on a pool of this machine's cores. Returns the
    exit status."""
    from tactile_mirror import simulate_many
    from tactile_mirror.lab.detector import evaluate
    from tactile_mirror.lab.detector.build_options import TEST_KWARGS, TEST_SEED
    from tactile_mirror.lab.detector.evaluation import detection_by_onset
    from tactile_mirror.scenes import random

    det = load_detector(args.weights)
    scenes = random(args.scenes, seed=TEST_SEED if args.seed is None else args.seed, **TEST_KWARGS)
    with open_workers(args) as executor:
        results = simulate_many(scenes, progress=True, **_on(executor))
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
                                "detector (and the baselines), evaluate and save the weights. With "
                                "--recalibrate, calibrate a trained net's decision point anew instead.")
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
    p.add_argument("--kind", default="jordan",
                   help="jordan: the paper's net; jordan_memory: the load-memory net; jordan_bank: the filter-bank "
                        "net (default: %(default)s)")
    p.add_argument("--study", type=positive(int), nargs="*",
                   help="hidden sizes to compare on the validation scenes (the report's hidden_size_study)")
    p.add_argument("--cache", default=None, help="folder keeping the simulated scenes between builds")
    p.add_argument("--extra-train", type=positive(int, allow_zero=True), default=0,
                   help="extra training scenes drawn from the held-out ranges, their own seed (default: 0)")
    p.add_argument("--negative-weight", type=float, default=None,
                   help="extra weight of the no-slip samples in the y_slip loss (default: the bundled nets')")
    p.add_argument("--pred-weight", type=float, default=None,
                   help="weight of the y_pred loss against the y_slip loss (default: the bundled nets')")
    p.add_argument("--onset-weight", type=float, default=0.0,
                   help="extra weight of the first 50 ms of every slip in the y_slip loss (0: none)")
    p.add_argument("--normalisation", default=None, choices=["rms", "median"],
                   help="input scale of the net (default: the bundled nets')")
    p.add_argument("--noise-range", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                   help="range of the training noise copies' sensor noise, V rms (default: the bundled nets')")
    p.add_argument("--lp-taus", type=float, nargs="+", default=None,
                   help="low-pass time constants of the jordan_bank filter bank, s (default: the default bank's)")
    p.add_argument("--abs-taus", type=float, nargs="*", default=None,
                   help="time constants of its shear-rate energy low-passes, s (none: no such channels)")
    p.add_argument("--compress", action="store_true",
                   help="jordan_bank: compress the bank's inputs to sign(x) log(1 + |x| / knee), the knees fitted "
                        "on the training inputs")
    p.add_argument("--select-conditions", nargs="+", default=None, metavar="CONDITION",
                   help="choose among the candidates in these sensor conditions (lab.detector.evaluation."
                        "NOISE_CONDITIONS, e.g. 'noise-free' '1 mV rms white') instead of in the validation scenes' "
                        "own noise")
    p.add_argument("--select-fa", type=float, default=None, metavar="FA",
                   help="the false-alarm rate at which the candidates' detection is compared (default: the "
                        "calibration's)")
    p.add_argument("--calibrate-fa", type=float, default=None, metavar="FA",
                   help="move y_slip's decision point to FA false alarms on the validation scenes (e.g. 0.02)")
    p.add_argument("--calibrate-goals", type=float, nargs=2, default=None, metavar=("FA_CLEAN", "FA_NOISY"),
                   help="instead: the decision point that keeps the validation scenes within FA_CLEAN false alarms "
                        "noise-free and FA_NOISY with 1 mV rms white noise and with the thermal floor + 2 mV hum "
                        "(notched), e.g. 0.015 0.025")
    p.add_argument("--calibrate-condition", nargs=2, action="append", default=None, metavar=("CONDITION", "FA"),
                   help="instead: the decision point for the named sensor condition(s) only (repeatable; one of "
                        "lab.detector.evaluation.NOISE_CONDITIONS, e.g. '1 mV rms white' 0.025): a net for a sensor "
                        "whose noise is known, not bound by the other conditions' false alarms")
    p.add_argument("--recalibrate", metavar="WEIGHTS", default=None,
                   help="do not train: calibrate the net in WEIGHTS anew (--calibrate-goals or "
                        "--calibrate-condition, on --n-validation scenes; its held-out record on --n-test scenes) "
                        "and write it to --out")
    add_workers_options(p, _SCENES_ON_CORES)

    p = add_command(sub, "evaluate", cmd_evaluate, help="evaluate a slip detector on held-out scenes",
                    description="Simulate randomized held-out scenes and report detection rate, false "
                                "alarms, latency and y_pred lead.")
    p.add_argument("--weights", default=None, help=WEIGHTS_HELP % "default")
    p.add_argument("--scenes", type=positive(int), default=20, help="held-out scenes (default: 20)")
    p.add_argument("--seed", type=nonnegative_int, default=None, help="scene seed (default: the held-out seed)")
    add_workers_options(p, _SCENES_ON_CORES)
