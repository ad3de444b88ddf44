"""Figures in the paper's style: stacked time series on a shared time axis, units on
the axes, the gross-slip time marked.

Every function takes a result and returns a matplotlib ``Figure``; ``save`` writes it.
matplotlib is imported lazily (the Agg backend works without a screen).
"""
from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from .contact import SimulationResult

__all__ = ["contact_scene_figure", "save"]


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
    """
    from .estimator import estimate_stress_rate

    if result.v_out is None or result.slip_fraction is None:
        raise ValueError("result must include the 'signals' and 'slip' outputs")
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

    from ._io import save_figure

    p = pathlib.Path(path)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        save_figure(fig, p, dpi=130)
    finally:
        plt.close(fig)
