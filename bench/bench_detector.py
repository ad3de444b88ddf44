"""Benchmarks of the slip-detector kernel (Jordan MLP, jordan_mlp.hpp).

1. One tick of 6 ridges x H = 16, timed inside C++ (float32/float64, exact/fast
   sigmoid, each SIMD path), with a plain scalar C++ loop over the ridges as the
   reference measured in the same run.
2. Block API (whole recurrence over (6, 4, n) in C++) against the numpy
   implementation of the same recurrence, and against numpy stepping one tick
   per Python call.
3. Run time against output error: exact/fast sigmoid x float32/float64, error
   measured against the float64 numpy reference (the detector kernel of
   ``tactile-mirror bench``: :func:`tactile_mirror.lab.measure.detector_variants`).
5. The bundled filter-bank net (kind ``"jordan_bank"``, 17 inputs per ridge: the
   four rates and their filter bank): one tick of 6 ridges inside C++ (goal
   <= 250 ns float32) and its block API against its numpy reference
   (``detector.core.reference_run``: ``bank_features`` + the numpy recurrence; goal
   >= 50x); then the same net with its inputs compressed (a bank with knees,
   ``detector.bank.log_compress``; knees fitted on the bench's own signals): what the
   compression costs per tick; and the bundled pad net (``SlipDetector.pad()``: it also
   reads the pad's mean of the bank, ``bank["pad_mean"]``, 34 inputs, compressed): what the
   pad's mean costs.
4. Training: one loss-and-gradient evaluation (exact BPTT) of the C++ kernel
   (``tactile_mirror.kernels.jordan_loss_grad``, 1 and 2 threads) against the numpy specification
   (``network.loss_and_grad``) on the same padded training batch, with the
   difference of their results.

Run: ``python bench/bench_detector.py [--quick]`` (``--quick``: tiny sizes, a smoke run of a
few seconds). Prints which code path ran; ``main`` returns the C++ gradient's largest
difference from the numpy specification's, relative to its largest element (section 4).
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from common import best_time, header
from tactile_mirror.detector import DetectorWeights, Params, SlipDetector
from tactile_mirror.detector.network import forward
from tactile_mirror.kernels import detector_has_avx2_fma, jordan_loss_grad
from tactile_mirror.lab.measure import detector_variants, sigmoid_error


def make_weights(n_hidden=16, seed=0):
    rng = np.random.default_rng(seed)
    p = Params(rng.normal(size=(n_hidden, 5)), rng.normal(size=n_hidden), rng.normal(size=(2, n_hidden)),
               rng.normal(size=2))
    p.w1[:, -1] = 3.0 * rng.normal(size=n_hidden)
    return DetectorWeights(p, np.zeros(4), np.ones(4), 1000.0, {"features": "stress_rate"})


def make_features(n_ridges, n, seed=1):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(size=(n_ridges, 4, n)), axis=-1) * 0.05 + rng.standard_t(2, (n_ridges, 4, n)) * 0.3


def numpy_tick_loop(w, x):
    """numpy, one Python call per tick (what a naive real-time loop would do)."""
    p = w.params
    prev = np.zeros(x.shape[0])
    gain = w.input_gain
    w_in, w_fb, w2t = p.w1[:, :-1].T, p.w1[:, -1], p.w2.T
    for t in range(x.shape[2]):
        xn = (x[:, :, t] - w.input_mean) * gain
        h = 1.0 / (1.0 + np.exp(-(xn @ w_in + np.multiply.outer(prev, w_fb) + p.b1)))
        y = 1.0 / (1.0 + np.exp(-(h @ w2t + p.b2)))
        prev = y[:, 1]
    return prev


def bank_net(n_iter, n_block, n_knee=20000):
    from tactile_mirror.detector.bank import bank_features, fit_knees
    from tactile_mirror.detector.core import reference_run

    bank = SlipDetector.bank()
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(size=(6, 4, n_block)), axis=-1) * 2e3 + rng.normal(size=(6, 4, n_block)) * 1e3
    x[:, 2:] *= 30.0  # second-order rates: larger
    w = bank.weights
    knee = fit_knees(bank_features(x[..., :n_knee], w.fs, w.bank))
    wk = DetectorWeights(w.params, w.input_mean, w.input_scale, w.fs,
                         {**w.metadata, "bank": {**w.bank, "knee": [float(k) for k in knee]}})
    wp = SlipDetector.pad().weights
    for title, weights in (("the bundled filter-bank net", w), ("the same, inputs compressed (knees)", wk),
                           ("the bundled pad net (SlipDetector.pad(): + the pad's mean, compressed)", wp)):
        print(f"\n5) {title} (kind 'jordan_bank', {weights.params.w1.shape[1] - 1} inputs + y_pred, H = 16), "
              "6 ridges")
        print(f"   {'dtype':<8} {'sigmoid':<7} {'step() ns/tick':>15}")
        for dtype in (np.float32, np.float64):
            for act in ("exact", "fast"):
                k = SlipDetector(weights, dtype=dtype, activation=act).kernel(6)
                print(f"   {np.dtype(dtype).name:<8} {act:<7} {k.time_step_ns(n_iter, 5):>15.1f}")
        t_ref = best_time(lambda: reference_run(weights, x), 3) / n_block
        print(f"   numpy reference (bank_features + forward): {t_ref * 1e6:8.3f} us/tick")
        ref = reference_run(weights, x)
        for dtype in (np.float64, np.float32):
            det = SlipDetector(weights, dtype=dtype)
            xc = np.ascontiguousarray(x, dtype=dtype)
            t_c = best_time(lambda: det.run(xc), 5) / n_block
            err = max(float(np.max(np.abs(a - b))) for a, b in zip(det.run(xc), ref))
            print(f"   C++ run() {np.dtype(dtype).name} ({det.simd_path}): {t_c * 1e6:8.3f} us/tick   "
                  f"{t_ref / t_c:6.0f}x numpy   max |dy| {err:.1e}")


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes (a smoke run of a few seconds)")
    args = ap.parse_args(argv)
    n_iter = 5_000 if args.quick else 2_000_000
    n_block = 2_000 if args.quick else 100_000
    n_sigmoid = 20_001 if args.quick else 2_000_001
    w = make_weights(16)
    header("slip-detector kernel")
    print(f"AVX2+FMA available: {detector_has_avx2_fma()}")

    # 1. one tick, timed inside C++
    print("\n1) one tick, 6 ridges x H=16 (ns per tick, timed inside C++, best of 5)")
    print(f"   {'dtype':<8} {'sigmoid':<7} {'path':<10} {'SIMD step()':>12} {'scalar loop':>12}")
    paths = ["generic"] + (["avx2+fma"] if detector_has_avx2_fma() else [])
    for dtype in (np.float32, np.float64):
        for act in ("exact", "fast"):
            k = SlipDetector(w, dtype=dtype, activation=act).kernel(6)
            scalar = k.time_step_ns(n_iter // 4, 5, "scalar")
            for path in paths:
                k.set_simd_path(path)
                simd = k.time_step_ns(n_iter, 5)
                print(f"   {np.dtype(dtype).name:<8} {act:<7} {path:<10} {simd:>12.1f} {scalar:>12.1f}")
    default_path = SlipDetector(w, dtype=np.float32).simd_path
    print(f"   default path selected at run time: {default_path}")

    # 2. block API against numpy
    print(f"\n2) block API over (6, 4, {n_block}) against numpy (us per tick)")
    x = make_features(6, n_block)
    xn = x  # mean 0, scale 1
    t_np = best_time(lambda: forward(w.params, xn), 3) / n_block
    n_loop = min(n_block, 20_000)
    t_loop = best_time(lambda: numpy_tick_loop(w, x[:, :, :n_loop]), 3) / n_loop
    print(f"   numpy, recurrence vectorised over ridges (network.forward): {t_np * 1e6:8.3f}")
    print(f"   numpy, one Python call per tick:                          {t_loop * 1e6:8.3f}")
    for dtype in (np.float64, np.float32):
        for act in ("exact", "fast"):
            det = SlipDetector(w, dtype=dtype, activation=act)
            xc = np.ascontiguousarray(x, dtype=dtype)
            t_c = best_time(lambda: det.run(xc), 5) / n_block
            print(f"   C++ run() {np.dtype(dtype).name} {act:<5} ({det.simd_path}): {t_c * 1e6:8.3f} us/tick"
                  f"   speed-up {t_np / t_c:6.0f}x vs forward, {t_loop / t_c:6.0f}x vs per-tick numpy")

    # 3. run time against error: the detector kernel of ``tactile-mirror bench`` (same functions)
    print(f"\n3) run time vs output error (block run over (6, 4, {n_block}); error vs float64 numpy)")
    print(f"   {'dtype':<8} {'sigmoid':<7} {'ns/tick':>9} {'max|dy_slip|':>13} {'max|dy_pred|':>13}")
    for row in detector_variants(w, x, repeat=5):
        print(f"   {row['dtype']:<8} {row['activation']:<7} {row['seconds'] * 1e9:>9.1f} "
              f"{row['error_slip']:>13.2e} {row['error_pred']:>13.2e}")
    print(f"   sigmoid alone over a in [-100, 100] ({n_sigmoid - 1:.0e} points): max |sigmoid_kernel - expit|"
          .replace("e+0", "e"))
    for dtype in (np.float64, np.float32):
        for act in ("exact", "fast"):
            for path in paths:
                print(f"     {np.dtype(dtype).name:<8} {act:<6} {path:<9} "
                      f"{sigmoid_error(dtype, act, path, n_sigmoid):.2e}")

    # 5. (printed here, before the long training section) the filter-bank net
    bank_net(n_iter, n_block, min(n_block, 20000))

    # 4. training gradient
    from tactile_mirror.detector.network import init_params, loss_and_grad

    n_seq, n_len = (4, 500) if args.quick else (128, 2500)
    rng = np.random.default_rng(5)
    xs = make_features(n_seq, n_len, seed=6)
    length = rng.integers(n_len // 2, n_len + 1, n_seq)  # sequences end at slip + 0.3 s: ragged
    real = np.arange(n_len)[None, :] < length[:, None]
    xs *= real[:, None, :]
    ts = (np.arange(n_len)[None, :] > 0.8 * length[:, None]).astype(float) * real
    tp = np.clip(np.arange(n_len)[None, :] / length[:, None], 0, 1) * real
    ws = real / real.sum()
    theta = init_params(4, 16, seed=2).pack()
    args_np = (theta, xs, ts, tp, ws, ws, 4, 16)
    t_np = best_time(lambda: loss_and_grad(*args_np), 3)
    f_np, g_np = loss_and_grad(*args_np)
    print(f"\n4) training loss + exact BPTT gradient, {n_seq} sequences of up to {n_len} samples "
          f"({int(length.sum())} real), H = 16")
    print(f"   numpy network.loss_and_grad (padded batch): {t_np * 1e3:8.1f} ms")
    worst = 0.0
    for nt in (1, 2):
        t_c = best_time(lambda: jordan_loss_grad(theta, xs, ts, tp, ws, ws, length, 16, nt), 5)
        f_c, g_c = jordan_loss_grad(theta, xs, ts, tp, ws, ws, length, 16, nt)
        dgrad = np.abs(g_c - g_np).max() / np.abs(g_np).max()
        worst = max(worst, float(dgrad))
        print(f"   C++ jordan_loss_grad, {nt} thread{'s' if nt > 1 else ' '}:        {t_c * 1e3:8.1f} ms"
              f"   {t_np / t_c:5.1f}x   {t_c / length.sum() * 1e9 * nt:5.0f} ns per sample-thread"
              f"   |dloss|/loss {abs(f_c - f_np) / abs(f_np):.1e}"
              f"   max|dgrad|/max|grad| {dgrad:.1e}")
    return worst


if __name__ == "__main__":
    main()
