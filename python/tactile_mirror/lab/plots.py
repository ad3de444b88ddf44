"""Figures in the paper's style: stacked time series on a shared time axis, units on
the axes, the gross-slip time marked.

Every function takes a result and returns a matplotlib ``Figure``; ``save`` writes it.
:func:`pareto_figure` draws the run-time-against-error report of ``tactile-mirror bench``
(its labels placed by :func:`place_labels`).
matplotlib is imported lazily (the Agg backend works without a screen).
"""
from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from tactile_mirror.contact import SimulationResult
    from tactile_mirror.lab.benchmark import BenchReport, KernelReport

__all__ = ["contact_scene_figure", "pareto_figure", "place_labels", "save"]


def _figure(n_rows: int, height: float = 1.6, width: float = 6.4):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(n_rows, 1, sharex=True, figsize=(width, height * n_rows + 0.6),
                             constrained_layout=True)
    return fig, np.atleast_1d(axes)


def _mark_slip(axes, slip_time, label=True):
    if slip_time is None:
        return
    for k, ax in enumerate(axes):
        ax.axvline(slip_time, color="crimson", lw=0.9, ls="--")
        if label and k == 0:
            ax.annotate("slip", xy=(slip_time, 1.0), xycoords=("data", "axes fraction"),
                        xytext=(4, -12), textcoords="offset points", color="crimson", fontsize=8)


def _shade_stops(axes, stops):
    for a, b in stops:
        for ax in axes:
            ax.axvspan(a, b, color="0.85", lw=0)


def contact_scene_figure(result: SimulationResult, ridge: int = 0, title: str | None = None,
                         estimator_order: int = 2, estimator_bandwidth: float = 100.0) -> Figure:
    """The paper's Figs. 6-8: plate motion, ``d/dt (sigma_L - sigma_R)`` and its
    derivative as the PVDF sensors and the stress-rate estimator see them, and the
    share of the contact slipping.

    The stress rates are those of the strip's equivalent load (the stress that makes
    the same charge; see :mod:`tactile_mirror.circuit`), estimated from ``v_out`` and
    ``u_out`` with :func:`tactile_mirror.estimate_stress_rate`.

    ``ridge`` is the index of the ridge shown, ``0 <= ridge < n_ridges`` (TypeError /
    ValueError naming it otherwise; a negative index is no ridge).
    """
    from tactile_mirror.checks import integer
    from tactile_mirror.estimator import estimate_stress_rate

    if result.v_out is None or result.slip_fraction is None:
        raise ValueError("result must include the 'signals' and 'slip' outputs")
    integer(ridge, "ridge", 0, np.shape(result.v_out)[0] - 1)
    scene = result.scene
    rate, rate2 = estimate_stress_rate(result.v_out[ridge], result.u_out[ridge], scene.circuit, result.fs,
                                       order=estimator_order, bandwidth=estimator_bandwidth)
    t = result.t
    fig, ax = _figure(4)
    _shade_stops(ax, scene.stops)
    ax[0].plot(t, result.plate_y * 1e3, label="y (slide)")
    ax[0].plot(t, result.indent * 1e3, label="z (indent)")
    ax[0].set_ylabel("plate [mm]")
    ax[0].legend(loc="upper left", fontsize=7, frameon=False)
    ax[1].plot(t, (rate[0] - rate[1]) / 1e3, color="k", lw=0.9)
    ax[1].set_ylabel(r"$\Delta\dot\sigma$ [kPa/s]")
    ax[2].plot(t, (rate2[0] - rate2[1]) / 1e6, color="k", lw=0.9)
    ax[2].set_ylabel(r"$\Delta\ddot\sigma$ [MPa/s$^2$]")
    ax[3].plot(t, result.slip_fraction[ridge], color="tab:red", lw=0.9)
    ax[3].set_ylabel("slipping\ncontact [-]")
    ax[3].set_ylim(-0.05, 1.05)
    ax[3].set_xlabel("time [s]")
    _mark_slip(ax, result.slip_time)
    for a in ax:
        a.grid(True, lw=0.3, alpha=0.5)
    if title:
        ax[0].set_title(title, fontsize=10)
    return fig


