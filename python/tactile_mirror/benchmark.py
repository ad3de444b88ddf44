"""Run time against error of every kernel, measured in one run (``tactile-mirror bench``).

Each kernel runs in several variants (precision, section structure, filter order,
mesh size, ...). Every variant is timed, and its error is measured against a
reference computed in the same run:

``filters``
    :func:`tactile_mirror.sosfilt` in float64 and float32 with tdf2 and delta
    sections, :class:`tactile_mirror.SosFilter` in float32, and
    :func:`scipy.signal.sosfilt` in float64 and float32, on
    ``butter(4, 0.5 Hz, 'highpass', fs=10 kHz)`` (poles near ``z = 1``), 12 channels.
    Error: ``max |y - ref| / max |ref|`` against an extended-precision reference
    (delta-operator sections in long double; mpmath where long double is no wider
    than float64). Speed: ratio to scipy.signal.sosfilt in float64.
``estimator``
    :class:`tactile_mirror.StressRateEstimator` (2nd-order rate from ``u_out``),
    low-pass order x bandwidth, on the default :class:`~tactile_mirror.PVDFCircuit`
    driven by :func:`tactile_mirror.testing.known_load` with 1 mV rms sensor noise,
    12 strips at 1 kHz. Error: ``rms(rate - true rate) / rms(true rate)`` against the
    analytic stress rate. Speed: ratio to scipy.signal.sosfilt running the same sections.
``detector``
    :meth:`tactile_mirror.SlipDetector.run` (block API, default weights, 6 ridges),
    float64/float32 x exact/fast sigmoid, on synthetic stick-slip features scaled to
    the weights' input normalisation. Error: ``max |y|`` difference of ``y_slip`` and
    ``y_pred`` against the float64 numpy recurrence
    (:func:`tactile_mirror.detector.reference_run`), which is also the speed reference.
``contact``
    :func:`tactile_mirror.simulate` of the paper's fig6 scene (to 1.3 s) at several
    mesh sizes ``h`` (contact zone ``h / 4``). Error: rms strip-stress difference to a
    fine reference mesh, relative to the peak stress. Time per step; speed ratio to the
    reference mesh. (The unreduced solve, hundreds of times slower per step than the
    reduced one, is too slow for whole scenes.)

A variant is Pareto-optimal when no other variant of the same kernel is at least as
accurate and at least as fast, and strictly better in one of the two.

Run times are the best of a few wall-clock rounds in which every variant of a kernel
runs in turn (one run for the contact model); on a shared machine compare the speed
ratios, which come from the same run, rather than absolute times. Run with ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1``.

Example
-------
>>> from tactile_mirror.benchmark import bench_report
>>> report = bench_report("bench-out", quick=True)     # doctest: +SKIP
>>> report.kernels["filters"].variants[0].error        # doctest: +SKIP
"""
from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
import pathlib
import platform
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "KERNELS",
    "BenchReport",
    "KernelReport",
    "Reference",
    "Variant",
    "bench_report",
    "extended_sosfilt",
    "pareto_front",
    "run",
]

#: Kernels measured by the report, in report order.
KERNELS = ("filters", "estimator", "detector", "contact")

MD_NAME = "bench_report.md"
PNG_NAME = "bench_pareto.png"
JSON_NAME = "bench_report.json"


# ---------------------------------------------------------------- records
@dataclass
class Variant:
    """One measured variant of a kernel.

    Attributes
    ----------
    label : str
    error : float
        Error against the kernel's reference (see :class:`KernelReport`).
    seconds : float
        Run time per unit of work (channel-sample, tick or step), s.
    ratio : float
        Speed ratio: run time of the speed reference / ``seconds`` (> 1 is faster).
    extra : dict
        Further columns of the table, by column key.
    pareto : bool
        No other variant of the kernel is at least as accurate and as fast.
    """

    label: str
    error: float
    seconds: float
    ratio: float
    extra: dict = field(default_factory=dict)
    pareto: bool = False


@dataclass
class Reference:
    """A reference timed in the same run.

    ``error`` is None for the reference the errors are measured against; a number
    for a speed reference that has its own error (scipy running the same sections).
    """

    label: str
    seconds: float
    error: float | None = None
    extra: dict = field(default_factory=dict)


