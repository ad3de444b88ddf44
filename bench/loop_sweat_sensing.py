"""Why the loop slips under sweat: a friction change moves the strips' shear signal as a
relative displacement does.

    python bench/loop_sweat_sensing.py                        # about 1 min on 2 cores
    python bench/loop_sweat_sensing.py --figure docs/figures/sweat_sensing.png
    python bench/loop_sweat_sensing.py --quick                # one drop, two offsets (a smoke run)

Two measurements on the 6-ridge FEM pad, the finger held still (no relative motion at all):

1. The pad held still, the finger resting at a shear offset ``d`` (0 to 40 um, reached in
   0.1 s after the 0.5 s press), friction ramped from the pad's 0.76 to ``mu`` over 0.2 s
   from 1.0 s. Printed: the calibrated shear signal (the loop's own: its calibration by
   ``calibrate_shear_weights`` and ``calibrate_shear``, its 1 s leak, tared after the press;
   um of relative displacement) before the drop, its largest move over the ramp and the 0.4 s
   after it, and its move by the end. A displacement sensor would read 0 um.
2. The same drop from 1.75 s, finger at rest for the whole 3 s, open loop and with the
   default law (``design_loop``, the envelope's stage): gross slips and the stage's
   largest excursion.
3. (``--common-mode``) The strips' common mode L + R as a second channel: its response per um
   of stuck relative displacement and per um of indent, and how much of the phantom of
   measurement 1 (the mean L - R change over ridges 0-2, in um of displacement) a linear
   prediction from the four combinations that a stuck displacement and the indent leave
   unmoved (the ridges' differences of L - R and of L + R: the printed sensitivities are
   equal from ridge to ridge) leaves, fitted on the drops to the first ``--mu`` and
   applied to the others.
4. (``--step-probe``) What the signal says of a real displacement after the drop: 0.4 s after
   the ramp, the relative displacement is moved by +``step`` and, in a second run, by -``step``
   (5 um over 50 ms, the pad moving, the finger still). Printed per um of the step: the part
   of the signal's move that changes sign with the step (its sensitivity to displacement; 1
   before the drop, by the calibration) and the part that does not (stored shear that any
   motion releases); then the same with the lower friction from the first contact on; and
   the same two parts of the pad's total tangential force (what a load cell under the pad
   reads), per um of displacement over the stuck contact's stiffness.

The shear offsets, the ramp and the friction values here are the envelope's sweat
conditions (mu 0.45 and 0.40) and not a tuning set: nothing is chosen from this output.
``main`` returns the largest move of the shear signal over the first drop, um (the phantom of
measurement 1, over all held offsets).
"""
from __future__ import annotations

import argparse

