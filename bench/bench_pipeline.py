"""Real-time pipeline: cost of one tick, from C++, C, Python and scipy + numpy.

Tables (one run, same machine, same configuration):

1. ``inside C++``: ``MirrorPipeline.time_step_ns`` (the tick loop runs in C++, best of 5)
   for 1..6 ridges, with u_out sampled or the digital differentiator, with and without
   the estimator and the controller, float64/float32, fast/exact sigmoid: the cost of
   the parts a configuration uses, and nothing for the others.
2. ``6-ridge tick`` through every door: inside C++, a C program calling
   ``tm_pipeline_step`` (tests/c/example.c compiled with the system cc), the C ABI's
   own timer, Python calling ``MirrorPipeline.step`` (pybind11), Python through cffi,
   and the same tick written with scipy.signal.sosfilt + numpy (``ReferencePipeline``).
3. ``latency``: a ``LoopRunner`` paced in real time at 10 kHz for 10 s (samples from an
   array, a simulated stage): p50, p99, p99.9 and max of the tick latency (sample handed
   over -> stage command issued), overruns and late starts; and the same run from the C
   program (``tm_pipeline_step`` paced by a busy wait, no Python).

4. ``filter-bank detector``: the same 6-ridge tick with the bundled filter-bank net
   (kind ``"jordan_bank"``: the rates plus 13 filter states per ridge in front of the
   net) inside C++ in each arithmetic, through the C ABI, and its scipy + numpy
   reference; goal <= 500 ns float64 inside C++; then with its inputs compressed, and the
   bundled pad net (``SlipDetector.pad()``, the pad's mean of the bank too).

Run: ``python bench/bench_pipeline.py`` (``--quick``: tiny runs, a 0.2 s latency run, a smoke run
of a few seconds; ``--latency-seconds``). Goals: <= 300 ns per 6-ridge tick in C++ and through the C
ABI, <= 1.5 us from Python, scipy + numpy >= 100x slower. ``main`` returns the 6-ridge float64 tick
inside C++, ns (table 2).
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
from common import best_time, header
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.filters import simd_path
from tactile_mirror.loop import ArraySource, LoopRunner, SimulatedStage
from tactile_mirror.loop.capi import CPipeline, header_path, library_path
from tactile_mirror.pipeline import MirrorPipeline, ReferencePipeline, VelocityController

ROOT = Path(__file__).resolve().parents[1]
H = 16


def weights(fs, seed=0):
    rng = np.random.default_rng(seed)
    return {"w1": rng.normal(size=(H, 5)), "b1": rng.normal(size=H), "w2": rng.normal(size=(2, H)),
            "b2": rng.normal(size=2), "input_mean": np.zeros(4),
            "input_gain": np.array([1e-4, 1e-4, 1e-6, 1e-6]), "fs": fs}


def make(fs=1000.0, n_ridges=6, use_u=True, estimator=True, controller=True, dtype=np.float64,
         activation="fast", detector_dtype=None):
    w = weights(fs)
    kw = {}
    if estimator:
        kw["estimator"] = StressRateEstimator(PVDFCircuit(), fs, 2 * n_ridges, use_u=use_u,
                                              bandwidth=min(100.0, fs / 4))
    else:
        w["features"] = "circuit"
        kw["use_u"] = use_u
        if not use_u:
            from tactile_mirror.estimator import differentiator_sos

            kw["sos_diff"] = differentiator_sos(fs)
    ctrl = VelocityController(v_max=0.02, a_max=1.0) if controller else None
    return MirrorPipeline(w, fs, n_ridges, controller=ctrl, dtype=dtype, detector_dtype=detector_dtype,
                          activation=activation, v_limit=10.0, u_limit=10.0, **kw)


def python_step_ns(pipe, n):
    x = np.ascontiguousarray(0.01 * np.sin(np.arange(pipe.n_inputs)))
    out = np.zeros(pipe.n_outputs)
    step = pipe.step

    def run():
        for _ in range(n):
            step(x, out)

    return best_time(run, 5, clock=time.perf_counter_ns) / n


def reference_step_ns(pipe, n):
    ref = ReferencePipeline(pipe.config)
    x = 0.01 * np.sin(np.arange(pipe.n_inputs))

    def run():
        for _ in range(n):
            ref.step(x)

    return best_time(run, 3, clock=time.perf_counter_ns) / n


def c_program(n, paced_seconds=0.0):
    """Run tests/c/example.c in timing mode; returns its "key value..." lines as a dict."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return {}
    lib = library_path()
    with tempfile.TemporaryDirectory() as d:
        exe = os.path.join(d, "example")
        subprocess.run([cc, "-std=c99", "-O2", "-D_POSIX_C_SOURCE=199309L", str(ROOT / "tests" / "c" / "example.c"),
                        "-I", os.path.dirname(header_path()), lib, "-Wl,-rpath," + os.path.dirname(lib), "-lm",
                        "-o", exe], check=True)
        args = [exe, str(n)] + ([str(paced_seconds)] if paced_seconds else [])
        out = subprocess.run(args, check=True, capture_output=True, text=True).stdout
    return {line.split()[0]: [float(v) for v in line.split()[1:]] for line in out.splitlines() if " " in line}