@dataclass
class KernelReport:
    """Variants and references of one kernel, with what they mean."""

    name: str
    title: str
    error_name: str
    unit: str
    time_scale: float  # seconds -> the table's time unit
    time_unit: str
    notes: str
    variants: list
    references: list = field(default_factory=list)
    extra_columns: list = field(default_factory=list)  # (key, header, format spec)
    ratio_reference: str = ""  # what the speed ratio compares with
    ratio_seconds: float | None = None  # its run time per unit, when one run time serves every variant
    seconds_total: float = 0.0

    def check(self) -> None:
        """Flag the Pareto-optimal variants (in place)."""
        flags = pareto_front([v.error for v in self.variants], [v.seconds for v in self.variants])
        for v, f in zip(self.variants, flags):
            v.pareto = bool(f)


def pareto_front(errors: Sequence[float], seconds: Sequence[float]) -> np.ndarray:
    """Boolean mask of the non-dominated points (both coordinates minimised).

    A point is dominated when another point has ``error <=`` and ``seconds <=`` with at
    least one strict inequality. Equal points are all kept.
    """
    e = np.asarray(errors, dtype=float)
    s = np.asarray(seconds, dtype=float)
    if e.shape != s.shape or e.ndim != 1:
        raise ValueError(f"errors and seconds must be 1-D of one length, got {e.shape} and {s.shape}")
    le = (e[None, :] <= e[:, None]) & (s[None, :] <= s[:, None])
    lt = (e[None, :] < e[:, None]) | (s[None, :] < s[:, None])
    dominated = np.any(le & lt, axis=1)
    return ~dominated


# ---------------------------------------------------------------- helpers
def _best_times(fns: Sequence[Callable[[], object]], repeat: int, tick: Callable[[], object] = lambda: None):
    """Shortest wall time of each function over ``repeat`` rounds; every round runs all of
    them in turn, so that a burst of load elsewhere on the machine hits them alike."""
    best = [math.inf] * len(fns)
    for _ in range(max(1, repeat)):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            fn()
            best[i] = min(best[i], time.perf_counter() - t0)
        tick()
    return best


class _Progress:
    """A tqdm bar per kernel, or nothing."""

    def __init__(self, enabled: bool):
        self.enabled = enabled

    def bar(self, name: str, total: int):
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=f"bench {name}", unit="variant", disable=not self.enabled, leave=True,
                    file=sys.stderr)


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


def _rel_max(y, ref) -> float:
    ref = np.asarray(ref, dtype=np.longdouble)
    return float(np.max(np.abs(np.asarray(y).astype(np.longdouble) - ref)) / np.max(np.abs(ref)))


def _rel_rms(a, b) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(np.broadcast_to(b, np.shape(a)) ** 2)))


