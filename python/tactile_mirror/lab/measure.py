"""Measuring functions shared by ``tactile-mirror bench`` and the scripts in ``bench/``.

One measuring path: the report of :mod:`tactile_mirror.lab.benchmark` and the scripts
``bench/bench_*.py`` time and score the kernels with these functions, so a figure in
the report and the same figure printed by a script come from the same code.

Timing
    :func:`best_times` (several functions, interleaved round after round, so a burst
    of load elsewhere hits them alike), :func:`best_time` and :func:`timed` (one
    function). Times are seconds of ``time.perf_counter`` unless a ``clock`` is given
    (``time.process_time`` for this process's CPU time, robust on a shared machine).
Errors
    :func:`rel_max`, :func:`rel_rms`, :func:`rel_rms_aligned`; the extended-precision
    filter reference :func:`extended_sosfilt`.
Kernels
    :func:`filter_variants` (the SOS engine and scipy on one filter: error and time of
    every dtype and structure), :func:`estimator_signals` and :func:`estimator_errors`
    (the stress-rate estimator against the analytic rate of a known load),
    :func:`detector_variants` and :func:`sigmoid_error` (the slip detector against the
    float64 numpy recurrence), :func:`lowpass_delay_ms`.
Where it ran
    :func:`environment` (versions, SIMD path, CPU model, threads), :func:`cpu_model`.
Tables
    :func:`markdown_table`.

A new benchmark (a C++ contact solver, a soak run) plugs in by timing with
:func:`best_times`/:func:`timed`, scoring with the error functions, and printing
:func:`environment` with its table; a kernel that belongs in the report adds a
function returning a :class:`tactile_mirror.lab.benchmark.KernelReport` to
``tactile_mirror.lab.benchmark.KERNEL_BENCHES``.
"""
from __future__ import annotations

import datetime
import math
import os
import platform
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from tactile_mirror.checks import integer

__all__ = [
    "FilterCase",
    "best_time",
    "best_times",
    "cpu_model",
    "detector_features",
    "detector_variants",
    "environment",
    "environment_line",
    "estimator_errors",
    "estimator_signals",
    "extended_sosfilt",
    "filter_variants",
    "lowpass_delay_ms",
    "markdown_table",
    "rel_max",
    "rel_rms",
    "rel_rms_aligned",
    "sigmoid_error",
    "timed",
]


# ---------------------------------------------------------------- timing
def best_times(fns: Sequence[Callable[[], object]], repeat: int, tick: Callable[[], object] | None = None,
               clock: Callable[[], float] = time.perf_counter) -> list[float]:
    """Shortest time of each function over ``repeat`` rounds, s; every round runs all of
    them in turn, so that a burst of load elsewhere on the machine hits them alike.
    ``tick`` is called after each round (a progress bar)."""
    best = [math.inf] * len(fns)
    for _ in range(max(1, int(repeat))):
        for i, fn in enumerate(fns):
            t0 = clock()
            fn()
            best[i] = min(best[i], clock() - t0)
        if tick is not None:
            tick()
    return best


def best_time(fn: Callable[[], object], repeat: int = 5, clock: Callable[[], float] = time.perf_counter) -> float:
    """Shortest time of ``repeat`` calls of ``fn``, s."""
    return best_times([fn], repeat, clock=clock)[0]


def timed(fn: Callable[[], object], repeat: int = 3, clock: Callable[[], float] = time.perf_counter):
    """``(shortest time, last result)`` of ``repeat`` calls of ``fn``; ``clock`` is wall
    time by default, ``time.process_time`` for this process's CPU time."""
    best, out = math.inf, None
    for _ in range(max(1, int(repeat))):
        t0 = clock()
        out = fn()
        best = min(best, clock() - t0)
    return best, out


# ---------------------------------------------------------------- errors
def rel_max(y, ref) -> float:
    """``max |y - ref| / max |ref|``, computed in long double (real arrays only)."""
    from tactile_mirror.checks import real_numeric

    for name, a in (("y", y), ("ref", ref)):  # (an imaginary part was dropped)
        real_numeric(np.asarray(a), name)
    ref = np.asarray(ref, dtype=np.longdouble)
    return float(np.max(np.abs(np.asarray(y).astype(np.longdouble) - ref)) / np.max(np.abs(ref)))


def rel_rms(a, b) -> float:
    """``rms(a - b) / rms(b)`` (``b`` broadcast to the shape of ``a``)."""
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(np.broadcast_to(b, np.shape(a)) ** 2)))


def rel_rms_aligned(a, b, max_shift: int = 30) -> float:
    """:func:`rel_rms` after shifting ``a`` back by the whole number of samples
    (0 .. ``max_shift``) that minimises it: the error left once a delay is removed.
    Time on the last axis."""
    a, b = np.asarray(a), np.asarray(b)
    n = b.shape[-1]
    integer(max_shift, "max_shift", 0, n - 1)  # (a shift of the whole signal leaves nothing to compare)
    return min(rel_rms(a[..., k:], b[..., : n - k]) for k in range(max_shift + 1))


