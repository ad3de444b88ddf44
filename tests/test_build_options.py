"""BuildOptions: what build_default builds, checked on construction; the old keyword
form of build_default is gone. ``tactile-mirror train``'s build options map onto them."""
from __future__ import annotations

import dataclasses

import pytest
from tactile_mirror.cli import main
from tactile_mirror.lab.detector import build, calibration
from tactile_mirror.lab.detector.build import build_default
from tactile_mirror.lab.detector.build_options import (
    TEST_KWARGS,
    TRAIN_KWARGS,
    TRAIN_OPTIONS,
    BuildOptions,
)


@pytest.fixture
def captured(monkeypatch):
    """build_default's arguments as they reach the build, without building."""
    calls = []

    def fake_build(out_path, options, report_path, figure_path, results):
        calls.append({"out": out_path, "options": options, "report_path": report_path,
                      "figure_path": figure_path, "results": results})
        return None, {}

    monkeypatch.setattr(build, "_build", fake_build)
    return calls


def test_defaults_are_the_bundled_settings_as_copies():
    o = BuildOptions()
    assert (o.n_train, o.n_test, o.n_hidden, o.maxiter, o.candidates, o.checkpoint_every, o.n_validation) == \
        (64, 200, 16, 800, 4, 25, 120)
    assert o.train_kwargs == TRAIN_KWARGS and o.train_kwargs is not TRAIN_KWARGS
    assert o.test_kwargs == TEST_KWARGS and o.train_options == TRAIN_OPTIONS
    assert o.selecting
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.n_hidden = 8  # type: ignore[misc]


@pytest.mark.parametrize("field,value,exc,match", [
    ("n_train", 0, ValueError, "n_train must be a positive integer"),
    ("n_hidden", 2.5, ValueError, "n_hidden"),
    ("candidates", 0, ValueError, "candidates must be a positive integer"),
    ("checkpoint_every", -1, ValueError, "checkpoint_every must be a non-negative integer"),
    ("noise_copies", True, ValueError, "noise_copies"),
    ("n_validation", 0, ValueError, "n_validation"),
    ("gain_range", (1.7, 0.6), ValueError, "gain_range"),
    ("noise_range", "loud", TypeError, "noise_range"),
    ("train_kwargs", [("stop_after_slip", 0.3)], TypeError, "train_kwargs"),
    ("study_sizes", (8, 0), ValueError, "study_sizes"),
])
def test_bad_fields_are_named(field, value, exc, match):
    with pytest.raises(exc, match=match):
        BuildOptions(**{field: value})


def test_validation_scenes_only_needed_when_choosing():
    o = BuildOptions(candidates=1, checkpoint_every=0, n_validation=0)
    assert not o.selecting


def test_options_call_reaches_the_build_unchanged(captured, tmp_path):
    o = BuildOptions(n_hidden=8)
    build_default(tmp_path / "w.npz", o, report_path="r.txt")
    assert captured[0]["options"] is o and captured[0]["report_path"] == "r.txt"
    build_default(tmp_path / "w.npz")
    assert captured[1]["options"] == BuildOptions()


def test_build_default_takes_only_options(tmp_path):
    with pytest.raises(TypeError, match="BuildOptions"):
        build_default(tmp_path / "w.npz", 2)
    with pytest.raises(TypeError):
        build_default(tmp_path / "w.npz", n_hidden=4)  # type: ignore[call-arg]


class _Stop(Exception):
    pass