def save(fig: Figure, path: str | os.PathLike[str]) -> None:
    """Write a figure (format from the file name) and close it.

    The folder is created if missing. Atomic: the image is written beside ``path``
    and moved into place, so a failed save leaves a previous file intact.
    """
    import pathlib

    import matplotlib.pyplot as plt

    from tactile_mirror.lab.figure_files import save_figure

    p = pathlib.Path(path)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        save_figure(fig, p, dpi=130)
    finally:
        plt.close(fig)


# ---------------------------------------------------------------- run time against error
_PARETO_COLOR = "tab:blue"


def _plain(v, _pos=None) -> str:
    return f"{v:g}"


def _plain_log_axis(axis, lo: float, hi: float, suffix: str = "") -> None:
    """Plain numbers on a log axis; minor ticks labelled at 2, 3, 5 (2 and 5 over 2-3 decades)."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    axis.set_major_formatter(FuncFormatter(lambda v, _p: f"{v:g}{suffix}"))
    if hi / lo < 1000:
        marks = (2, 3, 5) if hi / lo < 100 else (2, 5)

        def minor(v, _p):
            if v <= 0:
                return ""
            m = v / 10 ** math.floor(math.log10(v) + 1e-9)
            return f"{v:g}{suffix}" if any(abs(m - k) < 1e-6 for k in marks) else ""

        axis.set_minor_formatter(FuncFormatter(minor))
    else:
        axis.set_minor_formatter(NullFormatter())


def _pareto_panel(ax, k: KernelReport) -> tuple[list, list]:
    """Draw one kernel; return the points to label, (x, y, text, pareto), and every marker, (x, y)."""
    errs = np.array([v.error for v in k.variants])
    times = np.array([v.seconds for v in k.variants]) * k.time_scale
    errs = np.maximum(errs, np.finfo(np.float64).tiny)  # an exact match has no place on a log axis
    pareto = np.array([v.pareto for v in k.variants])
    ax.set_xscale("log")
    ax.set_yscale("log")
    for r in k.references:
        if r.error is None:
            y = r.seconds * k.time_scale
            ax.axhline(y, color="0.45", ls="--", lw=1)
            ax.annotate(r.label, (0.01, y), xycoords=("axes fraction", "data"), xytext=(0, 3),
                        textcoords="offset points", fontsize=7.5, color="0.3", va="bottom")
    speed_refs = [r for r in k.references if r.error is not None]
    if speed_refs:
        ax.scatter([r.error for r in speed_refs], [r.seconds * k.time_scale for r in speed_refs], marker="x",
                   color="0.6", s=22, lw=1, label=k.ratio_reference.split(",")[0] + " (same sections)", zorder=2)
    if np.any(~pareto):
        ax.scatter(errs[~pareto], times[~pareto], facecolors="none", edgecolors="0.45", s=36, zorder=3,
                   label="dominated")
    ax.scatter(errs[pareto], times[pareto], color=_PARETO_COLOR, s=48, zorder=4, label="Pareto-optimal")
    order = np.argsort(errs[pareto])
    pe, pt = errs[pareto][order], times[pareto][order]
    if pe.size > 1:
        ax.step(pe, pt, where="post", color=_PARETO_COLOR, lw=1, alpha=0.6, zorder=3)
    all_e = [*errs, *(r.error for r in speed_refs)]
    all_t = [*times, *(r.seconds * k.time_scale for r in k.references)]
    lo_x, hi_x = min(all_e), max(all_e)
    span_x = max(hi_x / lo_x, 10.0)
    ax.set_xlim(lo_x / span_x**0.08, hi_x * span_x**0.3)  # room for labels on the right
    lo_y, hi_y = min(all_t) / 1.6, max(all_t) * 1.8
    ax.set_ylim(lo_y, hi_y)
    _plain_log_axis(ax.yaxis, lo_y, hi_y)
    ax.set_xlabel(f"error: {k.error_name}")
    ax.set_ylabel(f"run time, {k.time_unit} per {k.unit}")
    ax.set_title(k.title, fontsize=9.5)
    ax.grid(True, which="major", alpha=0.3)
    if k.ratio_seconds is not None:
        r_s = k.ratio_seconds * k.time_scale
        sec = ax.secondary_yaxis("right", functions=(lambda y, r_s=r_s: r_s / np.maximum(y, 1e-300),
                                                     lambda q, r_s=r_s: r_s / np.maximum(q, 1e-300)))
        sec.set_ylabel("speed ratio to the reference", fontsize=8)
        _plain_log_axis(sec.yaxis, r_s / hi_y, r_s / lo_y, suffix="x")
    ax.legend(fontsize=7, loc="lower left")
    label_all = len(k.variants) <= 8
    items = [(e, t, v.label, v.pareto) for v, e, t in zip(k.variants, errs, times) if v.pareto or label_all]
    points = [*zip(errs, times), *((r.error, r.seconds * k.time_scale) for r in speed_refs)]
    return items, points


_OFFSETS = ((6, 3, "left", "bottom"), (6, -3, "left", "top"), (-6, 3, "right", "bottom"),
            (-6, -3, "right", "top"), (6, 12, "left", "bottom"), (6, -12, "left", "top"),
            (-6, 12, "right", "bottom"), (-6, -12, "right", "top"))


def place_labels(ax, items, points, renderer) -> None:
    """Label points where the text covers no other label, no other point and stays in the axes.

    ``items``: ``(x, y, text, highlighted)`` in data coordinates, labelled in this order
    (highlighted ones bold, in the Pareto colour); ``points``: every marker ``(x, y)``
    to keep clear; ``renderer``: the figure canvas's renderer (after the layout is
    final). Each label tries eight offsets around its point and keeps the first free
    one, else the first.
    """
    pts = ax.transData.transform(points) if points else np.zeros((0, 2))
    taken: list = []
    box = ax.get_window_extent(renderer)
    for x, y, text, pareto in items:
        own = ax.transData.transform([(x, y)])[0]
        kw = {"fontsize": 8 if pareto else 7, "color": _PARETO_COLOR if pareto else "0.3",
              "fontweight": "bold" if pareto else "normal", "zorder": 5}
        first = None
        for dx, dy, ha, va in _OFFSETS:
            ann = ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset points", ha=ha, va=va, **kw)
            bb = ann.get_window_extent(renderer)
            hits_point = any(bb.x0 - 4 < qx < bb.x1 + 4 and bb.y0 - 4 < qy < bb.y1 + 4
                             for qx, qy in pts if abs(qx - own[0]) + abs(qy - own[1]) > 0.5)
            inside = bb.x0 >= box.x0 and bb.x1 <= box.x1 and bb.y0 >= box.y0 and bb.y1 <= box.y1
            if inside and not hits_point and not any(bb.overlaps(o) for o in taken):
                taken.append(bb)
                if first is not None:
                    first.remove()
                break
            if first is None:
                first = ann
            else:
                ann.remove()
        else:  # nowhere free: keep the first position
            if first is not None:
                taken.append(first.get_window_extent(renderer))


def pareto_figure(report: BenchReport) -> Figure:
    """Run time against error of a :class:`~tactile_mirror.lab.benchmark.BenchReport`: one
    panel per kernel, log scales, Pareto-optimal variants filled and labelled."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    ks = list(report.kernels.values())
    ncols = 1 if len(ks) == 1 else 2
    nrows = math.ceil(len(ks) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(7.2 * ncols, 5.4 * nrows), squeeze=False)
    labels = [_pareto_panel(ax, k) for ax, k in zip(axes.ravel(), ks)]
    for ax in axes.ravel()[len(ks):]:
        ax.set_visible(False)
    fig.suptitle(f"Run time against error ({'quick' if report.quick else 'full'} run, "
                 f"{report.environment['machine']}, SIMD {report.environment['simd_path']}); "
                 "filled: Pareto-optimal", fontsize=11)
    fig.tight_layout()
    renderer = fig.canvas.get_renderer()
    for ax, (items, points) in zip(axes.ravel(), labels):
        place_labels(ax, items, points, renderer)
    return fig
