"""Benchmarks of the SOS engine against scipy.signal, measured in the same run.

    python bench/bench_filters.py            # full run (~1-2 min)
    python bench/bench_filters.py --quick    # tiny sizes (a few seconds: a smoke run, not the figures)

Prints markdown tables: block throughput (ratio to scipy.signal.sosfilt), per-sample
step cost from Python and inside C++, the cost of a decay into the subnormal range,
a long soak against an extended-precision reference, and run time against error for
each structure and dtype (the filters kernel of ``tactile-mirror bench``, measured by
the same function, :func:`tactile_mirror.lab.measure.filter_variants`).
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import scipy.signal as ss
import tactile_mirror as tm
from common import best_time, header, table
from tactile_mirror.lab.measure import filter_variants


def bench_block(n, channels=12, n_cached=20_000, reps_cached=50):
    sos = ss.butter(8, 0.1, output="sos")  # 4 sections
    rng = np.random.default_rng(0)
    rows = []
    sizes = ((f"{n:.0e}".replace("e+0", "e") + " samples (out of cache)", n, 5),
             (f"{n_cached:.0e}".replace("e+0", "e") + " samples (in cache)", n_cached, reps_cached))
    for label, n_samples, reps in sizes:
        x = rng.standard_normal((channels, n_samples))
        for dt in (np.float64, np.float32):
            xx = x.astype(dt)
            s = sos.astype(dt)
            t_ref = best_time(lambda: ss.sosfilt(s, xx), reps)
            f = tm.SosFilter(sos, channels, dt)
            t_ours = best_time(lambda: f.process(xx), reps)
            t_fn = best_time(lambda: tm.sosfilt(s, xx), reps)
            m = channels * n_samples / 1e6
            rows.append([label, np.dtype(dt).name, f"{m / t_ref:.0f}", f"{m / t_ours:.0f}",
                         f"{t_ref / t_ours:.2f}x", f"{t_ref / t_fn:.2f}x"])
    table(f"Block filtering, {channels} channels x 4 sections (M channel-samples/s)",
          ["size", "dtype", "scipy sosfilt", "SosFilter.process", "speed-up", "tm.sosfilt speed-up"], rows)


def bench_step(channels=12, n=50_000, m=2000, n_cpp=1_000_000):
    sos = ss.butter(8, 0.1, output="sos")
    f = tm.SosFilter(sos, channels)
    sample = np.random.default_rng(1).standard_normal(channels)

    def ours():
        for _ in range(n):
            f.step(sample)

    t_ours = best_time(ours, 3) / n
    zi = np.zeros((sos.shape[0], channels, 2))
    col = sample[:, None]

    def ref():
        z = zi
        for _ in range(m):
            _, z = ss.sosfilt(sos, col, zi=z)

    t_ref = best_time(ref, 3) / m

    def cpp_step(dt, thread_ftz):
        return min(tm.SosFilter(sos, channels, dt).time_step(n_cpp, thread_ftz) for _ in range(3))

    cpp = {dt: [cpp_step(dt, False), cpp_step(dt, True)] for dt in (np.float64, np.float32)}
    table(f"Per-sample step, {channels} channels x 4 sections",
          ["path", "time per sample", "ratio to scipy (zi per call)"],
          [["scipy.signal.sosfilt with zi, from Python", f"{t_ref * 1e6:.2f} us", "1x"],
           ["SosFilter.step from Python (float64)", f"{t_ours * 1e6:.3f} us", f"{t_ref / t_ours:.0f}x"],
           ["C++ step, float64, MXCSR set per call", f"{cpp[np.float64][0]:.1f} ns", ""],
           ["C++ step, float64, thread FTZ set once", f"{cpp[np.float64][1]:.1f} ns", ""],
           ["C++ step, float32, MXCSR set per call", f"{cpp[np.float32][0]:.1f} ns", ""],
           ["C++ step, float32, thread FTZ set once", f"{cpp[np.float32][1]:.1f} ns", ""]])


def bench_subnormal(n):
    # A state starting just above the smallest normal number, decaying through
    # the subnormal range for the whole tail (pole radius 1 - 1e-5 in float64,
    # 1 - 1e-4 in float32: ~3.6e6 and ~1.6e5 samples of subnormal decay).
    rows = []
    for dt, r, z0 in ((np.float64, 1 - 1e-5, 1e-306), (np.float32, 1 - 1e-4, 1e-36)):
        sos = np.array([[1.0 - r, 0.0, 0.0, 1.0, -r, 0.0]] * 2)
        tail = np.zeros((12, n), dt)
        normal = np.random.default_rng(2).standard_normal((12, n)).astype(dt)
        zi = np.full((2, 12, 2), z0, dt)
        zi[:, :, 1] = 0.0

        f = tm.SosFilter(sos, 12, dt)
        t_tail = best_time(lambda: (f.reset(zi), f.process(tail)), 3)
        t_norm = best_time(lambda: (f.reset(), f.process(normal)), 3)
        s = sos.astype(dt)
        _, z_end = ss.sosfilt(s, tail, zi=zi)
        t_ref_tail = best_time(lambda: ss.sosfilt(s, tail, zi=zi), 3)
        t_ref_norm = best_time(lambda: ss.sosfilt(s, normal), 3)
        tiny = np.finfo(dt).tiny
        still_sub = bool(np.any((np.abs(z_end) > 0) & (np.abs(z_end) < tiny)))
        rows.append([np.dtype(dt).name, f"{still_sub}", f"{t_tail / t_norm:.2f}x", f"{t_ref_tail / t_ref_norm:.1f}x"])
    table(f"Decay through the subnormal range: time of a {n}-sample zero tail / time of normal input",
          ["dtype", "scipy state still subnormal at the end", "SosFilter", "scipy sosfilt"], rows)


def bench_soak(n_total, chunk=1_000_000):
    """Returns the float64 (tdf2) filter's largest error over the soak, relative to the peak."""
    r = 1.0 - 1e-6
    th = 2 * np.pi * 2e-5
    sos = np.array([[(1 - r) ** 2 * 4, 0.0, 0.0, 1.0, -2 * r * np.cos(th), r * r]])
    rng = np.random.default_rng(3)
    f64 = tm.SosFilter(sos, 1)
    f64d = tm.SosFilter(sos, 1, structure="delta")
    f32 = tm.SosFilter(sos, 1, np.float32)
    zref = np.zeros((1, 2), np.longdouble)
    sref = sos.astype(np.longdouble)
    worst64 = worst64d = worst32 = 0.0
    peak = 0.0
    first = last = None
    t_ours = 0.0
    t0_all = time.perf_counter()
    n_done = 0
    while n_done < n_total:
        x = rng.standard_normal(chunk)
        ref, zref = ss.sosfilt(sref, x.astype(np.longdouble), zi=zref)
        t0 = time.perf_counter()
        y64 = f64.process(x)
        t_ours += time.perf_counter() - t0
        y64d = f64d.process(x)
        y32 = f32.process(x.astype(np.float32))
        ref = ref.astype(np.float64)
        peak = max(peak, float(np.max(np.abs(ref))))
        e64 = float(np.max(np.abs(y64 - ref)))
        worst64 = max(worst64, e64)
        worst64d = max(worst64d, float(np.max(np.abs(y64d - ref))))
        worst32 = max(worst32, float(np.max(np.abs(y32 - ref))))
        if first is None:
            first = e64
        last = e64
        n_done += chunk
    table(f"Soak: {n_done:.0e} samples, poles at radius 1 - 1e-6, against a long-double reference",
          ["path", "max |error| / peak", "error in first chunk / peak", "error in last chunk / peak"],
          [["SosFilter float64 (tdf2)", f"{worst64 / peak:.2e}", f"{first / peak:.2e}", f"{last / peak:.2e}"],
           ["SosFilter float64 (delta)", f"{worst64d / peak:.2e}", "", ""],
           ["SosFilter float32 (delta)", f"{worst32 / peak:.2e}", "", ""]])
    print(f"\n(soak wall time {time.perf_counter() - t0_all:.1f} s; our float64 filtering {t_ours:.2f} s)")
    return worst64 / peak