import numpy as np
import scipy.signal
from common import header, save_figure, table


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mu", default=None, help="friction after the drop (comma separated; default 0.45,0.40, "
                                               "--quick: 0.45)")
    ap.add_argument("--offsets", default=None,
                    help="shear offsets held during the drop, um (default 0,10,20,40,-20; --quick: 0,20)")
    ap.add_argument("--quick", action="store_true", help="one drop and two offsets (a smoke run)")
    ap.add_argument("--figure",
                    help="also write the figure (PNG): the signal's moves and the still finger's runs")
    ap.add_argument("--common-mode", action="store_true",
                    help="also measurement 3 (L + R as a second channel)")
    ap.add_argument("--step-probe", action="store_true",
                    help="also measurement 4 (a small pad step after the drop)")
    args = ap.parse_args(argv)
    if args.mu is None:
        args.mu = "0.45" if args.quick else "0.45,0.40"
    if args.offsets is None:
        args.offsets = "0,20" if args.quick else "0,10,20,40,-20"
    from tactile_mirror.lab.loop.envelope import law_controllers
    from tactile_mirror.lab.loop.experiment import default_weights, still_pad_features, weights_dict
    from tactile_mirror.loop.scene import LoopScene, run_scene
    from tactile_mirror.loop.stage import StageLimits

    header("Sweat and the shear signal: friction drops under a finger held still (6-ridge FEM pad)")
    fs, n_ridges, n0 = 1000.0, 6, 500
    mus = [float(m) for m in args.mu.split(",")]
    offsets = [float(d) * 1e-6 for d in args.offsets.split(",")]
    limits = StageLimits(-0.02, 0.02, 0.03, 1.0)
    w = weights_dict(default_weights("fem", fs))
    laws, design = law_controllers(w, fs, limits, 0.001, 0.002, n_ridges, "fem")
    c = design.shear_weights[:, 0]                    # per ridge, on L - R
    per_m = design.asym_per_m                         # the shear signal per metre
    tau = design.controller.asym_tau                  # its integrator's leak, s

    rows, traces, runs = [], {}, {}
    phantom = 0.0
    for mu in mus:
        for d in offsets:
            finger = np.zeros(1400)
            finger[n0:n0 + 101] = np.linspace(0.0, d, 101)
            finger[n0 + 101:] = d
            f = still_pad_features(w, finger, fs, n_ridges, "fem", mu_change=(1.0, mu, 0.2))
            # the loop's own shear signal: its leaky integral of the weighted L - R rates,
            # tared at the end of the press as the loop arms
            x = (f[:, :, 0] - f[:, :, 1]) @ c / per_m
            x[:n0] = 0.0
            shear = scipy.signal.lfilter([1.0 / fs], [1.0, -np.exp(-1.0 / (fs * tau))], x)
            move = shear[999:] - shear[999]
            traces[(mu, d)] = shear
            k = int(np.argmax(np.abs(move)))
            if mu == mus[0]:
                phantom = max(phantom, abs(float(move[k])) * 1e6)
            rows.append([f"{mu:.2f}", f"{d * 1e6:+.0f}", f"{shear[999] * 1e6:+.1f}",
                         f"{move[k] * 1e6:+.1f}", f"{move[-1] * 1e6:+.1f}"])
    table("Shear signal over a friction drop, finger and pad still (um; a displacement sensor reads 0)",
          ["mu after", "offset d", "signal before", "largest move", "move 0.4 s after the ramp"], rows)

    rows = []
    for mu in [None] + mus:
        sc = LoopScene(seed=0, duration=3.0, fs=fs, plant="fem", label="still finger",
                       mu_change=None if mu is None else (1.75, mu))
        for name in ("open loop", "default"):
            res = run_scene(sc, w, laws[name], limits=limits, n_ridges=n_ridges, finger=np.zeros(3000),
                            shear_weights=design.shear_weights if name == "default" else None)
            pad = res.log["pad"][: res.t.size]
            runs[(mu, name)] = res
            rows.append(["0.76 (no drop)" if mu is None else f"0.76 -> {mu:.2f}", name, res.gross_slips,
                         f"{np.abs(pad).max() * 1e6:.1f}"])
    table("Finger held still for 3 s, friction drop from 1.75 s over 0.2 s",
          ["friction", "law", "gross slips", "stage's largest excursion (um)"], rows)
    if args.figure:
        figure(args.figure, fs, traces, runs, mus)
    if args.common_mode:
        common_mode(mus, offsets)
    if args.step_probe:
        step_probe(mus, offsets, c, per_m)
    return phantom


def _strip_changes(n=1500, d=0.0, mu=None, move=0.0, dind=0.0):
    """Per tick from 0.99 s: the change of (L - R, L + R) of ridges 0-2 (their mirror
    images are equal), the FEM pad's finger pressed (0.5 s), moved to ``d`` (0.1 s), then
    from 1.0 s over 0.2 s: friction to ``mu``, or the finger by ``move``, or the indent by
    ``dind``."""
    from tactile_mirror.contact.plants import FemPad

    p = FemPad(6, fs=1000.0)
    indent0, mu0 = p.indent, p.mu
    out = np.empty((n, 3, 2))
    for k in range(n):
        ramp = min(1.0, max(0.0, (k - 1000) / 200))
        y = 0.0 if k < 500 else (d * min(1.0, (k - 500) / 100) + (move * ramp if k >= 1000 else 0.0))
        if mu is not None and 1000 <= k <= 1200:
            p.set_mu(mu0 + (mu - mu0) * ramp)
        if dind and k >= 1000:
            p.indent = indent0 + dind * ramp
        out[k] = p.advance(y).stress[:3]
    a = np.concatenate([out[..., 0] - out[..., 1], out[..., 0] + out[..., 1]], axis=1)
    return a[990:] - a[990]


def common_mode(mus, offsets) -> None:
    g = _strip_changes(move=5e-6)[-1] / 5.0        # per um of relative displacement
    h = _strip_changes(dind=3e-6)[-1] / 3.0        # per um of indent
    table("The strips' response per um (ridges 0-2; Pa)", ["what", "L - R", "L + R"],
          [[name, " / ".join(f"{v:.1f}" for v in r[:3]), " / ".join(f"{v:.1f}" for v in r[3:])]
           for name, r in (("relative displacement, stuck", g), ("indent", h))])

    def feats(a):
        D, S = a[:, :3], a[:, 3:]
        X = np.stack([D[:, 0] - D[:, 1], D[:, 1] - D[:, 2], S[:, 0] - S[:, 1], S[:, 1] - S[:, 2]], axis=1)
        return X, D.mean(axis=1) / g[:3].mean()    # the phantom in um of displacement

    ph = {(mu, d): feats(_strip_changes(d=d, mu=mu)) for mu in mus for d in offsets}
    fit = [v for (mu, _), v in ph.items() if mu == mus[0]]
    beta = np.linalg.lstsq(np.concatenate([X for X, _ in fit]), np.concatenate([y for _, y in fit]), rcond=None)[0]
    rows = [[f"{mu:.2f}" + (" (fitted)" if mu == mus[0] else ""), f"{d * 1e6:+.0f}", f"{np.abs(y).max():.0f}",
             f"{np.abs(y - X @ beta).max():.0f}"] for (mu, d), (X, y) in ph.items()]
    table("The phantom (um of displacement, largest over the ramp and 0.3 s after) and what a linear prediction "
          "from the combinations that a stuck displacement and the indent leave unmoved leaves",
          ["mu after", "offset d (um)", "phantom", "left after the prediction"], rows)


