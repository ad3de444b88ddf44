"""Why the loop slips under sweat: a friction change moves the strips' shear signal as a
relative displacement does.

    python bench/loop_sweat_sensing.py            # about 1 min on 2 cores

Two measurements on the 6-ridge FEM pad, the finger held still (no relative motion at all):

1. The pad held still, the finger resting at a shear offset ``d`` (0 to 40 um, reached in
   0.1 s after the 0.5 s press), friction ramped from the pad's 0.76 to ``mu`` over 0.2 s
   from 1.0 s. Printed: the calibrated shear signal's move over the ramp and the 0.4 s
   after it (the loop's own calibration: ``calibrate_shear_weights``, ``calibrate_shear``,
   um of relative displacement), the pad's lateral force before and after. A displacement
   sensor would read 0 um.
2. The same drop from 1.75 s, finger at rest for the whole 3 s, open loop and with the
   default law (``design_loop``, the envelope's stage): gross slips and the stage's
   largest excursion.

The shear offsets, the ramp and the friction values here are the envelope's sweat
conditions (mu 0.45 and 0.40) and not a tuning set: nothing is chosen from this output.
"""
from __future__ import annotations

import argparse

import numpy as np

from _common import header, table


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mu", default="0.45,0.40", help="friction after the drop (comma separated)")
    ap.add_argument("--offsets", default="0,10,20,40,-20", help="shear offsets held during the drop, um")
    args = ap.parse_args(argv)
    from tactile_mirror.loop.envelope import _laws
    from tactile_mirror.loop.experiment import _weights_dict, default_weights, still_pad_features
    from tactile_mirror.loop.scene import LoopScene, run_scene
    from tactile_mirror.loop.stage import StageLimits

    header("Sweat and the shear signal: friction drops under a finger held still (6-ridge FEM pad)")
    fs, n_ridges, n0 = 1000.0, 6, 500
    mus = [float(m) for m in args.mu.split(",")]
    offsets = [float(d) * 1e-6 for d in args.offsets.split(",")]
    limits = StageLimits(-0.02, 0.02, 0.03, 1.0)
    w = _weights_dict(default_weights("fem", fs))
    laws, design = _laws(w, fs, limits, 0.001, 0.002, n_ridges, "fem")
    c = design.shear_weights[:, 0]                    # per ridge, on L - R
    per_m = design.asym_per_m                         # the shear signal per metre

    rows = []
    for mu in mus:
        for d in offsets:
            finger = np.zeros(1400)
            finger[n0:n0 + 101] = np.linspace(0.0, d, 101)
            finger[n0 + 101:] = d
            f = still_pad_features(w, finger, fs, n_ridges, "fem", mu_change=(1.0, mu, 0.2))
            shear = np.cumsum(f[:, :, 0] - f[:, :, 1], axis=0) @ c / fs / per_m
            shear = shear - shear[n0 - 1]  # from the end of the press, as the loop arms
            move = shear[999:] - shear[999]
            k = int(np.argmax(np.abs(move)))
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
            rows.append(["0.76 (no drop)" if mu is None else f"0.76 -> {mu:.2f}", name, res.gross_slips,
                         f"{np.abs(pad).max() * 1e6:.1f}"])
    table("Finger held still for 3 s, friction drop from 1.75 s over 0.2 s",
          ["friction", "law", "gross slips", "stage's largest excursion (um)"], rows)


if __name__ == "__main__":
    main()