# ---------------------------------------------------------------- kernels
def _bench_filters(quick: bool, progress: _Progress) -> KernelReport:
    import scipy.signal as ss

    from . import filters as flt

    fs = 10_000.0
    sos = ss.butter(4, 0.5, "highpass", fs=fs, output="sos")
    channels = 12
    n_err, n_time, repeat = (4_000, 40_000, 3) if quick else (20_000, 200_000, 5)
    rng = np.random.default_rng(4)
    x_err = rng.standard_normal((channels, n_err))
    x_time = rng.standard_normal((channels, n_time))
    ref = extended_sosfilt(sos, x_err)
    sos32 = sos.astype(np.float32)

    def auto_tag(dtype, structure):
        forms = flt._forms(flt.validate_sos(sos.astype(dtype)), np.dtype(dtype), "auto")
        return " (auto)" if np.all(forms == flt._FORM_CODES[structure]) else ""

    # (label, filter function, dtype, structure)
    cases: list[tuple[str, Callable[[np.ndarray], np.ndarray], type, str]] = [
        ("scipy.signal.sosfilt float64", lambda x: ss.sosfilt(sos, x), np.float64, "tdf2"),
        ("scipy.signal.sosfilt float32", lambda x: ss.sosfilt(sos32, x), np.float32, "tdf2")]
    for sos_dt in (sos, sos32):
        for structure in ("tdf2", "delta"):
            def ours(x, s=sos_dt, structure=structure):
                return flt.sosfilt(s, x, structure=structure)

            name = sos_dt.dtype.name
            cases.append((f"sosfilt {name} {structure}{auto_tag(sos_dt.dtype, structure)}", ours,
                          sos_dt.dtype.type, structure))
    f32 = flt.SosFilter(sos, channels, np.float32)  # float64 design, float32 arithmetic, "auto"
    f32_structure = "/".join(dict.fromkeys(f32.structure))

    def sos_filter32(x):
        f32.reset()
        return f32.process(x)

    cases.append((f"SosFilter float32 {f32_structure} (auto)", sos_filter32, np.float32, f32_structure))

    bar = progress.bar("filters", len(cases) + repeat)
    errors, timed = [], []
    blocks = {np.dtype(dt): x_time.astype(dt) for dt in (np.float64, np.float32)}
    for _, fn, dt, _ in cases:
        errors.append(_rel_max(fn(x_err.astype(dt)), ref))
        xt = blocks[np.dtype(dt)]
        timed.append(lambda fn=fn, xt=xt: fn(xt))
        bar.update()
    secs = [t / x_time.size for t in _best_times(timed, repeat, bar.update)]
    bar.close()
    t_scipy = secs[0]
    variants = []
    for (label, _, dt, structure), err, t in zip(cases, errors, secs):
        api = "scipy" if label.startswith("scipy") else label.split()[0]
        variants.append(Variant(label, err, t, t_scipy / t,
                                {"dtype": np.dtype(dt).name, "structure": structure, "api": api}))
    return KernelReport(
        name="filters",
        title=f"filters: butter(4, 0.5 Hz, highpass, fs = 10 kHz), {channels} channels",
        error_name="max |error| / peak",
        unit="channel-sample", time_scale=1e9, time_unit="ns",
        notes=(f"Error on {channels} x {n_err} samples against delta-operator sections run in extended "
               f"precision; time on {channels} x {n_time} samples, best of {repeat} rounds. `sosfilt float32` follows "
               "scipy's convention (float32 coefficients); `SosFilter float32` designs in float64 and computes "
               "in float32. (auto) marks the structure `structure=\"auto\"` picks."),
        variants=variants, ratio_reference="scipy.signal.sosfilt float64, same data", ratio_seconds=t_scipy,
    )


def _lowpass_delay_ms(order: int, bandwidth: float, fs: float) -> float:
    import scipy.signal as ss

    b, a = ss.butter(order, bandwidth, fs=fs)
    _, gd = ss.group_delay((b, a), w=[1.0], fs=fs)
    return float(1e3 * gd[0] / fs)


def _bench_estimator(quick: bool, progress: _Progress) -> KernelReport:
    import scipy.signal as ss

    from .circuit import PVDFCircuit
    from .estimator import StressRateEstimator
    from .testing import known_load

    fs, duration, noise, channels = 1000.0, 2.0, 1e-3, 12
    tile, repeat = (10, 3) if quick else (50, 5)
    orders = (2, 3, 4)
    bandwidths = (50.0, 100.0, 200.0, 300.0)
    circuit = PVDFCircuit()
    t = np.arange(round(duration * fs)) / fs
    load, rate_true, rate2_true = known_load(t)
    stress = np.zeros((channels, 3, t.size))
    stress[:, 2] = load
    v, u = circuit.simulate(stress, fs, noise=noise, seed=0)  # independent noise per strip
    v_t, u_t = np.tile(v, tile), np.tile(u, tile)  # the timing block
    designs = [(order, bw) for order in orders for bw in bandwidths]
    bar = progress.bar("estimator", len(designs) + repeat)
    measured, timed = [], []
    for order, bw in designs:
        est = StressRateEstimator(circuit, fs, channels, order=order, bandwidth=bw)
        rate, rate2 = est.process(v, u)
        sos_v, sos_u = est.sos_rate, est.sos_rate2
        # scipy runs the very same sections: its error is that of the float64 design
        r1, r2 = ss.sosfilt(sos_v, v), ss.sosfilt(sos_u, u)
        measured.append((_rel_rms(rate, rate_true), _rel_rms(rate2, rate2_true), _rel_rms(r1, rate_true),
                         _rel_rms(r2, rate2_true)))

        def ours(est=est):
            est.reset()
            est.process(v_t, u_t)

        def theirs(sos_v=sos_v, sos_u=sos_u):
            ss.sosfilt(sos_v, v_t)
            ss.sosfilt(sos_u, u_t)

        timed += [ours, theirs]
        bar.update()
    secs = [t / v_t.size for t in _best_times(timed, repeat, bar.update)]
    bar.close()
    variants, references = [], []
    for i, ((order, bw), (e1, e2, e1_ref, e2_ref)) in enumerate(zip(designs, measured)):
        t_ours, t_ref = secs[2 * i], secs[2 * i + 1]
        label = f"order {order}, {bw:g} Hz"
        variants.append(Variant(label, e1, t_ours, t_ref / t_ours,
                                {"rate2": e2, "delay": _lowpass_delay_ms(order, bw, fs)}))
        references.append(Reference(f"scipy, {label}", t_ref, e1_ref, {"rate2": e2_ref}))
    return KernelReport(
        name="estimator",
        title="stress-rate estimator: low-pass order x bandwidth (Butterworth), fs = 1 kHz",
        error_name="rms(rate error) / rms(rate)",
        unit="channel-sample (both outputs)", time_scale=1e9, time_unit="ns",
        notes=(f"The default PVDF circuit driven by `tactile_mirror.testing.known_load` (loading, ramp, stop, "
               f"slip), {noise * 1e3:g} mV rms sensor noise on v_out and u_out, {channels} strips x "
               f"{duration:g} s; error against the analytic stress rate (rate2: the same for the 2nd-order rate, "
               f"from u_out); delay: low-frequency group delay of the low-pass. Time: "
               f"`StressRateEstimator.process` on {channels} x {v_t.shape[1]} samples, best of {repeat} rounds; "
               "speed ratio against scipy.signal.sosfilt running the same sections (grey crosses in the plot)."),
        variants=variants, references=references,
        extra_columns=[("rate2", "rate2 error", ".3f"), ("delay", "delay (ms)", ".2f")],
        ratio_reference="scipy.signal.sosfilt, same sections and data",
    )