def extended_sosfilt(sos, x) -> np.ndarray:
    """Filter ``x`` (channels, n) with ``sos`` in extended precision; float64-or-better reference.

    The sections run in the delta-operator structure (Kauraniemi et al. 1998), whose
    round-off does not grow for poles near ``z = 1``, in ``numpy.longdouble`` (80-bit on
    x86-64: about 1e-18 of peak for the filters used here, checked against mpmath by the
    tests). Where ``longdouble`` is no wider than float64 it falls back to mpmath (36
    digits; slow, use short signals) and raises ``RuntimeError`` without it.

    Returns
    -------
    ndarray of numpy.longdouble, shape of ``x``
    """
    sos = np.atleast_2d(np.asarray(sos, dtype=np.float64))
    x = np.atleast_2d(np.asarray(x, dtype=np.float64))
    if sos.ndim != 2 or sos.shape[1] != 6 or not np.all(sos[:, 3] != 0):
        raise ValueError("sos must have shape (n_sections, 6) with every a0 nonzero")
    if np.finfo(np.longdouble).eps < 1e-18:
        return _delta_longdouble(sos, x)
    try:
        import mpmath
    except ImportError:  # pragma: no cover - platforms without an extended long double
        raise RuntimeError("the filter reference needs an extended long double or mpmath "
                           "(pip install mpmath)") from None
    return _sosfilt_mpmath(sos, x, mpmath)  # pragma: no cover


def _delta_longdouble(sos: np.ndarray, x: np.ndarray) -> np.ndarray:
    L = np.longdouble
    y = x.astype(L)
    for row in sos:
        b0, b1, b2, a0, a1, a2 = (L(v) for v in row)
        b0, b1, b2, a1, a2 = b0 / a0, b1 / a0, b2 / a0, a1 / a0, a2 / a0
        c1, c2 = 2 * b0 + b1, (b0 + b1) + b2  # numerator in d = z - 1
        d1, d2 = 2 + a1, (1 + a1) + a2  # denominator in d
        s1 = np.zeros(y.shape[0], L)
        s2 = np.zeros(y.shape[0], L)
        out = np.empty_like(y)
        for i in range(y.shape[1]):
            xi = y[:, i]
            yi = b0 * xi + s1
            s1, s2 = s1 + (c1 * xi + s2) - d1 * yi, (s2 + c2 * xi) - d2 * yi
            out[:, i] = yi
        y = out
    return y


def _sosfilt_mpmath(sos: np.ndarray, x: np.ndarray, mpmath) -> np.ndarray:  # pragma: no cover
    out = np.empty(x.shape, dtype=object)
    with mpmath.workdps(36):
        coefs = [[mpmath.mpf(float(v)) for v in row] for row in sos]
        for ch in range(x.shape[0]):
            y = [mpmath.mpf(float(v)) for v in x[ch]]
            for b0, b1, b2, a0, a1, a2 in coefs:
                b0, b1, b2, a1, a2 = b0 / a0, b1 / a0, b2 / a0, a1 / a0, a2 / a0
                z1 = z2 = mpmath.mpf(0)
                for i, xi in enumerate(y):
                    yi = b0 * xi + z1
                    z1 = b1 * xi - a1 * yi + z2
                    z2 = b2 * xi - a2 * yi
                    y[i] = yi
            out[ch] = y
    return out.astype(np.longdouble)


# ---------------------------------------------------------------- filters
@dataclass
class FilterCase:
    """One filter implementation measured by :func:`filter_variants`.

    ``error``: ``max |y - ref| / max |ref|`` against :func:`extended_sosfilt`;
    ``seconds``: best time per channel-sample, s; ``auto``: the structure that
    ``structure="auto"`` picks.
    """

    label: str
    api: str          # "scipy", "sosfilt" or "SosFilter"
    dtype: str
    structure: str
    auto: bool = False
    error: float = math.nan
    seconds: float = math.nan
    extra: dict = field(default_factory=dict)