def table_scaling(n_iter):
    print("\n1. inside C++: ns per tick (time_step_ns, best of 5), fs = 1 kHz, H = 16")
    print(f"{'ridges':>6} {'u_out':>6} {'estim':>6} {'ctrl':>5} {'dtype':>8} {'sigmoid':>8} {'ns/tick':>9}")
    rows = []
    for dtype in (np.float64, np.float32):
        for r in (1, 2, 3, 6):
            rows.append((r, True, True, True, dtype, "fast"))
    rows += [(6, False, True, True, np.float64, "fast"), (6, True, False, True, np.float64, "fast"),
             (6, True, True, False, np.float64, "fast"), (6, False, False, False, np.float64, "fast"),
             (6, True, True, True, np.float64, "exact"), (6, True, True, True, np.float32, "exact")]
    for r, u, e, c, dt, act in rows:
        p = make(n_ridges=r, use_u=u, estimator=e, controller=c, dtype=dt, activation=act)
        ns = p.time_step_ns(n_iter, 5)
        print(f"{r:>6} {'yes' if u else 'diff':>6} {'yes' if e else 'raw':>6} {'yes' if c else 'no':>5} "
              f"{np.dtype(dt).name:>8} {act:>8} {ns:>9.1f}")


def table_doors(n_iter, n_py, n_ref):
    print("\n2. one 6-ridge tick (u_out sampled, estimator, detector H=16 fast sigmoid, velocity controller)")
    res = {}
    for dt in (np.float64, np.float32):
        p = make(dtype=dt)
        res[f"C++ inside, {np.dtype(dt).name}"] = p.time_step_ns(n_iter, 5)
    p = make(dtype=np.float64, detector_dtype=np.float32)
    res["C++ inside, float64 filters, float32 detector"] = p.time_step_ns(n_iter, 5)
    p = make()
    c = c_program(n_iter)
    if c:
        for tag, name in (("f64", "float64"), ("f32", "float32"), ("f64f32", "float64 filters, float32 detector")):
            res[f"C program -> tm_pipeline_step, {name}"] = c[f"capi_ns_per_tick_{tag}"][0]
            res[f"C ABI timer (tm_pipeline_time_step_ns), {name}"] = c[f"inside_ns_per_tick_{tag}"][0]
    res["Python -> MirrorPipeline.step (pybind11)"] = python_step_ns(p, n_py)
    with CPipeline(p.config) as c:
        res["Python -> cffi -> tm_pipeline_step"] = python_step_ns(c, max(n_py // 10, 1000))
    res["scipy sosfilt + numpy (ReferencePipeline.step)"] = reference_step_ns(p, n_ref)
    ours = res["Python -> MirrorPipeline.step (pybind11)"]
    width = max(len(k) for k in res)
    for k, v in res.items():
        print(f"  {k:<{width}}  {v:>10.1f} ns")
    ref = res["scipy sosfilt + numpy (ReferencePipeline.step)"]
    print(f"  scipy + numpy / pybind11 step from Python: {ref / ours:.0f}x;  "
          f"/ C++ inside: {ref / res['C++ inside, float64']:.0f}x")
    return res


def table_latency(seconds, fs=10000.0):
    print(f"\n3. latency: LoopRunner in real time at {fs / 1000:g} kHz for {seconds:g} s "
          "(array source, simulated stage)")
    p = make(fs=fs)
    n = int(seconds * fs)
    rng = np.random.default_rng(1)
    x = 0.01 * rng.standard_normal((n, p.n_inputs))
    stage = SimulatedStage(lag=0.002)
    res = LoopRunner(p, stage, ArraySource(x), realtime=True).run(n_ticks=n)
    pc = res.latency_percentiles()
    print(f"  Python LoopRunner (step + stage command): ticks {len(res.t)}  p50 {pc['p50']:.2f} us  "
          f"p99 {pc['p99']:.2f} us  p99.9 {pc['p99.9']:.2f} us  max {pc['max']:.1f} us  "
          f"overruns {res.overruns}  late starts {res.late_starts}")
    c = c_program(1000, seconds)
    if c:
        p50, p99, p999, mx = c["latency_ns"]
        print(f"  C program, tm_pipeline_step paced at 10 kHz: p50 {p50 / 1e3:.2f} us  p99 {p99 / 1e3:.2f} us  "
              f"p99.9 {p999 / 1e3:.2f} us  max {mx / 1e3:.1f} us  overruns {int(c['overruns'][0])}")
    return pc, res.overruns, res.late_starts


def table_bank(n_iter, n_ref):
    from tactile_mirror.detector import SlipDetector

    print("\n4. one 6-ridge tick with the filter-bank detector (bundled 'jordan_bank' net, H=16, fast sigmoid, "
          "velocity controller)")
    det = SlipDetector.bank()
    res = {}
    for dt, ddt in ((np.float64, None), (np.float32, None), (np.float64, np.float32)):
        est = StressRateEstimator(PVDFCircuit(), 1000.0, 12)
        p = MirrorPipeline(det, 1000.0, 6, estimator=est, controller=VelocityController(v_max=0.02, a_max=1.0),
                           dtype=dt, detector_dtype=ddt, activation="fast", v_limit=10.0, u_limit=10.0)
        name = np.dtype(dt).name + ("" if ddt is None else " filters, float32 detector")
        res[f"C++ inside, {name}"] = p.time_step_ns(n_iter, 5)
        if ddt is None and dt is np.float64:
            base = p
    res["Python -> MirrorPipeline.step (pybind11)"] = python_step_ns(base, max(n_iter // 10, 1000))
    with CPipeline(base.config) as c:
        res["Python -> cffi -> tm_pipeline_step"] = python_step_ns(c, max(n_iter // 100, 1000))
    res["scipy sosfilt + numpy (ReferencePipeline.step)"] = reference_step_ns(base, n_ref)
    # The same net with its inputs compressed (a bank with knees: detector.bank.log_compress);
    # the knees' values do not change the work, the net's input scales serve.
    from tactile_mirror.detector import DetectorWeights

    w = det.weights
    wk = DetectorWeights(w.params, w.input_mean, w.input_scale, w.fs,
                         {**w.metadata, "bank": {**w.bank, "knee": [float(k) for k in w.input_scale]}})
    for dt in (np.float64, np.float32):
        est = StressRateEstimator(PVDFCircuit(), 1000.0, 12)
        p = MirrorPipeline(SlipDetector(wk), 1000.0, 6, estimator=est,
                           controller=VelocityController(v_max=0.02, a_max=1.0), dtype=dt, activation="fast",
                           v_limit=10.0, u_limit=10.0)
        res[f"C++ inside, {np.dtype(dt).name}, compressed bank inputs"] = p.time_step_ns(n_iter, 5)
    # The bundled pad net (the pad's mean of the bank too, compressed: 34 inputs).
    for dt in (np.float64, np.float32):
        est = StressRateEstimator(PVDFCircuit(), 1000.0, 12)
        p = MirrorPipeline(SlipDetector.pad(), 1000.0, 6, estimator=est,
                           controller=VelocityController(v_max=0.02, a_max=1.0), dtype=dt, activation="fast",
                           v_limit=10.0, u_limit=10.0)
        res[f"C++ inside, {np.dtype(dt).name}, the pad net (SlipDetector.pad())"] = p.time_step_ns(n_iter, 5)
    width = max(len(k) for k in res)
    for k, v in res.items():
        print(f"  {k:<{width}}  {v:>10.1f} ns")
    return res


def main(argv=None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny runs (a smoke run of a few seconds)")
    ap.add_argument("--latency-seconds", type=float, default=None)
    args = ap.parse_args(argv)
    n_iter = 2000 if args.quick else 300000
    n_py = 1000 if args.quick else 200000
    n_ref = 20 if args.quick else 2000
    lat_s = args.latency_seconds if args.latency_seconds is not None else (0.2 if args.quick else 10.0)
    p = make()
    header("real-time pipeline tick")
    print(f"code paths: filters {simd_path()}; pipeline {p.simd_path}")
    table_scaling(n_iter)
    res = table_doors(n_iter, n_py, n_ref)
    table_latency(lat_s)
    table_bank(n_iter, n_ref)
    return res["C++ inside, float64"]


if __name__ == "__main__":
    main()
