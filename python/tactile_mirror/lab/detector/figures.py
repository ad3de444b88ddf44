"""Figure 10 of the paper: detector outputs on the no-stop and stop-at-B scenes."""
from __future__ import annotations

import numpy as np

from tactile_mirror.checks import integer
from tactile_mirror.detector.data_prep import features_from_result, targets_from_result

__all__ = ["figure10", "figure10_data"]


def _check_ridge(ridge, result) -> None:
    """Refuse a ridge index the result has no ridge for (its ``features`` or ``v_out``
    give the ridges: ``(n_ridges, channels, n)``)."""
    ready = getattr(result, "features", None)
    shape = np.shape(ready if ready is not None else getattr(result, "v_out", None))
    if len(shape) == 3:
        integer(ridge, "ridge", 0, shape[0] - 1)
    else:  # (the shape itself is refused by features_from_result)
        integer(ridge, "ridge", 0)


def figure10_data(detector, result, ridge: int = 0, stops=None) -> dict:
    """The curves of one Figure 10 panel.

    Parameters
    ----------
    detector : SlipDetector
    result
        Simulation result of a paper scene (e.g. ``simulate(scenes.paper("fig8"))``).
    ridge : int
        Ridge whose strips and outputs are shown: ``0 <= ridge < n_ridges`` (TypeError /
        ValueError naming ``ridge`` otherwise, before the detector runs).
    stops : list of (float, float), optional
        Plate stops in s; default ``result.stops`` or ``result.scene.stops``.

    Returns
    -------
    dict
        ``t`` (s), ``d_rate`` (L - R feature 0/1), ``d_rate2`` (L - R feature 2/3),
        ``y_slip``, ``y_pred`` (of the ridge), ``slip_time`` (first gross slip of the
        ridge, s, or None), ``stops``, ``features`` kind.
    """
    _check_ridge(ridge, result)
    x = features_from_result(result, detector.features, estimator=detector.metadata.get("estimator"))
    ys, _, yp = detector.run(x, fs=result.fs)
    gross, _ = targets_from_result(result)
    g = gross[min(ridge, gross.shape[0] - 1)]
    on = np.flatnonzero(g >= 0.5)
    t = np.asarray(result.t, dtype=np.float64)
    if stops is None:
        stops = getattr(result, "stops", None) or getattr(getattr(result, "scene", None), "stops", None) or []
    return {
        "t": t,
        "d_rate": x[ridge, 0] - x[ridge, 1],
        "d_rate2": x[ridge, 2] - x[ridge, 3],
        "y_slip": ys[ridge],
        "y_pred": yp[ridge],
        "slip_time": float(t[on[0]]) if on.size else None,
        "stops": list(stops),
        "features": detector.features,
    }


def figure10(detector, result_a, result_b, stops_b=None, ridge: int = 0, fig=None):
    """Reproduce Figure 10 (a) no stop and (b) stop at B.

    Top: differential stress rate and 2nd-order stress rate (L - R); middle:
    ``y_slip`` with the 0.8 threshold; bottom: ``y_pred``. Gross slip is marked
    by a vertical line, stops are shaded.

    Returns
    -------
    matplotlib.figure.Figure
    """
    # (the data first: a refused ridge leaves no half-made figure behind)
    panels = [("(a)", figure10_data(detector, result_a, ridge)),
              ("(b)", figure10_data(detector, result_b, ridge, stops=stops_b))]
    if fig is None:
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=(10, 7))
    axes = fig.subplots(3, 2, sharex="col")
    units = ("Pa/s", "Pa/s$^2$") if panels[0][1]["features"] == "stress_rate" else ("V", "V")
    for col, (label, d) in enumerate(panels):
        a0, a1, a2 = axes[:, col]
        a0.plot(d["t"], d["d_rate"], color="C0", lw=1, label=r"$\Delta\dot\sigma$")
        a0.set_ylabel(rf"$\Delta\dot\sigma$ [{units[0]}]", color="C0")
        tw = a0.twinx()
        tw.plot(d["t"], d["d_rate2"], color="C1", lw=0.8, alpha=0.8)
        tw.set_ylabel(rf"$\Delta\ddot\sigma$ [{units[1]}]", color="C1")
        a1.plot(d["t"], d["y_slip"], color="k", lw=1)
        a1.axhline(detector.slip_threshold, color="r", ls="--", lw=0.8)
        a1.set_ylabel(r"$y_{slip}$")
        a1.set_ylim(-0.05, 1.05)
        a2.plot(d["t"], d["y_pred"], color="g", lw=1)
        a2.set_ylabel(r"$y_{pred}$")
        a2.set_ylim(-0.05, 1.05)
        a2.set_xlabel("t [s]")
        a0.set_title(f"{label} {'no stop' if col == 0 else 'stop at B'}")
        for ax in (a0, a1, a2):
            if d["slip_time"] is not None:
                ax.axvline(d["slip_time"], color="r", lw=0.8, alpha=0.6)
            for s0, s1 in d["stops"]:
                ax.axvspan(s0, s1, color="0.85", zorder=0)
    fig.tight_layout()
    return fig