def _detector_features(weights, n_scenes: int) -> np.ndarray:
    from .detector.synthetic import synthetic_scene

    x = np.concatenate([synthetic_scene(seed=s, n_ridges=6).features for s in range(n_scenes)], axis=-1)
    rms = np.sqrt(np.mean(x**2, axis=(0, 2)))
    # unit rms after the weights' normalisation, as in training
    return weights.input_mean[None, :, None] + x / rms[None, :, None] / weights.input_gain[None, :, None]


def _bench_detector(quick: bool, progress: _Progress) -> KernelReport:
    from scipy.special import expit

    from . import _core
    from .detector import SlipDetector, reference_run

    n_scenes, repeat, repeat_ref = (3, 5, 2) if quick else (10, 7, 3)
    weights = SlipDetector.default().weights
    x = _detector_features(weights, n_scenes)
    n = x.shape[2]
    bar = progress.bar("detector", 4 + repeat + 1)
    ref_s, _, ref_p = reference_run(weights, x)
    grid = np.linspace(-100.0, 100.0, 2_000_001)
    cases, timed = [], []
    for dt in (np.float64, np.float32):
        g = grid.astype(dt)
        g_ref = expit(g.astype(np.float64))
        xc = np.ascontiguousarray(x, dtype=dt)
        for act in ("exact", "fast"):
            det = SlipDetector(weights, dtype=dt, activation=act)
            ys, _, yp = det.run(xc)
            err = max(float(np.max(np.abs(ys.astype(np.float64) - ref_s))),
                      float(np.max(np.abs(yp.astype(np.float64) - ref_p))))
            y_sig = _core.detector_sigmoid(g, act, det.simd_path)  # type: ignore[call-overload]
            sig = float(np.max(np.abs(y_sig.astype(np.float64) - g_ref)))
            cases.append((f"{np.dtype(dt).name} {act}", err,
                          {"sigmoid": sig, "path": det.simd_path, "dtype": np.dtype(dt).name, "activation": act}))
            timed.append(lambda det=det, xc=xc: det.run(xc))
            bar.update()
    secs = [t / n for t in _best_times(timed, repeat, bar.update)]
    t_ref = _best_times([lambda: reference_run(weights, x)], repeat_ref)[0] / n
    bar.update()
    bar.close()
    variants = [Variant(label, err, t, t_ref / t, extra) for (label, err, extra), t in zip(cases, secs)]
    return KernelReport(
        name="detector",
        title=f"slip detector: SlipDetector.run, default weights (H = {weights.n_hidden}), 6 ridges",
        error_name="max |y - y_ref| (y_slip, y_pred)",
        unit="tick (6 ridges)", time_scale=1e9, time_unit="ns",
        notes=(f"{n_scenes} synthetic stick-slip scenes (`tactile_mirror.detector.synthetic`), 6 ridges x {n} "
               "ticks, features scaled to the weights' input normalisation; error against the float64 numpy "
               f"recurrence, which is also the speed reference. Time: best of {repeat} rounds of block calls "
               f"(numpy: best of {repeat_ref}). sigmoid: "
               "the kernel's sigmoid alone, max |error| against scipy.special.expit over 2e6 points in "
               "[-100, 100] (documented in jordan_mlp.hpp: fast <= 4.7e-10 in float64, <= 1.9e-7 in float32)."),
        variants=variants, references=[Reference("numpy recurrence, float64 (error reference)", t_ref)],
        extra_columns=[("sigmoid", "sigmoid error", ".1e")],
        ratio_reference="numpy float64 recurrence (detector.reference_run)", ratio_seconds=t_ref,
    )


