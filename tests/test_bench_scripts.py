"""Every script of ``bench/`` in its ``--quick`` mode, run in this process (imported from
``bench/``, its ``main`` called, its files written under a temporary folder), each checked by
the one number its ``main`` returns against a range that a broken study would leave, and by
the CPU model it prints with its tables. Smoke runs of the studies behind the docs: what they
measure is tested elsewhere; here, that they still run end to end and give sane numbers.
No timing is asserted beyond a finite positive time."""
import importlib
import json
import math
import pathlib
import sys

import pytest

BENCH = pathlib.Path(__file__).resolve().parents[1] / "bench"


@pytest.fixture(scope="module", autouse=True)
def _forget_the_scripts():
    """The scripts and their helper module are imported by their own names (``common``,
    ``report``, ...): gone from ``sys.modules`` after this file. (Within it they stay, so that
    the studies' quick scenes are simulated once for all of them.)"""
    before = set(sys.modules)
    yield
    for name in set(sys.modules) - before:
        module = sys.modules.get(name)
        if pathlib.Path(getattr(module, "__file__", None) or "/").parent == BENCH:
            del sys.modules[name]


@pytest.fixture
def run(monkeypatch, tmp_path, capsys):
    """``run(script, *args)``: ``bench/<script>.py``'s ``main([*args, "--quick"])`` in the
    temporary folder (a stray relative path lands there), with ``bench/`` on ``sys.path`` for
    this test only; returns ``main``'s number after checking that the run printed the CPU model."""
    from tactile_mirror.lab.measure import cpu_model

    monkeypatch.setattr(sys, "path", [str(BENCH), *sys.path])
    monkeypatch.chdir(tmp_path)

    def go(script, *args):
        value = importlib.import_module(script).main([*map(str, args), "--quick"])
        out = capsys.readouterr().out
        assert cpu_model() in out, f"{script}: the CPU model is not printed"
        return value

    return go


def sklearn():
    pytest.importorskip("sklearn", reason="the study's classifier is scikit-learn's (not a dependency)")


# ---------------------------------------------------------------- microbenchmarks
def test_bench_filters(run):
    # the float64 filter's largest error over the soak against a long-double reference, / peak
    assert 1e-14 < run("bench_filters") < 1e-8


def test_bench_estimator(run):
    # the best rms error of the stress-rate estimate against the load's true derivative
    assert 0.02 < run("bench_estimator") < 0.3


def test_bench_detector(run):
    # the C++ BPTT gradient against the numpy specification, largest difference / largest element
    assert 0.0 <= run("bench_detector") < 1e-10


def test_bench_pipeline(run):
    # the 6-ridge float64 tick inside C++, ns
    ns = run("bench_pipeline")
    assert math.isfinite(ns) and 10.0 < ns < 1e5


def test_bench_contact(run):
    # compiled event stepping against compiled per-sample stepping: the strip stresses, / peak
    assert 0.0 <= run("bench_contact") <= 1e-9


def test_mesh_study(run, tmp_path):
    # rms strip-stress error of the finest quick mesh (0.4 mm) against the 0.25 mm reference
    assert 1e-3 < run("mesh_study", "--out", tmp_path) < 2e-2
    assert (tmp_path / "mesh_study.json").is_file() and (tmp_path / "mesh_study.png").is_file()


def test_soak(run):
    # goals missed: rejection counts exact per kind, outputs finite, every tick counted
    assert run("soak") == 0


def test_report(run, tmp_path):
    # the filters kernel's most accurate variant, error / peak against extended precision
    assert 0.0 <= run("report", "--kernels", "filters", "--out", tmp_path) < 1e-12


# ---------------------------------------------------------------- the loop
def test_loop_envelope(run, tmp_path):
    # gross slips over the four laws on one report path at 5 mm/s: open loop slips, the laws hold
    assert 1 <= run("loop_envelope", "--out", tmp_path) <= 12
    assert (tmp_path / "loop_envelope.json").is_file() and (tmp_path / "loop_envelope.png").is_file()