@pytest.mark.parametrize("where", ["here", "executor", "workers"])
def test_the_build_simulates_its_scenes_where_it_is_told(where, monkeypatch, tmp_path):
    """build_default(executor=) hands the executor to the scene simulation; workers=N starts one
    pool of N processes for the whole build; neither simulates here (no executor passed on)."""
    import concurrent.futures

    seen = []

    def fake_simulate_cached(n, seed, kwargs, cache_dir=None, progress=True, **spread):
        seen.append(spread)
        raise _Stop

    monkeypatch.setattr(build, "simulate_cached", fake_simulate_cached)
    given = {"here": {}, "executor": {"executor": concurrent.futures.ThreadPoolExecutor(1)},
             "workers": {"workers": 2}}[where]
    with pytest.raises(_Stop):
        build_default(tmp_path / "w.npz", BuildOptions(progress=False), **given)
    (spread,) = seen
    if where == "here":
        assert spread == {}
    elif where == "executor":
        assert spread == given
    else:
        assert isinstance(spread["executor"], concurrent.futures.ProcessPoolExecutor)
        with pytest.raises(RuntimeError, match="shutdown"):  # the build's pool is closed with it
            spread["executor"].submit(pow, 2, 3)
    with pytest.raises(ValueError, match="give executor or workers, not both"):
        build_default(tmp_path / "w.npz", BuildOptions(progress=False), workers=2,
                      executor=concurrent.futures.ThreadPoolExecutor(1))


def test_train_command_maps_onto_options(monkeypatch, tmp_path):
    seen = {}

    def fake(out_path, options, report_path=None, figure_path=None):
        seen.update(out=out_path, options=options, report=report_path, figure=figure_path)
        return None, {"evaluation_table": "", "total_seconds": 0.0}

    monkeypatch.setattr(build, "build_default", fake)
    monkeypatch.chdir(tmp_path)  # (the report's folder is checked before the build)
    assert main(["train", "--out", str(tmp_path / "w.npz"), "--hidden", "8", "--pred-weight", "2",
                 "--report", "r.txt"]) == 0
    assert seen["options"] == BuildOptions(n_hidden=8, train_options=dict(TRAIN_OPTIONS, pred_weight=2.0))
    assert seen["report"] == "r.txt" and seen["figure"] is None


def test_train_command_maps_the_bank_options(monkeypatch, tmp_path):
    seen = {}

    def fake(out_path, options, report_path=None, figure_path=None):
        seen.update(options=options)
        return None, {"evaluation_table": "", "total_seconds": 0.0}

    monkeypatch.setattr(build, "build_default", fake)
    assert main(["train", "--out", str(tmp_path / "w.npz"), "--kind", "jordan_bank", "--lp-taus", "0.008", "0.032",
                 "--abs-taus", "--negative-weight", "30", "--noise-range", "0", "0.002"]) == 0
    o = seen["options"]
    assert o.kind == "jordan_bank" and o.noise_range == (0.0, 0.002)
    assert o.bank == {"lp_taus": [0.008, 0.032], "abs_taus": [], "load_tau": 0.5, "peak_tau": 2.0}
    assert o.train_options["negative_weight"] == 30.0
    # without bank options the build uses the default bank (None here)
    assert main(["train", "--out", str(tmp_path / "w.npz"), "--kind", "jordan_bank"]) == 0
    assert seen["options"].bank is None