def _bench_contact(quick: bool, progress: _Progress) -> KernelReport:
    from . import scenes
    from .contact import RidgeGeometry, ridge_model, simulate

    sizes, ref_size = ((0.4e-3, 0.3e-3), 0.2e-3) if quick else ((0.4e-3, 0.3e-3, 0.2e-3, 0.15e-3, 0.1e-3), 0.075e-3)
    duration = 1.3
    base = scenes.paper("fig6", duration=duration, outputs=frozenset({"stress"}))
    default_h = RidgeGeometry().mesh_size
    bar = progress.bar("contact", len(sizes) + 1)

    def run_mesh(h):
        g = RidgeGeometry(mesh_size=h, contact_mesh_size=h / 4)
        model = ridge_model(g)  # built (and timed) once, then cached
        t0 = time.perf_counter()
        res = simulate(dataclasses.replace(base, geometry=g))
        secs = (time.perf_counter() - t0) / res.t.size
        bar.update()
        return model, secs, res

    def label(h):
        return f"h = {h * 1e3:.3g} mm" + (" (default)" if math.isclose(h, default_h) else "")

    m_ref, t_ref, ref = run_mesh(ref_size)
    scale = float(np.max(np.abs(ref.stress)))
    variants = []
    for h in sizes:
        m, secs, res = run_mesh(h)
        diff = res.stress - ref.stress
        variants.append(Variant(label(h), float(np.sqrt(np.mean(diff**2))) / scale, secs, t_ref / secs,
                                {"max": float(np.max(np.abs(diff))) / scale, "dofs": m.n_dofs,
                                 "nodes": m.n_nodes, "setup": m.setup_seconds, "h": h}))
    bar.close()
    return KernelReport(
        name="contact",
        title=f"contact model: fig6 scene to {duration:g} s ({ref.t.size} steps at 1 kHz), mesh size h",
        error_name="rms strip-stress error / peak",
        unit="step", time_scale=1e3, time_unit="ms",
        notes=(f"Reference: {label(ref_size)} ({m_ref.n_dofs} DOFs), run in the same report; errors over all "
               "strip stresses and steps relative to the peak stress (max: the largest single difference, "
               "dominated by the timing of the slip front). Time: one `simulate` run, model setup (mesh, "
               "assembly, condensation; once per geometry) excluded and listed apart."),
        variants=variants,
        references=[Reference(f"{label(ref_size)} (error reference)", t_ref,
                              extra={"dofs": m_ref.n_dofs, "nodes": m_ref.n_nodes, "setup": m_ref.setup_seconds})],
        extra_columns=[("max", "max error", ".1e"), ("dofs", "DOFs", "d"), ("nodes", "contact nodes", "d"),
                       ("setup", "setup (s)", ".2f")],
        ratio_reference=f"reference mesh {label(ref_size)}", ratio_seconds=t_ref,
    )


_BENCHES = {"filters": _bench_filters, "estimator": _bench_estimator, "detector": _bench_detector,
            "contact": _bench_contact}


