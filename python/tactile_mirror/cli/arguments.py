"""What the command groups share: argument types, output-folder checks, the detector option.

Nothing here imports the lab or the runtime at import time (``tactile-mirror --help``
stays fast); the functions that need them import them when called.
"""
from __future__ import annotations

import argparse
import pathlib

__all__ = [
    "BUNDLED_NETS",
    "WEIGHTS_HELP",
    "CommandError",
    "UsageError",
    "add_command",
    "add_workers_options",
    "load_detector",
    "names",
    "nonnegative_int",
    "open_workers",
    "out_files",
    "out_folder",
    "positive",
]


class CommandError(Exception):
    """A failure to report as ``error: ...`` without a traceback (exit status 1)."""


class UsageError(Exception):
    """A bad argument found after parsing (by an options class, or two options that exclude
    each other): reported as argparse reports one, the command's usage line and
    ``error: <message>``, exit status 2, before any work."""


def add_command(subparsers, name: str, func, **kwargs) -> argparse.ArgumentParser:
    """Add the subcommand ``name`` to ``subparsers`` (``kwargs``: ``help``, ``description``,
    ... of ``add_parser``), run by ``func(args)`` (which returns the exit status).

    The parsed arguments also carry ``command_parser``, the subcommand's parser, which
    reports a :class:`UsageError` with the subcommand's own usage line. Returns that parser.
    """
    p = subparsers.add_parser(name, **kwargs)
    p.set_defaults(func=func, command_parser=p)
    return p


def positive(kind, allow_zero: bool = False):
    """An argparse ``type``: the text as ``kind`` (``int`` or ``float``), refused unless it is
    positive (non-negative with ``allow_zero``) with ``expected a <kind>, got '<text>'`` or
    ``must be positive, got '<text>'``."""
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
nonnegative_int = positive(int, allow_zero=True)


def names(choices):
    """An argparse ``type``: a comma-separated list of some of ``choices`` (at least one),
    returned as a list of str in the order given."""
    def parse(text):
        items = [x.strip() for x in text.split(",") if x.strip()]
        bad = [x for x in items if x not in choices]
        if bad or not items:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(choices)}, got {text!r}")
        return items

    return parse


def out_folder(path) -> pathlib.Path:
    """``--out`` as a folder, made now: a file there, or a folder that cannot be written,
    fails (:class:`CommandError`) before the work, not after it. Returns the folder's path."""
    import os

    out = pathlib.Path(path)
    if out.exists() and not out.is_dir():
        raise CommandError(f"--out {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise CommandError(f"--out {out} is not writable")
    return out


def out_files(path, *file_names) -> pathlib.Path:
    """:func:`out_folder`, and that each of the files ``file_names`` the command writes there
    can be written (not a folder, not read-only; a ``.png`` in a format matplotlib writes):
    checked before the work, not after it. Returns the folder's path."""
    from tactile_mirror.files import check_writable
    from tactile_mirror.lab.figure_files import check_figure_path

    out = out_folder(path)
    for name in file_names:
        (check_figure_path if name.endswith(".png") else check_writable)(out / name)
    return out


#: Names ``--weights`` takes for the bundled nets (``SlipDetector.<name>()``); a weights file
#: of one of these names is given as a path, e.g. ``./pad``.
BUNDLED_NETS = ("default", "paper", "bank", "early", "pad", "memory")
#: ``--weights``' help, with ``%s`` for what the command uses without it.
WEIGHTS_HELP = ("detector weights file, or a bundled net: " + ", ".join(BUNDLED_NETS) + " (default: %s)")


def load_detector(path):
    """The :class:`~tactile_mirror.detector.SlipDetector` that ``--weights`` names: the
    default net for None, a bundled net by its name (:data:`BUNDLED_NETS`), else the weights
    file at ``path``."""
    from tactile_mirror.detector import SlipDetector

    if path is None:
        return SlipDetector.default()
    if path in BUNDLED_NETS:
        return getattr(SlipDetector, path)()
    return SlipDetector.load(path)


def add_workers_options(parser, default: str = "in this process, one after the other") -> None:
    """Add ``--scheduler ADDRESS`` and ``--workers N`` (one or the other) to a command that
    runs a sweep: where its tasks run (:func:`open_workers`); ``default`` says, in the help,
    where they run without either."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--scheduler", metavar="ADDRESS", default=None,
                       help="run the tasks on the workers of the dask scheduler at ADDRESS, e.g. tcp://host:8786 "
                            "(needs dask.distributed and the same tactile-mirror on every worker; docs/cluster.md)")
    group.add_argument("--workers", metavar="N", type=positive(int), default=None,
                       help=f"run the tasks on N local worker processes (default: {default})")


def open_workers(args):
    """The executor of ``--scheduler`` / ``--workers`` (:func:`add_workers_options`), as a
    context manager closing it at the end: a dask client's executor, a pool of N local
    processes, or ``None`` (in this process); :func:`tactile_mirror.engine.open_executor`.
    :class:`CommandError` when ``--scheduler`` is given without dask.distributed installed."""
    import importlib.util

    from tactile_mirror.engine import open_executor

    if args.scheduler is not None and importlib.util.find_spec("distributed") is None:
        raise CommandError("--scheduler needs dask.distributed: pip install 'dask[distributed]'")
    return open_executor(args.scheduler, args.workers)
