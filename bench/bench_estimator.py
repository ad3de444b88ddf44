"""Stress-rate estimation: error against the true derivatives, and run time.

A load with analytic derivatives (quintic loading, a ramp, a 50 ms stop, a slip
with a 10 ms drop and a 20 ms rebound; 2 s) runs through the default PVDF circuit
(``PVDFCircuit.simulate``, sensor noise on ``v_out`` and ``u_out``); the
estimator turns the sampled outputs back into stress rate and 2nd-order stress
rate, which are compared with the true derivatives of the load.

Columns:

- ``rate err``, ``rate2 err``: rms(estimate - truth) / rms(truth), mean over the
  noise seeds;
- ``rate err, aligned``, ``rate2 err, aligned``: the same after shifting the estimate by
  the whole number of samples that minimises it (how much of the error is the filter's
  delay);
- ``delay``: group delay of the low-pass at low frequency, ms;
- ``ns/sample/ch``: ``StressRateEstimator.process`` on a (12, 100000) block, both
  outputs, best of 5;
- ``step us``: one ``StressRateEstimator.step`` call from Python, 12 channels.

Signals and errors come from :mod:`tactile_mirror.lab.measure` (``estimator_signals``,
``estimator_errors``, ``lowpass_delay_ms``), as in ``tactile-mirror bench``.

Run: ``python bench/bench_estimator.py`` (options: ``--fs``, ``--noise``, ``--kind``,
``--seeds``; ``--quick``: one seed and short timing runs, a smoke run of a few seconds).
``main`` returns the smallest ``rate err`` of the table.
"""
from __future__ import annotations

import argparse

import numpy as np
from common import best_time, environment_line
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator, estimate_stress_rate
from tactile_mirror.lab.measure import estimator_errors, estimator_signals, lowpass_delay_ms


def timing(circuit, fs, order, bandwidth, use_u, kind, channels=12, n=100_000, reps=2000):
    rng = np.random.default_rng(0)
    v = rng.normal(0, 0.05, (channels, n))
    u = rng.normal(0, 0.05, (channels, n)) if use_u else None
    est = StressRateEstimator(circuit, fs, channels, order=order, bandwidth=bandwidth, use_u=use_u, kind=kind)
    best = best_time(lambda: (est.reset(), est.process(v, u)), 5)
    vs = v[:, 0].copy()
    us = u[:, 0].copy() if use_u else None

    def steps():
        for _ in range(reps):
            est.step(vs, us)

    best_step = best_time(steps, 3) / reps
    return 1e9 * best / (channels * n), 1e6 * best_step


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fs", type=float, default=1000.0, help="sample rate, Hz (default 1000)")
    ap.add_argument("--noise", type=float, default=1e-3, help="sensor noise, V rms (default 1e-3)")
    ap.add_argument("--kind", choices=["butter", "bessel"], default="butter")
    ap.add_argument("--seeds", type=int, default=None, help="noise realisations (default 5; --quick: 1)")
    ap.add_argument("--quick", action="store_true", help="one seed, short timing runs (a smoke run)")
    args = ap.parse_args(argv)
    fs = args.fs
    if args.seeds is None:
        args.seeds = 1 if args.quick else 5
    sizes = {"n": 5_000, "reps": 100} if args.quick else {}

    c = PVDFCircuit()
    runs = [estimator_signals(c, fs, 2.0, args.noise, channels=1, seed=seed)[:2] for seed in range(args.seeds)]
    v0, u0, d, d2 = estimator_signals(c, fs, 2.0, 0.0, channels=1)

    print(f"# Stress-rate estimation: fs = {fs:g} Hz, sensor noise {args.noise * 1e3:g} mV rms "
          f"(v_out peak {np.abs(v0).max() * 1e3:.0f} mV, u_out peak {np.abs(u0).max() * 1e3:.0f} mV), "
          f"{args.seeds} seeds, {args.kind} low-pass")
    print(f"# {environment_line()}")
    print(f"# circuit: fc = {c.fc:.1f} Hz, fd = {c.fd:.0f} Hz, tau_d = {c.tau_d * 1e3:g} ms; "
          f"load rms rate {np.sqrt(np.mean(d**2)):.3g} Pa/s, rms 2nd-order rate {np.sqrt(np.mean(d2**2)):.3g} Pa/s^2")
    print()
    print("| 2nd-order rate from | order | bandwidth (Hz) | rate err | rate2 err | rate err, aligned "
          "| rate2 err, aligned | delay (ms) | ns/sample/ch | step us |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    bandwidths = [bw for bw in (50.0, 100.0, 200.0, 300.0) if bw < 0.45 * fs]
    best = np.inf
    for use_u in (True, False):
        for order in ((2, 3, 4) if use_u else (1, 2, 3, 4)):
            for bw in bandwidths:
                e1, e2, ea, ea2 = [], [], [], []
                for v, u in runs:
                    r, r2 = estimate_stress_rate(v, u if use_u else None, c, fs, order=order, bandwidth=bw,
                                                 kind=args.kind)
                    err = estimator_errors(r, r2, d, d2, aligned=True)
                    e1.append(err["rate"])
                    e2.append(err["rate2"])
                    ea.append(err["rate_aligned"])
                    ea2.append(err["rate2_aligned"])
                ns, step_us = timing(c, fs, order, bw, use_u, args.kind, **sizes)
                best = min(best, float(np.mean(e1)))
                print(f"| {'u_out' if use_u else 'differentiator'} | {order} | {bw:g} | {np.mean(e1):.3f} "
                      f"| {np.mean(e2):.3f} | {np.mean(ea):.3f} | {np.mean(ea2):.3f} | {lowpass_delay_ms(order, bw, fs, args.kind):.2f} "
                      f"| {ns:.2f} | {step_us:.2f} |")
    return best


if __name__ == "__main__":
    main()