# ---------------------------------------------------------------- report
@dataclass
class BenchReport:
    """The measured kernels and where they ran."""

    kernels: dict
    quick: bool
    environment: dict
    seconds: float = 0.0

    # ---- markdown
    def markdown(self) -> str:
        env = self.environment
        where = (f"tactile-mirror {env['version']}, filter SIMD path {env['simd_path']}, "
                 f"{env['machine']}, {env['cpus']} CPUs, Python {env['python']}, numpy {env['numpy']}, "
                 f"scipy {env['scipy']}; threads: {env['threads']}; {'quick' if self.quick else 'full'} run of "
                 f"{self.seconds:.0f} s on {env['date']}.")
        how = ("Errors against references computed in the same run; speed ratio = reference time / variant "
               "time in the same run (> 1: faster). Pareto: no other variant of the kernel is both at least as "
               "accurate and at least as fast. Variants are timed in turn, round after round, and keep their "
               "best round; still, on a shared machine run times move between runs, so a Pareto flag that rests "
               "on a time difference of a few tens of per cent may change from run to run.")
        lines = ["# Run time against error", "", where, "", how, ""]
        for k in self.kernels.values():
            lines += [f"## {k.title}", "", k.notes, ""]
            t_head = f"{k.time_unit} per {k.unit}"
            extra = [h for _, h, _ in k.extra_columns]
            err_head = _md(k.error_name)
            lines.append("| variant | " + " | ".join([err_head, *extra, t_head, "speed ratio", "Pareto"]) + " |")
            lines.append("|---|" + "|".join("---:" for _ in range(len(extra) + 3)) + "|---|")
            for r in k.references:
                if r.error is None:
                    err = "reference"
                    cells = [_fmt(r.extra.get(key), spec) for key, _, spec in k.extra_columns]
                    lines.append(f"| *{r.label}* | {err} | " + " | ".join(
                        [*cells, _fmt_time(r.seconds * k.time_scale), "1", ""]) + " |")
            for v in k.variants:
                cells = [_fmt(v.extra.get(key), spec) for key, _, spec in k.extra_columns]
                lines.append(f"| {v.label} | {v.error:.2e} | " + " | ".join(
                    [*cells, _fmt_time(v.seconds * k.time_scale), f"{v.ratio:.3g}",
                     "**yes**" if v.pareto else ""]) + " |")
            speed_refs = [r for r in k.references if r.error is not None]
            if speed_refs:
                lines += ["", f"Speed references ({k.ratio_reference}):", "",
                          f"| reference | {err_head} | {t_head} |", "|---|---:|---:|"]
                lines += [f"| {r.label} | {r.error:.2e} | {_fmt_time(r.seconds * k.time_scale)} |"
                          for r in speed_refs]
            lines += ["", f"Speed ratio against: {k.ratio_reference}. Kernel measured in {k.seconds_total:.1f} s.",
                      ""]
        lines.append(f"Plot: `{PNG_NAME}`.")
        return "\n".join(lines) + "\n"

    # ---- figure
    def figure(self):
        """Matplotlib figure: one panel per kernel, error against run time, log scales."""
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        ks = list(self.kernels.values())
        ncols = 1 if len(ks) == 1 else 2
        nrows = math.ceil(len(ks) / ncols)
        fig, axes = plt.subplots(nrows, ncols, figsize=(7.2 * ncols, 5.4 * nrows), squeeze=False)
        labels = [_panel(ax, k) for ax, k in zip(axes.ravel(), ks)]
        for ax in axes.ravel()[len(ks):]:
            ax.set_visible(False)
        fig.suptitle(f"Run time against error ({'quick' if self.quick else 'full'} run, "
                     f"{self.environment['machine']}, SIMD {self.environment['simd_path']}); "
                     "filled: Pareto-optimal", fontsize=11)
        fig.tight_layout()
        renderer = fig.canvas.get_renderer()
        for ax, (items, points) in zip(axes.ravel(), labels):
            _place_labels(ax, items, points, renderer)
        return fig

    # ---- json
    def as_dict(self) -> dict:
        return {"quick": self.quick, "seconds": self.seconds, "environment": self.environment,
                "kernels": {name: dataclasses.asdict(k) for name, k in self.kernels.items()}}

    def write(self, out) -> dict:
        """Write ``bench_report.md``, ``bench_pareto.png`` and ``bench_report.json`` into ``out``."""
        from .plots import save

        out = pathlib.Path(out)
        out.mkdir(parents=True, exist_ok=True)
        paths = {"markdown": out / MD_NAME, "figure": out / PNG_NAME, "json": out / JSON_NAME}
        paths["markdown"].write_text(self.markdown())
        paths["json"].write_text(json.dumps(self.as_dict(), indent=1, default=_json_default))
        save(self.figure(), paths["figure"])
        return paths


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _md(text: str) -> str:
    """Text for a markdown table cell."""
    return text.replace("|", "\\|")


