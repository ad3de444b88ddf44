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
    driven by :func:`tactile_mirror.lab.testing.known_load` with 1 mV rms sensor noise,
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

The measuring itself (timing rounds, error functions, the filter, estimator and
detector measurements) lives in :mod:`tactile_mirror.lab.measure`, which the scripts in
``bench/`` call too; the figure is :func:`tactile_mirror.lab.plots.pareto_figure`.

Run times are the best of a few wall-clock rounds in which every variant of a kernel
runs in turn (one run for the contact model); on a shared machine compare the speed
ratios, which come from the same run, rather than absolute times. Run with ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1``.

Example
-------
>>> from tactile_mirror.lab.benchmark import bench_report
>>> report = bench_report("bench-out", quick=True)     # doctest: +SKIP
>>> report.kernels["filters"].variants[0].error        # doctest: +SKIP
"""
from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from tactile_mirror.files import write_text
from tactile_mirror.lab import measure
from tactile_mirror.lab.measure import extended_sosfilt

__all__ = [
    "KERNELS",
    "KERNEL_BENCHES",
    "BenchReport",
    "KernelReport",
    "Reference",
    "Variant",
    "bench_report",
    "extended_sosfilt",
    "pareto_front",
    "run",
]

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
class _Progress:
    """A tqdm bar per kernel, or nothing."""

    def __init__(self, enabled: bool):
        self.enabled = enabled

    def bar(self, name: str, total: int):
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=f"bench {name}", unit="variant", disable=not self.enabled, leave=True,
                    file=sys.stderr)


# ---------------------------------------------------------------- kernels
def _bench_filters(quick: bool, progress: _Progress) -> KernelReport:
    import scipy.signal as ss

    fs = 10_000.0
    sos = ss.butter(4, 0.5, "highpass", fs=fs, output="sos")
    channels = 12
    n_err, n_time, repeat = (4_000, 40_000, 3) if quick else (20_000, 200_000, 5)
    bar = progress.bar("filters", 7 + repeat)
    cases = measure.filter_variants(sos, channels, n_err, n_time, repeat, tick=bar.update)
    bar.close()
    t_scipy = cases[0].seconds
    variants = [Variant(c.label, c.error, c.seconds, t_scipy / c.seconds,
                        {"dtype": c.dtype, "structure": c.structure, "api": c.api}) for c in cases]
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


def _bench_estimator(quick: bool, progress: _Progress) -> KernelReport:
    import scipy.signal as ss

    from tactile_mirror.circuit import PVDFCircuit
    from tactile_mirror.estimator import StressRateEstimator

    fs, duration, noise, channels = 1000.0, 2.0, 1e-3, 12
    tile, repeat = (10, 3) if quick else (50, 5)
    orders = (2, 3, 4)
    bandwidths = (50.0, 100.0, 200.0, 300.0)
    circuit = PVDFCircuit()
    # independent noise per strip
    v, u, rate_true, rate2_true = measure.estimator_signals(circuit, fs, duration, noise, channels, seed=0)
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
        ours_err = measure.estimator_errors(rate, rate2, rate_true, rate2_true)
        ref_err = measure.estimator_errors(r1, r2, rate_true, rate2_true)
        measured.append((ours_err["rate"], ours_err["rate2"], ref_err["rate"], ref_err["rate2"]))

        def ours(est=est):
            est.reset()
            est.process(v_t, u_t)

        def theirs(sos_v=sos_v, sos_u=sos_u):
            ss.sosfilt(sos_v, v_t)
            ss.sosfilt(sos_u, u_t)

        timed += [ours, theirs]
        bar.update()
    secs = [t / v_t.size for t in measure.best_times(timed, repeat, bar.update)]
    bar.close()
    variants, references = [], []
    for i, ((order, bw), (e1, e2, e1_ref, e2_ref)) in enumerate(zip(designs, measured)):
        t_ours, t_ref = secs[2 * i], secs[2 * i + 1]
        label = f"order {order}, {bw:g} Hz"
        variants.append(Variant(label, e1, t_ours, t_ref / t_ours,
                                {"rate2": e2, "delay": measure.lowpass_delay_ms(order, bw, fs)}))
        references.append(Reference(f"scipy, {label}", t_ref, e1_ref, {"rate2": e2_ref}))
    return KernelReport(
        name="estimator",
        title="stress-rate estimator: low-pass order x bandwidth (Butterworth), fs = 1 kHz",
        error_name="rms(rate error) / rms(rate)",
        unit="channel-sample (both outputs)", time_scale=1e9, time_unit="ns",
        notes=(f"The default PVDF circuit driven by `tactile_mirror.lab.testing.known_load` (loading, ramp, stop, "
               f"slip), {noise * 1e3:g} mV rms sensor noise on v_out and u_out, {channels} strips x "
               f"{duration:g} s; error against the analytic stress rate (rate2: the same for the 2nd-order rate, "
               f"from u_out); delay: low-frequency group delay of the low-pass. Time: "
               f"`StressRateEstimator.process` on {channels} x {v_t.shape[1]} samples, best of {repeat} rounds; "
               "speed ratio against scipy.signal.sosfilt running the same sections (grey crosses in the plot)."),
        variants=variants, references=references,
        extra_columns=[("rate2", "rate2 error", ".3f"), ("delay", "delay (ms)", ".2f")],
        ratio_reference="scipy.signal.sosfilt, same sections and data",
    )


def _bench_detector(quick: bool, progress: _Progress) -> KernelReport:
    from tactile_mirror.detector import SlipDetector, reference_run

    n_scenes, repeat, repeat_ref = (3, 5, 2) if quick else (10, 7, 3)
    weights = SlipDetector.paper().weights
    x = measure.detector_features(weights, n_scenes)
    n = x.shape[2]
    bar = progress.bar("detector", 4 + repeat + 1)
    rows = measure.detector_variants(weights, x, repeat, tick=bar.update)
    t_ref = measure.best_times([lambda: reference_run(weights, x)], repeat_ref)[0] / n
    bar.update()
    bar.close()
    variants = [Variant(r["label"], r["error"], r["seconds"], t_ref / r["seconds"],
                        {"sigmoid": measure.sigmoid_error(np.dtype(r["dtype"]).type, r["activation"], r["path"]),
                         "path": r["path"], "dtype": r["dtype"], "activation": r["activation"]}) for r in rows]
    return KernelReport(
        name="detector",
        title=f"slip detector: SlipDetector.run, the paper's net (H = {weights.n_hidden}), 6 ridges",
        error_name="max |y - y_ref| (y_slip, y_pred)",
        unit="tick (6 ridges)", time_scale=1e9, time_unit="ns",
        notes=(f"{n_scenes} synthetic stick-slip scenes (`tactile_mirror.lab.detector.synthetic`), 6 ridges x {n} "
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
    from tactile_mirror import scenes
    from tactile_mirror.contact import ridge_model, simulate
    from tactile_mirror.geometry import RidgeGeometry

    sizes, ref_size = ((0.4e-3, 0.3e-3), 0.2e-3) if quick else ((0.4e-3, 0.3e-3, 0.2e-3, 0.15e-3, 0.1e-3), 0.075e-3)
    duration = 1.3
    base = scenes.paper("fig6", duration=duration, outputs=frozenset({"stress"}))
    default_h = RidgeGeometry().mesh_size
    bar = progress.bar("contact", len(sizes) + 2)

    def run_mesh(h, stepping="auto"):
        g = RidgeGeometry(mesh_size=h, contact_mesh_size=h / 4)
        model = ridge_model(g)  # built (and timed) once, then cached
        t0 = time.perf_counter()
        res = simulate(dataclasses.replace(base, geometry=g), stepping=stepping)
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
    # the per-sample reference stepping on the default mesh (the finest measured one in
    # the quick run): the same error, its own time
    h_every = min(sizes, key=lambda h: abs(h - default_h))
    m, secs, res = run_mesh(h_every, "every")
    diff = res.stress - ref.stress
    variants.append(Variant(label(h_every) + ", stepping 'every'", float(np.sqrt(np.mean(diff**2))) / scale, secs,
                            t_ref / secs, {"max": float(np.max(np.abs(diff))) / scale, "dofs": m.n_dofs,
                                           "nodes": m.n_nodes, "setup": m.setup_seconds, "h": h_every}))
    bar.close()
    return KernelReport(
        name="contact",
        title=f"contact model: fig6 scene to {duration:g} s ({ref.t.size} steps at 1 kHz), mesh size h",
        error_name="rms strip-stress error / peak",
        unit="step", time_scale=1e3, time_unit="ms",
        notes=(f"Reference: {label(ref_size)} ({m_ref.n_dofs} DOFs), run in the same report; errors over all "
               "strip stresses and steps relative to the peak stress (max: the largest single difference, "
               "dominated by the timing of the slip front). Time: one `simulate` run with the event-driven "
               "stepping ('auto', the default) unless the label says 'every' (a solve at every sample, "
               "the reference stepping), model setup (mesh, assembly, condensation; once per geometry) "
               "excluded and listed apart."),
        variants=variants,
        references=[Reference(f"{label(ref_size)} (error reference)", t_ref,
                              extra={"dofs": m_ref.n_dofs, "nodes": m_ref.n_nodes, "setup": m_ref.setup_seconds})],
        extra_columns=[("max", "max error", ".1e"), ("dofs", "DOFs", "d"), ("nodes", "contact nodes", "d"),
                       ("setup", "setup (s)", ".2f")],
        ratio_reference=f"reference mesh {label(ref_size)}", ratio_seconds=t_ref,
    )


#: The measuring function of each kernel, in report order: ``(quick, progress) ->
#: KernelReport``. A new kernel joins the report (and ``tactile-mirror bench --kernels``)
#: by adding its function here.
KERNEL_BENCHES: dict[str, Callable[[bool, _Progress], KernelReport]] = {
    "filters": _bench_filters, "estimator": _bench_estimator, "detector": _bench_detector,
    "contact": _bench_contact}

#: Kernels measured by the report, in report order.
KERNELS = tuple(KERNEL_BENCHES)


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
        """Matplotlib figure: one panel per kernel, error against run time, log scales
        (:func:`tactile_mirror.lab.plots.pareto_figure`)."""
        from tactile_mirror.lab.plots import pareto_figure

        return pareto_figure(self)

    # ---- json
    def as_dict(self) -> dict:
        return {"quick": self.quick, "seconds": self.seconds, "environment": self.environment,
                "kernels": {name: dataclasses.asdict(k) for name, k in self.kernels.items()}}

    def write(self, out) -> dict:
        """Write ``bench_report.md``, ``bench_pareto.png`` and ``bench_report.json`` into ``out``."""
        from tactile_mirror.lab.plots import save

        out = pathlib.Path(out)
        out.mkdir(parents=True, exist_ok=True)
        paths = {"markdown": out / MD_NAME, "figure": out / PNG_NAME, "json": out / JSON_NAME}
        write_text(paths["markdown"], self.markdown())
        write_text(paths["json"], json.dumps(self.as_dict(), indent=1, default=_json_default))
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
        k = KERNEL_BENCHES[name](bool(quick), prog)
        k.seconds_total = time.perf_counter() - t_k
        k.check()
        out[name] = k
    return BenchReport(out, bool(quick), measure.environment(), time.perf_counter() - t0)


def bench_report(out, kernels: Iterable[str] = KERNELS, quick: bool = False, progress: bool = True) -> BenchReport:
    """Measure the kernels and write ``bench_report.md``, ``bench_pareto.png`` and
    ``bench_report.json`` into the folder ``out`` (created if needed, before any work)."""
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = _check_kernels(kernels)
    report = run(names, quick=quick, progress=progress)
    report.write(out)
    return report