def step_probe(mus, offsets, c, per_m, step: float = 5e-6) -> None:
    """Measurement 4: the calibrated signal's answer to a +-``step`` pad displacement 0.4 s
    after the friction ramp (or at the same time with no drop)."""
    from tactile_mirror.contact.plants import FemPad

    def move(d, mu, sgn, start=False):
        p = FemPad(6, fs=1000.0)
        mu0 = p.mu
        if start:  # this friction from the first contact on: no drop under load
            p.set_mu(mu)
        sig, force = np.empty(1700), np.empty(1700)
        for k in range(sig.size):
            y = 0.0 if k < 500 else d * min(1.0, (k - 500) / 100)
            if mu is not None and not start and 1000 <= k <= 1200:
                p.set_mu(mu0 + (mu - mu0) * (k - 1000) / 200)
            if k >= 1600:
                y += sgn * step * min(1.0, (k - 1600) / 50)  # finger - pad moves by sgn * step
            state = p.advance(y)
            st = state.stress
            sig[k] = (st[:, 0] - st[:, 1]) @ c / per_m
            force[k] = state.force_y
        return (sig[-1] - sig[1599]) / step, (force[-1] - force[1599]) / step

    rows, k_t = [], None
    for mu, start in [(None, False)] + [(m, False) for m in mus] + [(m, True) for m in mus]:
        for d in offsets:
            (up, f_up), (down, f_down) = move(d, mu, 1.0, start), move(d, mu, -1.0, start)
            if k_t is None:
                k_t = (f_up - f_down) / 2  # the stuck contact's tangential stiffness, N/m
            name = "0.76 (no drop)" if mu is None else (f"{mu:.2f} from the start" if start else f"0.76 -> {mu:.2f}")
            rows.append([name, f"{d * 1e6:+.0f}", f"{(up - down) / 2:+.2f}", f"{(up + down) / 2:+.2f}",
                         f"{(f_up - f_down) / 2 / k_t:+.2f}", f"{(f_up + f_down) / 2 / k_t:+.3f}"])
    table(f"A +-{step * 1e6:g} um relative displacement 0.4 s after the drop, finger still: the shear signal's move "
          "per um of displacement (1 = the calibration's), and the pad's tangential force's (a load cell's; 1 = the "
          f"stuck contact's stiffness, {k_t / 1e3:.1f} N/mm)",
          ["friction", "offset d (um)", "signal: sensitivity (odd part)", "signal: released by any move (even part)",
           "force: sensitivity", "force: released"], rows)


def figure(path, fs, traces, runs, mus) -> None:
    """Left: the calibrated shear signal through the drop, pad and finger still, one line per
    held offset. Right: the stage under the still finger through the same drop, open loop and
    the default law, with the gross slips marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from tactile_mirror.loop.scene import gross_slip_starts

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    mu = mus[0]
    for (m, d), shear in traces.items():
        if m != mu:
            continue
        t = np.arange(shear.size) / fs
        ax1.plot(t, shear * 1e6, label=f"held at {d * 1e6:+.0f} um")
    ax1.axvspan(1.0, 1.2, color="0.85", label=f"friction 0.76 -> {mu:.2f}")
    ax1.set(xlabel="time (s)", ylabel="shear signal (um of relative displacement)", xlim=(0.5, 1.4),
            title="Finger and pad still: what the strips report")
    ax1.legend(fontsize=8)
    for (m, name), res in runs.items():
        if m is None or m == mus[-1] and len(mus) > 1:
            continue
        pad = res.log["pad"][: res.t.size] * 1e6
        line, = ax2.plot(res.t, pad, label=f"{name}, mu -> {m:.2f}: {res.gross_slips} gross slips")
        starts = gross_slip_starts(res.log["slip_fraction"][:, : res.t.size])
        ax2.plot(res.t[starts], pad[starts], "x", color=line.get_color(), ms=8)
    ax2.axvspan(1.75, 1.95, color="0.85")
    ax2.set(xlabel="time (s)", ylabel="stage position (um)", title="Finger held still: the loop follows the phantom")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
