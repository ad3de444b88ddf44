"""Figure files: checked before the work they show, written atomically (matplotlib)."""
from __future__ import annotations

import os

from tactile_mirror.files import atomic_write, check_writable

__all__ = ["check_figure_path", "save_figure"]


def check_figure_path(path, *, make_folder: bool = False) -> None:
    """:func:`check_writable`, and that matplotlib can write the format the suffix names
    (raise ValueError now, not after the work the figure shows)."""
    check_writable(path, make_folder=make_folder)
    suffix = os.path.splitext(os.fspath(path))[1].lstrip(".").lower()
    if suffix:
        from matplotlib.backend_bases import FigureCanvasBase

        formats = FigureCanvasBase.get_supported_filetypes()
        if suffix not in formats:
            raise ValueError(f"{os.fspath(path)!r}: matplotlib cannot write '.{suffix}' figures; use one of "
                             f"{', '.join('.' + f for f in sorted(formats))}")


def save_figure(fig, path, **savefig_kwargs) -> None:
    """``fig.savefig`` to ``path`` atomically; the format comes from the suffix (or ``format=``)."""
    fmt = savefig_kwargs.pop("format", None)
    if fmt is None:
        suffix = os.path.splitext(os.fspath(path))[1].lstrip(".").lower()
        fmt = suffix or None  # matplotlib's default format
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format=fmt, **savefig_kwargs)
