"""The run-time-against-error report (``tactile-mirror bench``): the quick run of every
kernel, what its numbers must satisfy, its files, and the command. No timing is asserted."""
import json
import math

import numpy as np
import pytest
import scipy.signal as ss
from tactile_mirror.cli import main
from tactile_mirror.lab.benchmark import (
    JSON_NAME,
    KERNELS,
    MD_NAME,
    PNG_NAME,
    bench_report,
    extended_sosfilt,
    pareto_front,
)

# Documented in jordan_mlp.hpp: the fast sigmoid against scipy.special.expit over 2e6
# points in [-100, 100].
FAST_SIGMOID_BOUND = {"float64": 4.7e-10, "float32": 1.9e-7}


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    return out, bench_report(out, quick=True, progress=False)


def by_label(kernel):
    return {v.label: v for v in kernel.variants}


def test_every_kernel_has_rows_with_finite_positive_errors_and_times(quick):
    _, report = quick
    assert list(report.kernels) == list(KERNELS)
    for k in report.kernels.values():
        assert len(k.variants) >= 2, k.name
        for v in k.variants:
            assert math.isfinite(v.error) and v.error > 0, (k.name, v.label, v.error)
            assert math.isfinite(v.seconds) and v.seconds > 0, (k.name, v.label)
            assert math.isfinite(v.ratio) and v.ratio > 0, (k.name, v.label)
        for r in k.references:
            assert math.isfinite(r.seconds) and r.seconds > 0
        if k.ratio_seconds is not None:  # one reference time for every ratio
            for v in k.variants:
                assert v.ratio == pytest.approx(k.ratio_seconds / v.seconds, rel=1e-12)


def test_filters_float64_beats_float32_and_delta_beats_tdf2(quick):
    _, report = quick
    rows = by_label(report.kernels["filters"])
    f64 = [v.error for v in rows.values() if v.extra["dtype"] == "float64"]
    f32 = [v.error for v in rows.values() if v.extra["dtype"] == "float32"]
    assert len(f64) == 3 and len(f32) == 4
    assert max(f64) < min(f32)
    for api in ("scipy", "sosfilt"):
        for structure in ("tdf2", "delta"):
            pair = {v.extra["dtype"]: v.error for v in rows.values()
                    if v.extra["api"] == api and v.extra["structure"] == structure}
            if len(pair) == 2:
                assert pair["float64"] < pair["float32"], (api, structure, pair)
    # poles near z = 1: the delta sections keep float64 at round-off and float32 usable
    assert rows["sosfilt float64 delta"].error < 1e-14 < rows["sosfilt float64 tdf2 (auto)"].error
    assert rows["SosFilter float32 delta (auto)"].error < 1e-6 < rows["sosfilt float32 tdf2"].error
    # scipy float64 is the speed reference
    assert rows["scipy.signal.sosfilt float64"].ratio == 1.0


def test_detector_errors_and_the_fast_sigmoid_bound(quick):
    _, report = quick
    rows = by_label(report.kernels["detector"])
    assert set(rows) == {"float64 exact", "float64 fast", "float32 exact", "float32 fast"}
    for dt, bound in FAST_SIGMOID_BOUND.items():
        assert rows[f"{dt} fast"].extra["sigmoid"] <= bound
    assert rows["float64 exact"].extra["sigmoid"] <= 1e-15
    assert rows["float64 exact"].error < 1e-10  # the C++ kernel is the numpy recurrence
    for act in ("exact", "fast"):
        assert rows[f"float64 {act}"].error < rows[f"float32 {act}"].error
    assert all(v.error < 1e-2 for v in rows.values())


def test_estimator_rows_against_the_analytic_rate(quick):
    _, report = quick
    k = report.kernels["estimator"]
    assert len(k.variants) == len(k.references) == 12
    for v, r in zip(k.variants, k.references):
        assert 0 < v.error < 1 and v.extra["rate2"] > 0
        # the speed reference runs the very same sections: the same error to round-off
        assert r.error == pytest.approx(v.error, rel=1e-9)
        assert v.ratio == pytest.approx(r.seconds / v.seconds, rel=1e-12)
    rows = by_label(k)
    for order in (2, 3, 4):  # a wider band has less delay
        delays = [rows[f"order {order}, {bw} Hz"].extra["delay"] for bw in (50, 100, 200, 300)]
        assert np.all(np.diff(delays) < 0)


def test_contact_rows_against_a_finer_mesh(quick):
    _, report = quick
    k = report.kernels["contact"]
    (ref,) = k.references
    dofs = [v.extra["dofs"] for v in k.variants]
    assert all(d < ref.extra["dofs"] for d in dofs)
    for v in k.variants:
        assert v.error < v.extra["max"] < 1.0


