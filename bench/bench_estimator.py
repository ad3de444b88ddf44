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

Run: ``python bench/bench_estimator.py`` (options: ``--fs``, ``--noise``, ``--kind``,
``--seeds``).
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.signal
import tactile_mirror
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator, estimate_stress_rate
from tactile_mirror.testing import known_load


def rel_rms(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))


def aligned(a, b, max_shift=30):
    return min(rel_rms(a[k:], b[: b.size - k]) for k in range(max_shift + 1))


def lowpass_delay_ms(order, bandwidth, fs, kind):
    if kind == "butter":
        b, a = scipy.signal.butter(order, bandwidth, fs=fs)
    else:
        b, a = scipy.signal.bessel(order, bandwidth, fs=fs, norm="mag")
    _, gd = scipy.signal.group_delay((b, a), w=[1.0], fs=fs)
    return 1e3 * gd[0] / fs


def timing(circuit, fs, order, bandwidth, use_u, kind, channels=12, n=100_000):
    rng = np.random.default_rng(0)
    v = rng.normal(0, 0.05, (channels, n))
    u = rng.normal(0, 0.05, (channels, n)) if use_u else None
    est = StressRateEstimator(circuit, fs, channels, order=order, bandwidth=bandwidth, use_u=use_u, kind=kind)
    best = np.inf
    for _ in range(5):
        est.reset()
        t0 = time.perf_counter()
        est.process(v, u)
        best = min(best, time.perf_counter() - t0)
    vs = v[:, 0].copy()
    us = u[:, 0].copy() if use_u else None
    reps = 2000
    best_step = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(reps):
            est.step(vs, us)
        best_step = min(best_step, (time.perf_counter() - t0) / reps)
    return 1e9 * best / (channels * n), 1e6 * best_step


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fs", type=float, default=1000.0, help="sample rate, Hz (default 1000)")
    ap.add_argument("--noise", type=float, default=1e-3, help="sensor noise, V rms (default 1e-3)")
    ap.add_argument("--kind", choices=["butter", "bessel"], default="butter")
    ap.add_argument("--seeds", type=int, default=5, help="noise realisations (default 5)")
    args = ap.parse_args(argv)
    fs = args.fs

    c = PVDFCircuit()
    t = np.arange(round(2.0 * fs)) / fs
    s, d, d2 = known_load(t)
    stress = np.zeros((3, t.size))
    stress[2] = s
    runs = [c.simulate(stress, fs, noise=args.noise, seed=seed) for seed in range(args.seeds)]
    v0, u0 = c.simulate(stress, fs)

    print(f"# Stress-rate estimation: fs = {fs:g} Hz, sensor noise {args.noise * 1e3:g} mV rms "
          f"(v_out peak {np.abs(v0).max() * 1e3:.0f} mV, u_out peak {np.abs(u0).max() * 1e3:.0f} mV), "
          f"{args.seeds} seeds, {args.kind} low-pass, SIMD path {tactile_mirror.simd_path()}")
    print(f"# circuit: fc = {c.fc:.1f} Hz, fd = {c.fd:.0f} Hz, tau_d = {c.tau_d * 1e3:g} ms; "
          f"load rms rate {np.sqrt(np.mean(d**2)):.3g} Pa/s, rms 2nd-order rate {np.sqrt(np.mean(d2**2)):.3g} Pa/s^2")
    print()
    print("| 2nd-order rate from | order | bandwidth (Hz) | rate err | rate2 err | rate err, aligned "
          "| rate2 err, aligned | delay (ms) | ns/sample/ch | step us |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    bandwidths = [bw for bw in (50.0, 100.0, 200.0, 300.0) if bw < 0.45 * fs]
    for use_u in (True, False):
        for order in ((2, 3, 4) if use_u else (1, 2, 3, 4)):
            for bw in bandwidths:
                e1, e2, ea, ea2 = [], [], [], []
                for v, u in runs:
                    r, r2 = estimate_stress_rate(v, u if use_u else None, c, fs, order=order, bandwidth=bw,
                                                 kind=args.kind)
                    e1.append(rel_rms(r, d))
                    e2.append(rel_rms(r2, d2))
                    ea.append(aligned(r, d))
                    ea2.append(aligned(r2, d2))
                ns, step_us = timing(c, fs, order, bw, use_u, args.kind)
                print(f"| {'u_out' if use_u else 'differentiator'} | {order} | {bw:g} | {np.mean(e1):.3f} "
                      f"| {np.mean(e2):.3f} | {np.mean(ea):.3f} | {np.mean(ea2):.3f} | {lowpass_delay_ms(order, bw, fs, args.kind):.2f} "
                      f"| {ns:.2f} | {step_us:.2f} |")


if __name__ == "__main__":
    main()