@pytest.mark.parametrize("argv, option", [
    (["--n-train", "0"], "--n-train"), (["--hidden", "-1"], "--hidden"), (["--candidates", "0"], "--candidates"),
    (["--study", "8", "0"], "--study"), (["--noise-range", "0.002", "0"], "--noise-range"),
    (["--calibrate-fa", "2"], "--calibrate-fa"), (["--kind", "jordan_bank", "--lp-taus", "-1"], "--lp-taus"),
    (["--compress"], "--compress"), (["--negative-weight", "nan"], "--negative-weight"),
    (["--pred-weight", "-1"], "--pred-weight"), (["--onset-weight", "inf"], "--onset-weight"),
    (["--recalibrate", "in.npz", "--calibrate-goals", "0.01", "0.02", "--n-validation", "0"], "--n-validation"),
])
def test_build_command_line_refuses_bad_arguments_with_a_usage_line(argv, option, monkeypatch, capsys):
    """Bad arguments were a traceback (ValueError from BuildOptions, or from the training
    after the scenes were simulated); now argparse's usage line, exit status 2, nothing run."""

    def never(*args, **kwargs):
        raise AssertionError("the build ran")

    monkeypatch.setattr(build, "build_default", never)
    monkeypatch.setattr(calibration, "recalibrate", never)
    with pytest.raises(SystemExit) as exc:
        main(["train", "--out", "unused.npz", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage:") and f"error: argument {option}" in err and "Traceback" not in err


def test_bad_bank_is_named():
    with pytest.raises(ValueError, match="lp_taus"):
        BuildOptions(kind="jordan_bank", bank={"lp_taus": [], "abs_taus": [], "load_tau": 0.5, "peak_tau": 2.0})


def test_calibrate_condition_reaches_the_recalibration(monkeypatch, tmp_path, capsys):
    """--calibrate-condition calibrates for the named sensor conditions only (a net for a
    sensor whose noise is known); unknown names, bad rates and the mix with
    --calibrate-goals are refused by name."""
    calls = []

    def fake_recalibrate(weights_path, out_path, conditions, n_validation, n_test, cache_dir):
        calls.append((weights_path, out_path, conditions, n_validation, n_test, cache_dir))
        return None, {"threshold": 0.5}

    monkeypatch.setattr(calibration, "recalibrate", fake_recalibrate)
    out = str(tmp_path / "w.npz")
    assert main(["train", "--out", out, "--recalibrate", "in.npz", "--calibrate-condition", "1 mV rms white",
                 "0.025", "--n-validation", "480"]) == 0
    assert calls == [("in.npz", out, {"1 mV rms white": 0.025}, 480, 200, None)]
    assert main(["train", "--out", out, "--recalibrate", "in.npz", "--calibrate-goals", "0.015", "0.025"]) == 0
    assert calls[-1][2] == {"noise-free": 0.015, "1 mV rms white": 0.025, "thermal + 2 mV 50 Hz hum, notch": 0.025}
    for bad, match in ((["--calibrate-condition", "2 mV", "0.02"], "unknown condition"),
                       (["--calibrate-condition", "noise-free", "low"], "must be a number"),
                       (["--calibrate-condition", "noise-free", "1.5"], "must be a number in [0, 1)"),
                       (["--calibrate-condition", "noise-free", "nan"], "must be a number in [0, 1)"),
                       (["--calibrate-condition", "noise-free", "0.02", "--calibrate-condition", "noise-free",
                         "0.03"], "given twice"),
                       (["--calibrate-condition", "noise-free", "0.02", "--calibrate-fa", "0.02"],
                        "exclude each other"),
                       (["--calibrate-condition", "noise-free", "0.02", "--calibrate-goals", "0.01", "0.02"],
                        "exclude each other")):
        with pytest.raises(SystemExit):
            main(["train", "--out", out, "--recalibrate", "in.npz", *bad])
        assert match in capsys.readouterr().err
    assert len(calls) == 2


def test_train_command_passes_the_cache_and_refuses_what_the_build_cannot_do(monkeypatch, tmp_path, capsys):
    """--cache reaches the build; an unknown --kind and --recalibrate without a calibration goal
    end in the usage line (exit status 2) before anything runs."""
    seen = {}

    def fake(out_path, options, report_path=None, figure_path=None, cache_dir=None):
        seen.update(options=options, cache_dir=cache_dir, runs=seen.get("runs", 0) + 1)
        return None, {"evaluation_table": "", "total_seconds": 0.0, "hidden_size_study": [{"n_hidden": 8}]}

    monkeypatch.setattr(build, "build_default", fake)
    out = str(tmp_path / "w.npz")
    assert main(["train", "--out", out, "--cache", str(tmp_path / "cache"), "--study", "8", "16"]) == 0
    assert seen["cache_dir"] == str(tmp_path / "cache") and seen["options"].study_sizes == (8, 16)
    assert "{'n_hidden': 8}" in capsys.readouterr().out
    for argv, message in ((["--kind", "elman"], "error: argument --kind: kind must be one of"),
                          (["--recalibrate", "in.npz"], "--recalibrate needs --calibrate-goals")):
        with pytest.raises(SystemExit) as exc:
            main(["train", "--out", out, *argv])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith("usage: tactile-mirror train") and message in err
    assert seen["runs"] == 1