def test_pareto_flags_are_consistent(quick):
    _, report = quick
    for k in report.kernels.values():
        assert any(v.pareto for v in k.variants)
        for v in k.variants:
            dominated_by = [w.label for w in k.variants if w is not v and w.error <= v.error
                            and w.seconds <= v.seconds and (w.error < v.error or w.seconds < v.seconds)]
            assert v.pareto == (not dominated_by), (k.name, v.label, dominated_by)


def test_pareto_front_by_hand():
    err = [1.0, 2.0, 0.5, 2.0, 1.0, 3.0]
    sec = [1.0, 0.5, 3.0, 0.5, 2.0, 0.4]
    # (1,2) is dominated by (1,1); the two (2, 0.5) tie and are both kept
    assert pareto_front(err, sec).tolist() == [True, True, True, True, False, True]
    assert pareto_front([1.0], [1.0]).tolist() == [True]
    with pytest.raises(ValueError, match="one length"):
        pareto_front([1.0, 2.0], [1.0])


def test_files_are_written(quick):
    out, report = quick
    md = (out / MD_NAME).read_text()
    for k in report.kernels.values():
        assert k.title in md
        for v in k.variants:
            assert f"| {v.label} | {v.error:.2e} |" in md
    png = (out / PNG_NAME).read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    data = json.loads((out / JSON_NAME).read_text())
    assert data["quick"] is True
    for name, k in report.kernels.items():
        assert [v["error"] for v in data["kernels"][name]["variants"]] == [v.error for v in k.variants]


def test_extended_reference_agrees_with_mpmath():
    mpmath = pytest.importorskip("mpmath")
    sos = ss.butter(4, 0.5, "highpass", fs=10_000.0, output="sos")
    x = np.random.default_rng(0).standard_normal((1, 1500))
    ref = extended_sosfilt(sos, x)
    assert ref.dtype == np.longdouble and ref.shape == x.shape
    with mpmath.workdps(40):
        y = [mpmath.mpf(float(v)) for v in x[0]]
        for b0, b1, b2, _, a1, a2 in (map(mpmath.mpf, row) for row in sos.tolist()):
            z1 = z2 = mpmath.mpf(0)
            for i, xi in enumerate(y):
                yi = b0 * xi + z1
                z1, z2 = b1 * xi - a1 * yi + z2, b2 * xi - a2 * yi
                y[i] = yi
        exact = np.array([float(v) for v in y])  # float64 is enough for the scale
        diff = max(abs(mpmath.mpf(str(r)) - v) for r, v in zip(ref[0], y))
    tol = 1e3 * float(np.finfo(np.longdouble).eps)  # ~1e-16 in 80-bit: 1000x better than float64 tdf2
    assert float(diff) / np.max(np.abs(exact)) < tol