def _fmt(value, spec: str) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    return format(value, spec)


def _fmt_time(x: float) -> str:
    return f"{x:.3g}" if x < 1000 else f"{x:.0f}"


_PARETO_COLOR = "tab:blue"


def _plain(v, _pos=None) -> str:
    return f"{v:g}"


def _plain_log_axis(axis, lo: float, hi: float, suffix: str = "") -> None:
    """Plain numbers on a log axis; minor ticks labelled at 2, 3, 5 (2 and 5 over 2-3 decades)."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    axis.set_major_formatter(FuncFormatter(lambda v, _p: f"{v:g}{suffix}"))
    if hi / lo < 1000:
        marks = (2, 3, 5) if hi / lo < 100 else (2, 5)

        def minor(v, _p):
            if v <= 0:
                return ""
            m = v / 10 ** math.floor(math.log10(v) + 1e-9)
            return f"{v:g}{suffix}" if any(abs(m - k) < 1e-6 for k in marks) else ""

        axis.set_minor_formatter(FuncFormatter(minor))
    else:
        axis.set_minor_formatter(NullFormatter())


def _panel(ax, k: KernelReport) -> tuple[list, list]:
    """Draw one kernel; return the points to label, (x, y, text, pareto), and every marker, (x, y)."""
    errs = np.array([v.error for v in k.variants])
    times = np.array([v.seconds for v in k.variants]) * k.time_scale
    errs = np.maximum(errs, np.finfo(np.float64).tiny)  # an exact match has no place on a log axis
    pareto = np.array([v.pareto for v in k.variants])
    ax.set_xscale("log")
    ax.set_yscale("log")
    for r in k.references:
        if r.error is None:
            y = r.seconds * k.time_scale
            ax.axhline(y, color="0.45", ls="--", lw=1)
            ax.annotate(r.label, (0.01, y), xycoords=("axes fraction", "data"), xytext=(0, 3),
                        textcoords="offset points", fontsize=7.5, color="0.3", va="bottom")
    speed_refs = [r for r in k.references if r.error is not None]
    if speed_refs:
        ax.scatter([r.error for r in speed_refs], [r.seconds * k.time_scale for r in speed_refs], marker="x",
                   color="0.6", s=22, lw=1, label=k.ratio_reference.split(",")[0] + " (same sections)", zorder=2)
    if np.any(~pareto):
        ax.scatter(errs[~pareto], times[~pareto], facecolors="none", edgecolors="0.45", s=36, zorder=3,
                   label="dominated")
    ax.scatter(errs[pareto], times[pareto], color=_PARETO_COLOR, s=48, zorder=4, label="Pareto-optimal")
    order = np.argsort(errs[pareto])
    pe, pt = errs[pareto][order], times[pareto][order]
    if pe.size > 1:
        ax.step(pe, pt, where="post", color=_PARETO_COLOR, lw=1, alpha=0.6, zorder=3)
    all_e = [*errs, *(r.error for r in speed_refs)]
    all_t = [*times, *(r.seconds * k.time_scale for r in k.references)]
    lo_x, hi_x = min(all_e), max(all_e)
    span_x = max(hi_x / lo_x, 10.0)
    ax.set_xlim(lo_x / span_x**0.08, hi_x * span_x**0.3)  # room for labels on the right
    lo_y, hi_y = min(all_t) / 1.6, max(all_t) * 1.8
    ax.set_ylim(lo_y, hi_y)
    _plain_log_axis(ax.yaxis, lo_y, hi_y)
    ax.set_xlabel(f"error: {k.error_name}")
    ax.set_ylabel(f"run time, {k.time_unit} per {k.unit}")
    ax.set_title(k.title, fontsize=9.5)
    ax.grid(True, which="major", alpha=0.3)
    if k.ratio_seconds is not None:
        r_s = k.ratio_seconds * k.time_scale
        sec = ax.secondary_yaxis("right", functions=(lambda y, r_s=r_s: r_s / np.maximum(y, 1e-300),
                                                     lambda q, r_s=r_s: r_s / np.maximum(q, 1e-300)))
        sec.set_ylabel("speed ratio to the reference", fontsize=8)
        _plain_log_axis(sec.yaxis, r_s / hi_y, r_s / lo_y, suffix="x")
    ax.legend(fontsize=7, loc="lower left")
    label_all = len(k.variants) <= 8
    items = [(e, t, v.label, v.pareto) for v, e, t in zip(k.variants, errs, times) if v.pareto or label_all]
    points = [*zip(errs, times), *((r.error, r.seconds * k.time_scale) for r in speed_refs)]
    return items, points


_OFFSETS = ((6, 3, "left", "bottom"), (6, -3, "left", "top"), (-6, 3, "right", "bottom"),
            (-6, -3, "right", "top"), (6, 12, "left", "bottom"), (6, -12, "left", "top"),
            (-6, 12, "right", "bottom"), (-6, -12, "right", "top"))


def _place_labels(ax, items, points, renderer) -> None:
    """Label points where the text covers no other label, no other point and stays in the axes."""
    pts = ax.transData.transform(points) if points else np.zeros((0, 2))
    taken: list = []
    box = ax.get_window_extent(renderer)
    for x, y, text, pareto in items:
        own = ax.transData.transform([(x, y)])[0]
        kw = {"fontsize": 8 if pareto else 7, "color": _PARETO_COLOR if pareto else "0.3",
              "fontweight": "bold" if pareto else "normal", "zorder": 5}
        first = None
        for dx, dy, ha, va in _OFFSETS:
            ann = ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset points", ha=ha, va=va, **kw)
            bb = ann.get_window_extent(renderer)
            hits_point = any(bb.x0 - 4 < qx < bb.x1 + 4 and bb.y0 - 4 < qy < bb.y1 + 4
                             for qx, qy in pts if abs(qx - own[0]) + abs(qy - own[1]) > 0.5)
            inside = bb.x0 >= box.x0 and bb.x1 <= box.x1 and bb.y0 >= box.y0 and bb.y1 <= box.y1
            if inside and not hits_point and not any(bb.overlaps(o) for o in taken):
                taken.append(bb)
                if first is not None:
                    first.remove()
                break
            if first is None:
                first = ann
            else:
                ann.remove()
        else:  # nowhere free: keep the first position
            if first is not None:
                taken.append(first.get_window_extent(renderer))


def _environment() -> dict:
    import scipy

    from . import __version__, simd_path

    threads = ", ".join(f"{v}={os.environ[v]}" for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")
                        if v in os.environ) or "library defaults"
    return {"version": __version__, "simd_path": simd_path(), "machine": platform.machine(),
            "processor": platform.processor(), "cpus": os.cpu_count(), "python": platform.python_version(),
            "numpy": np.__version__, "scipy": scipy.__version__, "threads": threads,
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}


def _check_kernels(kernels: Iterable[str]) -> list:
    if isinstance(kernels, str):
        kernels = [kernels]
    names = list(dict.fromkeys(kernels))
    bad = [k for k in names if k not in KERNELS]
    if bad:
        raise ValueError(f"kernels: unknown {', '.join(map(repr, bad))}; choose from {', '.join(KERNELS)}")
    if not names:
        raise ValueError("kernels: choose at least one of " + ", ".join(KERNELS))
    return [k for k in KERNELS if k in names]


def run(kernels: Iterable[str] = KERNELS, quick: bool = False, progress: bool = True) -> BenchReport:
    """Measure the kernels and return the report (nothing written).

    Parameters
    ----------
    kernels : iterable of str
        A subset of :data:`KERNELS`.
    quick : bool
        Small sizes (all kernels in well under half a minute); the default run takes
        a few minutes.
    progress : bool
        Show a progress bar per kernel (on stderr).
    """
    names = _check_kernels(kernels)
    prog = _Progress(progress)
    t0 = time.perf_counter()
    out = {}
    for name in names:
        t_k = time.perf_counter()
        k = _BENCHES[name](bool(quick), prog)
        k.seconds_total = time.perf_counter() - t_k
        k.check()
        out[name] = k
    return BenchReport(out, bool(quick), _environment(), time.perf_counter() - t0)


def bench_report(out, kernels: Iterable[str] = KERNELS, quick: bool = False, progress: bool = True) -> BenchReport:
    """Measure the kernels and write ``bench_report.md``, ``bench_pareto.png`` and
    ``bench_report.json`` into the folder ``out`` (created if needed, before any work)."""
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = _check_kernels(kernels)
    report = run(names, quick=quick, progress=progress)
    report.write(out)
    return report