def filter_variants(sos, channels: int = 12, n_err: int = 20_000, n_time: int = 200_000, repeat: int = 5,
                    seed: int = 4, tick: Callable[[], object] | None = None) -> list[FilterCase]:
    """Error and run time of every filter path on the sections ``sos``.

    scipy.signal.sosfilt (float64, float32), :func:`tactile_mirror.sosfilt` with float64
    and float32 sections in tdf2 and delta structure, and :class:`tactile_mirror.SosFilter`
    designed in float64 computing in float32 (``structure="auto"``). White noise,
    ``channels`` x ``n_err`` samples for the error (against :func:`extended_sosfilt`),
    ``channels`` x ``n_time`` samples for the time (best of ``repeat`` interleaved
    rounds). The first case is scipy float64, the usual speed reference. ``tick`` is
    called once per case and once per timing round.
    """
    import scipy.signal as ss

    from tactile_mirror import filters as flt

    sos = np.asarray(sos, dtype=np.float64)
    rng = np.random.default_rng(seed)
    x_err = rng.standard_normal((channels, n_err))
    x_time = rng.standard_normal((channels, n_time))
    ref = extended_sosfilt(sos, x_err)
    sos32 = sos.astype(np.float32)

    def is_auto(dtype, structure):
        forms = flt._forms(flt.validate_sos(sos.astype(dtype)), np.dtype(dtype), "auto")
        return bool(np.all(forms == flt._FORM_CODES[structure]))

    cases: list[tuple[FilterCase, Callable[[np.ndarray], np.ndarray], type]] = [
        (FilterCase("scipy.signal.sosfilt float64", "scipy", "float64", "tdf2"), lambda x: ss.sosfilt(sos, x),
         np.float64),
        (FilterCase("scipy.signal.sosfilt float32", "scipy", "float32", "tdf2"), lambda x: ss.sosfilt(sos32, x),
         np.float32)]
    for sos_dt in (sos, sos32):
        for structure in ("tdf2", "delta"):
            def ours(x, s=sos_dt, structure=structure):
                return flt.sosfilt(s, x, structure=structure)

            name = sos_dt.dtype.name
            auto = is_auto(sos_dt.dtype, structure)
            cases.append((FilterCase(f"sosfilt {name} {structure}{' (auto)' if auto else ''}", "sosfilt", name,
                                     structure, auto), ours, sos_dt.dtype.type))
    f32 = flt.SosFilter(sos, channels, np.float32)  # float64 design, float32 arithmetic, "auto"
    f32_structure = "/".join(dict.fromkeys(f32.structure))

    def sos_filter32(x):
        f32.reset()
        return f32.process(x)

    cases.append((FilterCase(f"SosFilter float32 {f32_structure} (auto)", "SosFilter", "float32", f32_structure,
                             True), sos_filter32, np.float32))
    blocks = {np.dtype(dt): x_time.astype(dt) for dt in (np.float64, np.float32)}
    runs = []
    for case, fn, dt in cases:
        case.error = rel_max(fn(x_err.astype(dt)), ref)
        xt = blocks[np.dtype(dt)]
        runs.append(lambda fn=fn, xt=xt: fn(xt))
        if tick is not None:
            tick()
    for (case, _, _), t in zip(cases, best_times(runs, repeat, tick)):
        case.seconds = t / x_time.size
    return [c for c, _, _ in cases]


# ---------------------------------------------------------------- estimator
def lowpass_delay_ms(order: int, bandwidth: float, fs: float, kind: str = "butter") -> float:
    """Low-frequency group delay of the estimator's low-pass (``kind`` "butter" or
    "bessel"), ms."""
    import scipy.signal as ss

    if kind == "butter":
        b, a = ss.butter(order, bandwidth, fs=fs)
    elif kind == "bessel":
        b, a = ss.bessel(order, bandwidth, fs=fs, norm="mag")
    else:
        raise ValueError(f"kind must be 'butter' or 'bessel', got {kind!r}")
    _, gd = ss.group_delay((b, a), w=[1.0], fs=fs)
    return float(1e3 * gd[0] / fs)


def estimator_signals(circuit=None, fs: float = 1000.0, duration: float = 2.0, noise: float = 1e-3,
                      channels: int = 12, seed: int = 0):
    """The circuit's outputs for :func:`tactile_mirror.lab.testing.known_load` on every strip.

    Returns ``(v_out, u_out, rate, rate2)``: outputs (channels, n) in V with independent
    sensor noise (``noise`` V rms) per strip, and the analytic stress rate (Pa/s) and
    2nd-order rate (Pa/s^2) of the load, shape (n,).
    """
    from tactile_mirror.circuit import PVDFCircuit
    from tactile_mirror.lab.testing import known_load

    circuit = PVDFCircuit() if circuit is None else circuit
    t = np.arange(round(duration * fs)) / fs
    load, rate_true, rate2_true = known_load(t)
    stress = np.zeros((channels, 3, t.size))
    stress[:, 2] = load
    v, u = circuit.simulate(stress, fs, noise=noise, seed=seed)
    return v, u, rate_true, rate2_true


def estimator_errors(rate, rate2, rate_true, rate2_true, aligned: bool = False, max_shift: int = 30) -> dict:
    """Relative rms errors of an estimate against the truth: ``rate``, ``rate2`` and,
    with ``aligned``, the same after the best whole-sample delay (``rate_aligned``,
    ``rate2_aligned``)."""
    out = {"rate": rel_rms(rate, rate_true), "rate2": rel_rms(rate2, rate2_true)}
    if aligned:
        out["rate_aligned"] = rel_rms_aligned(rate, rate_true, max_shift)
        out["rate2_aligned"] = rel_rms_aligned(rate2, rate2_true, max_shift)
    return out


