"""Figures of the closed loop: the paper's Fig. 12 (open loop) and Fig. 13 (closed loop)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tactile_mirror.checks import integer
from tactile_mirror.lab.figure_files import save_figure

if TYPE_CHECKING:
    from tactile_mirror.loop.scene import SceneResult

__all__ = ["design_figure", "loop_figure", "paced_figure"]

#: What the figures call each law of :func:`tactile_mirror.lab.loop.experiment.make_laws`.
LAW_TITLES = {"paper": "paper's law", "velocity": "shear loop with y_pred gain scheduling",
              "velocity, y_pred ramp": "velocity law, y_pred ramp only",
              "velocity, shear only": "shear loop without y_pred"}


def loop_figure(r: SceneResult, path, closed: bool, ridge: int = 0, law: str | None = None):
    """The paper's Fig. 12 (open loop) / Fig. 13 (closed loop) layout for one run.

    ``ridge`` is the ridge whose strip voltages are shown, ``0 <= ridge < n_ridges``
    (TypeError / ValueError naming it otherwise, before anything is drawn)."""
    R = r.log["v_out"].shape[0]
    integer(ridge, "ridge", 0, R - 1)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = r.t
    n = t.size
    y = r.outputs[:, 2:].reshape(n, R, 3)
    rows = 7 if closed else 6
    fig, ax = plt.subplots(rows, 1, figsize=(7, 1.45 * rows + 0.6), sharex=True)
    ax[0].plot(t, 1e3 * r.log["v_out"][ridge, 0, :n], lw=0.7, label="L")
    ax[0].plot(t, 1e3 * r.log["v_out"][ridge, 1, :n], lw=0.7, label="R")
    ax[0].set_ylabel("v_out\n(mV)")
    ax[0].legend(loc="upper right", fontsize=7, ncol=2)
    ax[1].plot(t, 1e3 * r.log["u_out"][ridge, 0, :n], lw=0.7)
    ax[1].plot(t, 1e3 * r.log["u_out"][ridge, 1, :n], lw=0.7)
    ax[1].set_ylabel("u_out\n(mV)")
    ax[2].plot(t, r.log["force_y"][:n], "k", lw=0.8)
    ax[2].set_ylabel("F_y (N)")
    ax[3].plot(t, r.log["force_z"][:n], "k", lw=0.8)
    ax[3].set_ylabel("F_z (N)")
    ax[3].set_ylim(0, 1.5 * max(r.log["force_z"].max(), 1e-6))
    ax[4].plot(t, y[:, :, 0].max(axis=1), "r", lw=0.8)
    ax[4].axhline(0.8, color="gray", ls="--", lw=0.6)
    ax[4].set_ylabel("y_slip")
    ax[4].set_ylim(-0.05, 1.05)
    gross = np.all(r.log["slip_fraction"][:, :n] >= 0.999, axis=0)
    for a in ax[4:6]:
        a.fill_between(t, 0, 1, where=gross, color="orange", alpha=0.25, lw=0, transform=a.get_xaxis_transform())
    ax[5].plot(t, y[:, :, 2].max(axis=1), "b", lw=0.8)
    ax[5].set_ylabel("y_pred")
    ax[5].set_ylim(-0.05, 1.05)
    if closed:
        ax[6].plot(t, 1e3 * r.finger, "k", lw=0.8, label="finger")
        ax[6].plot(t, 1e3 * r.stage, "g", lw=0.9, label="stage")
        ax[6].set_ylabel("y (mm)")
        ax[6].legend(loc="upper right", fontsize=7, ncol=2)
    ax[-1].set_xlabel("t (s)")
    law = LAW_TITLES.get(law or r.controller, law or r.controller)
    title = f"Fig. 13 (simulated): with feedback, {law}" if closed else "Fig. 12 (simulated): without feedback"
    fig.suptitle(f"{title}; seed {r.scene.seed}; gross slips: {r.gross_slips} (shaded)", fontsize=9)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)


def design_figure(design, path) -> None:
    """Bode plot of the designed shear loop (:class:`~tactile_mirror.loop.design.LoopDesign`) with
    its crossover and margins, and the predicted peak tracking error of sinusoidal finger
    motions against peak speed, one line per peak acceleration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = np.geomspace(0.1, 0.499 * design.fs, 800)
    L = design.loop(f)
    S = 1.0 / (1.0 + L)
    fig, axs = plt.subplots(1, 3, figsize=(13, 4))
    ax = axs[0]
    ax.loglog(f, np.abs(L), label="|L| (open loop)")
    ax.loglog(f, np.abs(S), label="|S| = |e / x_finger|")
    ax.axhline(1.0, color="k", lw=0.5)
    ax.axvline(design.crossover_hz, color="0.5", ls=":", lw=0.8)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("gain")
    ax.legend(fontsize=8)
    ax.set_title(f"crossover {design.crossover_hz:.1f} Hz, GM {design.gain_margin_db:.1f} dB, "
                 f"max|S| {design.max_sensitivity:.2f}", fontsize=9)
    ax = axs[1]
    ax.semilogx(f, np.degrees(np.unwrap(np.angle(L))))
    ax.axhline(-180, color="k", lw=0.5)
    ax.axvline(design.crossover_hz, color="0.5", ls=":", lw=0.8)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("phase of L (deg)")
    d = design.delays
    ax.set_title(f"PM {design.phase_margin_deg:.0f} deg; delays: stage {d['stage_dead_time'] * 1e3:g} + tick "
                 f"{d['command_tick'] * 1e3:g} + lag {d['stage_lag'] * 1e3:g} + "
                 f"{'load cell difference' if design.sensor == 'force' else 'estimator'} "
                 f"{d['estimator_group_delay'] * 1e3:.2f} ms", fontsize=8)
    ax = axs[2]
    v = np.geomspace(1e-3, 3e-2, 40)
    for a in (0.05, 0.1, 0.25, 0.5):
        ax.loglog(v * 1e3, [1e3 * design.sine_error(x, a) for x in v], label=f"{a:g} m/s$^2$")
    ax.loglog(v * 1e3, 1e3 * v / design.kp, "k--", lw=0.8, label="type-1 loop (v / Kp)")
    ax.set_xlabel("peak finger speed (mm/s)")
    ax.set_ylabel("predicted peak tracking error (mm)")
    ax.set_title(f"Kp {design.kp:.0f}/s, integral {design.z:.0f}/s, Kv {design.kv:.2f}: error = A / "
                 f"{design.acceleration_constant:.3g} s$^{{-2}}$", fontsize=8)
    ax.legend(fontsize=7, title="peak acceleration", title_fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def paced_figure(res, slip_fraction, fs: float, path, title: str) -> None:
    """A loop paced by the wall clock (``LoopRunner(realtime=True)``'s result ``res``):
    each tick's work against time with the deadline, gross slips (from ``slip_fraction``,
    (n_ridges, n)) marked; and the ticks' histogram."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tactile_mirror.loop.scene import gross_slip_starts

    us = res.tick_ns / 1e3
    period = 1e6 / fs
    fig, (ax_t, ax_h) = plt.subplots(1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [2.2, 1]})
    ax_t.plot(res.t, us, lw=0.6)
    ax_t.axhline(period, color="r", lw=1, label=f"one tick ({period:.0f} us)")
    starts = gross_slip_starts(slip_fraction)
    if starts.size:
        ax_t.plot(res.t[starts], us[starts], "kx", ms=7, label="gross slip starts")
    ax_t.set(xlabel="time (s)", ylabel="tick: plant + pipeline + stage (us)", yscale="log", title=title)
    ax_t.legend(fontsize=8)
    ax_h.hist(us, bins=np.logspace(np.log10(max(us.min(), 1.0)), np.log10(us.max() * 1.01), 40))
    ax_h.axvline(period, color="r", lw=1)
    ax_h.set(xscale="log", xlabel="tick (us)", ylabel="ticks",
             title=f"p99 {np.percentile(us, 99):.0f} us; {res.overruns} overruns, {res.late_starts} late starts")
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