def test_cli_bench_quick_writes_the_report(tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["bench", "--quick", "--kernels", "detector,filters", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Pareto-optimal" in text and str(out / MD_NAME) in text
    md = (out / MD_NAME).read_text()
    assert md.index("filters:") < md.index("slip detector:")  # report order, whatever the option's order
    assert "contact model" not in md and "stress-rate estimator" not in md
    assert (out / PNG_NAME).stat().st_size > 10_000


def test_cli_bench_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "usage: tactile-mirror bench" in text and "--kernels" in text and "--quick" in text


@pytest.mark.parametrize("argv,message", [
    (["bench", "--kernels", "filters,nope"], "comma-separated list"),
    (["bench", "--kernels", ","], "comma-separated list"),
    (["bench", "--quick=yes"], "ignored explicit argument"),
    (["bench", "--fast"], "unrecognized arguments"),
])
def test_cli_bench_bad_options(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_cli_bench_unusable_output_fails_before_any_work(tmp_path, capsys):
    target = tmp_path / "file"
    target.write_text("")
    assert main(["bench", "--quick", "--out", str(target)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error:") and "not a folder" in err
    assert main(["bench", "--quick", "--out", str(target / "sub")]) == 1  # parent is a file
    assert capsys.readouterr().err.startswith("error:")


# ---------------------------------------------------------------- one measuring path
def test_report_and_measure_functions_give_the_same_errors(quick):
    """The report's rows come from tactile_mirror.lab.measure: the same function on the same
    data gives the same errors (the times differ run to run)."""
    from tactile_mirror import PVDFCircuit, SlipDetector, StressRateEstimator
    from tactile_mirror.lab import measure

    _, report = quick
    sos = ss.butter(4, 0.5, "highpass", fs=10_000.0, output="sos")
    cases = measure.filter_variants(sos, 12, n_err=4_000, n_time=64, repeat=1)
    assert {c.label: c.error for c in cases} == {v.label: v.error for v in report.kernels["filters"].variants}
    weights = SlipDetector.paper().weights
    rows = measure.detector_variants(weights, measure.detector_features(weights, 3), repeat=1)
    assert {r["label"]: r["error"] for r in rows} == {v.label: v.error for v in report.kernels["detector"].variants}
    v, u, rate, rate2 = measure.estimator_signals(noise=1e-3, channels=12, seed=0)
    est = StressRateEstimator(PVDFCircuit(), 1000.0, 12, order=3, bandwidth=100.0)
    err = measure.estimator_errors(*est.process(v, u), rate, rate2)
    row = by_label(report.kernels["estimator"])["order 3, 100 Hz"]
    assert (err["rate"], err["rate2"]) == (row.error, row.extra["rate2"])


def test_bench_scripts_time_with_the_shared_functions():
    import importlib.util
    import pathlib

    from tactile_mirror.lab import measure

    path = pathlib.Path(__file__).resolve().parents[1] / "bench" / "common.py"
    spec = importlib.util.spec_from_file_location("bench_common", path)
    common = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(common)
    assert common.best_time is measure.best_time and common.timed is measure.timed


def test_measure_timing_and_errors():
    from tactile_mirror.lab import measure

    ticks = []
    calls = []
    t = measure.best_times([lambda: calls.append("a"), lambda: calls.append("b")], 3, tick=lambda: ticks.append(1))
    assert calls == ["a", "b"] * 3 and len(ticks) == 3 and all(x >= 0 for x in t)
    clock = iter(range(100)).__next__  # each call advances by 1
    assert measure.best_time(lambda: None, 4, clock=clock) == 1
    assert measure.timed(lambda: 7, 2)[1] == 7
    a = np.sin(np.arange(200) / 10.0)
    assert measure.rel_rms(a, a) == 0.0
    late = np.concatenate([np.zeros(5), a[:-5]])  # the estimate 5 samples late
    assert measure.rel_rms_aligned(late, a, max_shift=3) > 0.1
    assert measure.rel_rms_aligned(late, a, max_shift=8) == 0.0  # shifting back by 5 aligns them
    assert measure.rel_max(2 * a, a) == pytest.approx(1.0)
    assert measure.lowpass_delay_ms(2, 100.0, 1000.0) > 0
    with pytest.raises(ValueError, match="kind"):
        measure.lowpass_delay_ms(2, 100.0, 1000.0, kind="cheby")
    env = measure.environment()
    assert env["cpu_model"] and env["cpu_model"] in measure.environment_line(env)
    assert measure.markdown_table("t", ["a", "b"], [[1, 2]]).splitlines()[-1] == "| 1 | 2 |"


def test_reference_helpers_name_bad_arguments():
    from tactile_mirror.lab import measure

    with pytest.raises(ValueError, match="max_shift"):
        measure.rel_rms_aligned(np.ones(10), np.ones(10), max_shift=10)
    with pytest.raises(TypeError, match="max_shift"):
        measure.rel_rms_aligned(np.ones(10), np.ones(10), max_shift=2.0)
    assert measure.rel_rms_aligned(np.ones(10), np.ones(10), max_shift=9) == 0.0
    with pytest.raises(ValueError, match="a0"):
        measure.extended_sosfilt(np.array([[1.0, 0, 0, 0, 0.1, 0]]), np.ones(4))


def test_place_labels_keeps_labels_apart_and_inside():
    """The plot helper (tactile_mirror.lab.plots) puts every label where it covers no other
    label and stays in the axes, for a cluster of points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from tactile_mirror.lab.plots import place_labels

    fig, ax = plt.subplots(figsize=(5, 4))
    ax.set_xscale("log")
    ax.set_yscale("log")
    x = np.array([1e-6, 1.3e-6, 1.6e-6, 1e-3, 1.2e-3, 1e-9])
    y = np.array([10.0, 11.0, 12.0, 30.0, 31.0, 100.0])
    ax.scatter(x, y)
    ax.set_xlim(1e-10, 1e-1)
    ax.set_ylim(5, 200)
    fig.tight_layout()
    renderer = fig.canvas.get_renderer()
    items = [(xi, yi, f"variant {i}", i % 2 == 0) for i, (xi, yi) in enumerate(zip(x, y))]
    place_labels(ax, items, list(zip(x, y)), renderer)
    boxes = [t.get_window_extent(renderer) for t in ax.texts]
    assert len(boxes) == len(items)
    frame = ax.get_window_extent(renderer)
    for i, b in enumerate(boxes):
        assert frame.x0 <= b.x0 and b.x1 <= frame.x1 and frame.y0 <= b.y0 and b.y1 <= frame.y1
        assert not any(b.overlaps(o) for o in boxes[i + 1:])
    plt.close(fig)