# ---------------------------------------------------------------- detector
def detector_features(weights, n_scenes: int) -> np.ndarray:
    """Features of ``n_scenes`` synthetic stick-slip scenes (6 ridges), scaled to unit
    rms after the weights' input normalisation (as in training); (6, 4, n)."""
    from tactile_mirror.lab.detector.synthetic import synthetic_scene

    x = np.concatenate([synthetic_scene(seed=s, n_ridges=6).features for s in range(n_scenes)], axis=-1)
    rms = np.sqrt(np.mean(x**2, axis=(0, 2)))
    return weights.input_mean[None, :, None] + x / rms[None, :, None] / weights.input_gain[None, :, None]


def sigmoid_error(dtype, activation: str, path: str | None = None, n: int = 2_000_001) -> float:
    """The detector kernel's sigmoid alone: ``max |sigmoid - expit|`` over ``n`` points
    in [-100, 100] (``path``: a SIMD path name, default the detector's)."""
    from scipy.special import expit

    from tactile_mirror.kernels import detector_sigmoid

    g = np.linspace(-100.0, 100.0, n).astype(dtype)
    if path is None:
        from tactile_mirror.detector import SlipDetector

        path = SlipDetector.default().simd_path
    y = detector_sigmoid(g, activation, path)
    return float(np.max(np.abs(y.astype(np.float64) - expit(g.astype(np.float64)))))


def detector_variants(weights, x, repeat: int = 5, tick: Callable[[], object] | None = None) -> list[dict]:
    """:meth:`SlipDetector.run` in float64/float32 x exact/fast sigmoid on features
    ``x`` (n_ridges, 4, n): per variant ``label``, ``dtype``, ``activation``, ``path``,
    ``error`` (max |y - y_ref| of ``y_slip`` and ``y_pred`` against the float64 numpy
    recurrence :func:`tactile_mirror.detector.reference_run`), ``error_slip``,
    ``error_pred`` and ``seconds`` per tick (best of ``repeat`` interleaved rounds).
    ``tick`` is called once per variant and once per round."""
    from tactile_mirror.detector import SlipDetector, reference_run

    ref_s, _, ref_p = reference_run(weights, x)
    rows, runs = [], []
    n = x.shape[2]
    for dt in (np.float64, np.float32):
        xc = np.ascontiguousarray(x, dtype=dt)
        for act in ("exact", "fast"):
            det = SlipDetector(weights, dtype=dt, activation=act)
            ys, _, yp = det.run(xc)
            es = float(np.max(np.abs(ys.astype(np.float64) - ref_s)))
            ep = float(np.max(np.abs(yp.astype(np.float64) - ref_p)))
            rows.append({"label": f"{np.dtype(dt).name} {act}", "dtype": np.dtype(dt).name, "activation": act,
                         "path": det.simd_path, "error": max(es, ep), "error_slip": es, "error_pred": ep})
            runs.append(lambda det=det, xc=xc: det.run(xc))
            if tick is not None:
                tick()
    for row, t in zip(rows, best_times(runs, repeat, tick)):
        row["seconds"] = t / n
    return rows


# ---------------------------------------------------------------- where it ran
def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or what :mod:`platform` knows."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def environment() -> dict:
    """Where a measurement ran: versions, SIMD path, machine, CPU model, threads, date."""
    import scipy

    from tactile_mirror import __version__, simd_path

    threads = ", ".join(f"{v}={os.environ[v]}" for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")
                        if v in os.environ) or "library defaults"
    return {"version": __version__, "simd_path": simd_path(), "machine": platform.machine(),
            "processor": platform.processor(), "cpu_model": cpu_model(), "cpus": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
            "threads": threads,
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}


def environment_line(env: dict | None = None) -> str:
    """:func:`environment` as one line, for the head of a script's output."""
    env = environment() if env is None else env
    return (f"tactile_mirror {env['version']}, SIMD path {env['simd_path']}, CPU {env['cpu_model']} "
            f"({env['cpus']} CPUs), numpy {env['numpy']}, scipy {env['scipy']}, threads: {env['threads']}")


# ---------------------------------------------------------------- tables
def markdown_table(title: str | None, header: Iterable, rows: Iterable[Iterable]) -> str:
    """A markdown table (under a ``###`` heading when ``title`` is given)."""
    header = [str(h) for h in header]
    lines = [f"\n### {title}\n"] if title else []
    lines.append("| " + " | ".join(header) + " |")
    lines.append("|" + "|".join("---" for _ in header) + "|")
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)