def _real_time(run, script, tmp_path):
    """``run(script)`` once more after a miss: a real-time run on the loaded test machine (the
    suite's compilers beside it), where one stall can spoil one run. ``(missed, its report)``."""
    for attempt in range(2):
        missed = run(script, "--out", tmp_path / str(attempt))
        if missed == 0:
            break
    return missed, json.loads((tmp_path / str(attempt) / f"{script}.json").read_text())


def test_rig_goals(run, tmp_path):
    # checks missed on the simulated rig: the short goal run stopped by a fault, the silent
    # controller not ending its run as a communication timeout with the axis stopped; two
    # misses in a row fail with what was missed
    missed, report = _real_time(run, "rig_goals", tmp_path)
    assert missed == 0, {k: report.get(k) for k in ("runs", "faults")}


def test_rig_stalls(run, tmp_path):
    # the designed law's gross slips (plus runs stopped by a fault) on the analog path with the
    # loop stalled 6 ms every second
    missed, report = _real_time(run, "rig_stalls", tmp_path)
    assert missed == 0 and report["runs"][0]["stalls"] >= 2, report["runs"]


def test_loop_sweat_sensing(run):
    # the shear signal's phantom over a friction drop to 0.45, finger and pad still, um
    assert 20.0 < run("loop_sweat_sensing") < 300.0


# ---------------------------------------------------------------- spreading over workers
def test_engine_speedup(run):
    pytest.importorskip("dask.distributed", reason="the cluster is dask's (a test dependency)")
    # both jobs, the envelope and the build's scene simulation, give the serial run's bits on the cluster
    assert run("engine_speedup") == 2


# ---------------------------------------------------------------- the detector studies
def test_detector_bound(run):
    sklearn()
    # the bundled net's detection rate on the held-out scenes (y_slip >= 0.8)
    assert 0.5 <= run("detector_bound") <= 1.0


def test_detector_bank_study(run):
    sklearn()
    # every input set scored (noise-free only)
    assert run("detector_bank_study") == 9


def test_detector_bank_sweep(run):
    # every variant trained, kept and scored in the three conditions
    assert run("detector_bank_sweep") == 8 * 3


def test_detector_compare(run, tmp_path):
    from tactile_mirror.detector import SlipDetector

    path = tmp_path / "bank.npz"
    SlipDetector.bank().weights.save(path)
    # the bundled net's detection rate at 2 % false alarms (an always or never alarming net: 0)
    assert 0.5 <= run("detector_compare", "--weights", path) <= 1.0


def test_detector_distill(run):
    sklearn()
    assert 0.5 <= run("detector_distill") <= 1.0


def test_detector_heldout(run):
    assert 0.5 <= run("detector_heldout", "--consecutive", 3) <= 1.0


def test_detector_input_study(run, tmp_path):
    assert 0.5 <= run("detector_input_study", "--json", tmp_path / "input.json") <= 1.0
    assert (tmp_path / "input.json").is_file()


def test_detector_mining_study(run, tmp_path):
    assert 0.5 <= run("detector_mining_study", "--json", tmp_path / "mining.json") <= 1.0
    assert (tmp_path / "mining.json").is_file()


def test_detector_selection_study(run):
    # one seed of 10 iterations with checkpoints every 5: the checkpoint at 10 is the end, once
    assert run("detector_selection_study") == 2


def test_detector_pad_study(run):
    sklearn()
    assert 0.5 <= run("detector_pad_study") <= 1.0


def test_detector_pad_net(run, tmp_path):
    # the pad-mean net saved as weights and run by SlipDetector too, and the figure
    args = ("--inputs", "mean", "--compress", "log", "--save", tmp_path / "pad.npz", "--figure", tmp_path / "pad.png")
    assert 0.5 <= run("detector_pad_net", *args) <= 1.0
    assert (tmp_path / "pad.npz").is_file() and (tmp_path / "pad.png").is_file()


def test_detector_pred_bound(run):
    sklearn()
    # share of the bundled net's slips with y_pred in 0.8 +- 0.1 just before the onset
    assert 0.4 <= run("detector_pred_bound") <= 1.0


def test_detector_roc(run, tmp_path):
    sklearn()
    out = tmp_path / "roc"
    assert 0.5 <= run("detector_roc", "--out", out, "--figure", tmp_path / "roc.png") <= 1.0
    assert all((tmp_path / name).is_file() for name in ("roc.md", "roc.json", "roc.png"))