def bench_accuracy(n, repeat=3):
    """The filters kernel of ``tactile-mirror bench`` (measure.filter_variants), at size n."""
    sos = ss.butter(4, 0.5, "highpass", fs=10_000.0, output="sos")
    cases = filter_variants(sos, 12, n_err=min(n, 20_000), n_time=n, repeat=repeat)
    t_ref = cases[0].seconds
    rows = [[c.label, f"{c.error:.1e}", f"{c.seconds * 1e9:.2f}", f"{t_ref / c.seconds:.2f}x"] for c in cases]
    table("Run time against error: butter(4, 0.5 Hz, highpass, fs=10 kHz), 12 channels, extended-precision "
          "reference", ["implementation", "max |error| / peak", "ns per channel-sample", "speed (vs scipy float64)"],
          rows)


def main(argv=None) -> float:
    """Print the tables; return the soak's float64 (tdf2) error relative to its peak."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="tiny sizes (a smoke run of a few seconds)")
    args = p.parse_args(argv)
    header("SOS engine against scipy.signal")
    if args.quick:
        bench_block(20_000, n_cached=2_000, reps_cached=5)
        bench_step(n=2_000, m=200, n_cpp=20_000)
        bench_subnormal(20_000)
        bench_accuracy(5_000, repeat=1)
        return bench_soak(400_000, chunk=200_000)
    bench_block(1_000_000)
    bench_step()
    bench_subnormal(1_000_000)
    bench_accuracy(200_000)
    return bench_soak(100_000_000)


if __name__ == "__main__":
    main()
