"""The tactile-mirror command: help, errors without tracebacks, and real outputs."""
import numpy as np
import pytest
from tactile_mirror.cli import build_parser, main


def _commands(parser=None, prefix=()):
    """Every command and subcommand of the parser (argparse formats each help on --help)."""
    import argparse

    parser = parser or build_parser()
    yield list(prefix)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*prefix, name))


@pytest.mark.parametrize("command", list(_commands()), ids=lambda c: " ".join(c) or "top")
def test_help_everywhere(command, capsys):
    # (a help string with a bare '%', e.g. from a condition's name, made argparse raise)
    with pytest.raises(SystemExit) as exc:
        main([*command, "--help"])
    assert exc.value.code == 0
    assert "usage: tactile-mirror" in capsys.readouterr().out


@pytest.mark.parametrize("argv,message", [
    (["simulate", "--friction", "-1"], "must be positive"),
    (["simulate", "--ridges", "two"], "expected a int"),
    (["simulate", "--scene", "fig9"], "invalid choice"),
    (["figure", "9"], "invalid choice"),
    (["figure", "13", "--law", "pid"], "invalid choice"),
    (["train", "--hidden", "0"], "must be positive"),
    (["train", "--candidates", "0"], "must be positive"),
    (["train", "--checkpoint-every", "-1"], "must be non-negative"),
    (["evaluate", "--scenes", "-3"], "must be positive"),
    (["fly"], "invalid choice"),
])
def test_bad_options_give_a_message_not_a_traceback(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_simulate_writes_signals_and_figure(tmp_path, capsys):
    out, fig = tmp_path / "s.npz", tmp_path / "s.png"
    assert main(["simulate", "--scene", "fig6", "--duration", "0.7", "--out", str(out), "--figure", str(fig)]) == 0
    data = np.load(out)
    assert data["v_out"].shape == (1, 2, 700) and data["stress"].shape == (1, 2, 3, 700)
    assert np.isnan(data["slip_time"])  # no slip within 0.7 s
    assert fig.stat().st_size > 10_000
    assert "wrote" in capsys.readouterr().out


def test_runtime_errors_are_reported(tmp_path, capsys):
    target = tmp_path / "file"
    target.write_text("")
    rc = main(["simulate", "--duration", "0.1", "--out", str(target / "x.npz")])  # parent is a file
    assert rc == 1
    err = capsys.readouterr().err
    assert err.startswith("error:") and "Traceback" not in err  # reported before any simulation


def test_figure10_and_evaluate(tmp_path, capsys):
    assert main(["figure", "10", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "fig10.png").stat().st_size > 10_000
    assert main(["evaluate", "--scenes", "2", "--seed", "5"]) == 0
    out = capsys.readouterr().out
    assert "detect %" in out and "false %" in out and "detection by how gross slip starts" in out


@pytest.mark.parametrize("name", ["default", "paper", "bank", "early", "pad", "memory"])
def test_weights_takes_the_bundled_nets_by_name(name):
    """--weights NAME is SlipDetector.NAME(): the same weights; a path is a file."""
    from tactile_mirror.cli import BUNDLED_NETS, load_detector
    from tactile_mirror.detector import SlipDetector

    assert name in BUNDLED_NETS
    got, want = load_detector(name).weights, getattr(SlipDetector, name)().weights
    assert got.kind == want.kind and got.metadata == want.metadata
    np.testing.assert_array_equal(got.params.pack(), want.params.pack())


def test_weights_by_name_runs_the_command(capsys):
    assert main(["evaluate", "--weights", "paper", "--scenes", "1", "--seed", "5"]) == 0
    assert "detect %" in capsys.readouterr().out


def test_a_file_named_like_a_bundled_net_is_given_as_a_path(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["evaluate", "--weights", "./pad", "--scenes", "1"]) == 1  # no such file here
    assert capsys.readouterr().err.startswith("error:")


def test_missing_weights_file_is_an_error(tmp_path, capsys):
    assert main(["evaluate", "--weights", str(tmp_path / "none.npz"), "--scenes", "1"]) == 1
    assert capsys.readouterr().err.startswith("error:")


@pytest.mark.parametrize("command, fs", [("design", "1e9"), ("realtime", "2000")])
def test_loop_rate_other_than_the_detectors_is_refused_before_any_simulation(tmp_path, capsys, monkeypatch, command,
                                                                            fs):
    # The pad was calibrated (simulated) at --fs before the pipeline refused the rate;
    # at --fs 1e9 that exhausted the machine's memory. Now nothing is simulated first.
    from tactile_mirror.lab.loop import experiment

    def must_not_run(*a, **k):
        raise AssertionError("the pad was simulated before --fs was checked")

    monkeypatch.setattr(experiment, "calibrate_shear_weights", must_not_run)
    assert main(["loop", command, "--fs", fs, "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert f"--fs {float(fs):g} Hz does not match the 1000 Hz" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_parser_lists_the_subcommands():
    text = build_parser().format_help()
    for name in ("demo", "simulate", "figure", "train", "evaluate"):
        assert name in text


def test_train_writes_loadable_weights(tmp_path, capsys):
    out = tmp_path / "det.npz"
    assert main(["train", "--n-train", "2", "--n-test", "2", "--maxiter", "3", "--hidden", "4",
                 "--candidates", "2", "--checkpoint-every", "1", "--n-validation", "2", "--out", str(out)]) == 0
    from tactile_mirror import SlipDetector

    det = SlipDetector.load(out)
    assert det.n_hidden == 4
    sel = det.metadata["training"]["selection"]
    # 2 seeds x (3 checkpoints + the final weights)
    assert sel["n_candidates"] == 8 and sel["chosen_seed"] in (0, 1) and 1 <= sel["chosen_iteration"] <= 3
    assert "detect %" in capsys.readouterr().out


def test_demo_end_to_end(tmp_path, capsys):
    """The README's first command: paper scenes, the detector on them, open and closed loop."""
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for name in ("fig6", "fig7", "fig8", "fig10", "fig12", "fig13"):
        assert (tmp_path / f"{name}.png").stat().st_size > 10_000, name
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in out.splitlines() if line.startswith("| ")}
    # the detector fires at the paper scenes' slips, not in their stops (Fig. 10)
    for scene in ("fig6", "fig7", "fig8"):
        slip, alarm = (float(v.split()[0]) for v in rows[scene][1:3])
        assert slip - 1e-9 <= alarm <= slip + 0.02, (scene, slip, alarm)
    # Figs. 12 / 13: the finger slips on the still pad; with the stage in the loop it never does
    open_row, closed_row = rows["open (stage still)"], rows["closed (shear loop + y_pred)"]
    assert int(open_row[0]) >= 1 and int(closed_row[0]) == 0
    assert float(closed_row[1].split()[0]) < 0.1 * float(open_row[1].split()[0])
    assert float(closed_row[2]) < 0.8  # y_slip stays below the slip level all run


def test_train_maps_its_flags_onto_build_options():
    from tactile_mirror.cli import build_options_from_args
    from tactile_mirror.lab.detector.build_options import BuildOptions

    parser = build_parser()
    # the command's defaults are the bundled detector's
    assert build_options_from_args(parser.parse_args(["train"])) == BuildOptions()
    args = parser.parse_args(["train", "--n-train", "5", "--n-test", "6", "--hidden", "7", "--maxiter", "8",
                              "--candidates", "2", "--checkpoint-every", "0", "--n-validation", "3"])
    assert build_options_from_args(args) == BuildOptions(n_train=5, n_test=6, n_hidden=7, maxiter=8, candidates=2,
                                                         checkpoint_every=0, n_validation=3)


def test_loop_experiment_maps_onto_the_options():
    import argparse

    from tactile_mirror.cli.loop import experiment_options_from_args
    from tactile_mirror.lab.loop.experiment import ExperimentOptions

    args = argparse.Namespace(seeds=3, duration=1.5, plant="fem", no_robustness=True, robustness_seeds=1)
    o = experiment_options_from_args(args)
    assert o == ExperimentOptions(seeds=(0, 1, 2), duration=1.5, plant="fem", robustness=False,
                                  robustness_seeds=1, progress=True)
    with pytest.raises(SystemExit):
        main(["loop", "experiment", "--duration", "0", "--out", "unused"])


def test_loop_experiment_refuses_an_unknown_plant_with_a_usage_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["loop", "experiment", "--plant", "rubber", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: tactile-mirror loop experiment") and "plant must be one of" in err
    assert not (tmp_path / "o").exists()  # refused before the work


@pytest.mark.parametrize("argv", [["simulate", "--duration", "0.05"], ["train", "--maxiter", "1"]])
def test_an_unwritable_figure_format_fails_before_the_work(argv, tmp_path, capsys):
    out = tmp_path / ("x.npz" if argv[0] == "simulate" else "w.npz")
    rc = main([*argv, "--out", str(out), "--figure", str(tmp_path / "fig.xyz")])
    assert rc != 0
    err = capsys.readouterr().err
    assert "'.xyz'" in err and "Traceback" not in err
    assert not out.exists()  # nothing was computed and saved first


# -- an --out that cannot be written fails before the work --------------------------------------

def test_commands_with_a_file_as_their_out_folder_fail_before_the_work(tmp_path, capsys):
    f = tmp_path / "afile"
    f.write_text("keep")
    for argv in (["figure", "6"], ["demo"], ["bench", "--quick"]):
        assert main([*argv, "--out", str(f)]) != 0
        assert "exists and is not a folder" in capsys.readouterr().err
    assert f.read_text() == "keep"


def _must_not_run(*args, **kwargs):
    raise AssertionError("the work ran before --out was checked")


@pytest.fixture
def no_loop_work(monkeypatch):
    from tactile_mirror.contact import plants
    from tactile_mirror.lab.loop import envelope, experiment
    from tactile_mirror.loop import scene

    for module, name in ((envelope, "design_law"), (envelope, "law_controllers"), (envelope, "run_envelope"),
                         (experiment, "calibrate_shear_weights"), (experiment, "calibrate_shear"),
                         (scene, "run_scene"), (plants, "FemPad")):
        monkeypatch.setattr(module, name, _must_not_run)


@pytest.mark.parametrize("command", ["design", "envelope", "realtime"])
def test_loop_out_that_is_a_file_fails_before_the_work(command, tmp_path, capsys, no_loop_work):
    target = tmp_path / "taken"
    target.write_text("keep me")
    assert main(["loop", command, "--out", str(target)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: --out") and str(target) in err and "not a folder" in err
    assert "Traceback" not in err and "Errno" not in err
    assert target.read_text() == "keep me"


@pytest.mark.parametrize("command, name", [("design", "loop_design.json"), ("realtime", "realtime.json"),
                                           ("envelope", "loop_envelope.json")])
def test_loop_output_file_that_is_a_folder_fails_before_the_work(command, name, tmp_path, capsys, no_loop_work):
    (tmp_path / name).mkdir()
    assert main(["loop", command, "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error:") and name in err and "Traceback" not in err


# -- where a sweep runs: --scheduler ADDRESS or --workers N -------------------------------------------

@pytest.fixture
def executors_seen(monkeypatch):
    """The build, the recalibration, the envelope and the evaluation's simulation faked: each
    records the executor it was given (None: none) after running a task on it."""
    import tactile_mirror
    from tactile_mirror.lab.detector import build, calibration
    from tactile_mirror.lab.loop import envelope

    seen = []

    def record(executor):
        if executor is not None:
            assert executor.submit(pow, 2, 3).result() == 8  # (open while the command runs)
        seen.append(executor)

    def fake_build(out_path, options, report_path=None, figure_path=None, executor=None):
        record(executor)
        return None, {"evaluation_table": "", "total_seconds": 0.0}

    def fake_recalibrate(*args, executor=None):
        record(executor)
        return None, {}

    def fake_envelope(out, executor=None, **kwargs):
        record(executor)
        return {"rows": [], "table": []}

    def fake_simulate_many(scenes, progress=True, executor=None):
        record(executor)
        raise SystemExit(0)  # (the evaluation itself is tested elsewhere)

    monkeypatch.setattr(build, "build_default", fake_build)
    monkeypatch.setattr(calibration, "recalibrate", fake_recalibrate)
    monkeypatch.setattr(envelope, "run_envelope", fake_envelope)
    monkeypatch.setattr(envelope, "envelope_figure", lambda *args, **kwargs: None)
    monkeypatch.setattr(tactile_mirror, "simulate_many", fake_simulate_many)
    return seen


SWEEPS = [["train", "--out", "w.npz"], ["train", "--recalibrate", "in.npz", "--calibrate-goals", "0.01", "0.02"],
          ["loop", "envelope", "--out", "env", "--quiet"], ["evaluate"]]


@pytest.mark.parametrize("command", SWEEPS, ids=lambda c: " ".join(c[:2]))
def test_sweeps_run_here_or_on_local_worker_processes(command, executors_seen, tmp_path, monkeypatch, capsys):
    import concurrent.futures

    monkeypatch.chdir(tmp_path)
    for extra in ([], ["--workers", "2"]):
        try:
            assert main([*command, *extra]) == 0
        except SystemExit as exc:  # (the faked evaluation's end)
            assert exc.code == 0
    assert executors_seen[0] is None and isinstance(executors_seen[1], concurrent.futures.ProcessPoolExecutor)
    with pytest.raises(RuntimeError, match="shutdown"):  # closed when the command ended
        executors_seen[1].submit(pow, 2, 3)


def test_sweeps_run_on_a_dask_scheduler(executors_seen, tmp_path, monkeypatch):
    distributed = pytest.importorskip("dask.distributed")

    monkeypatch.chdir(tmp_path)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        for command in SWEEPS[:3]:
            assert main([*command, "--scheduler", cluster.scheduler_address]) == 0
    assert [type(e).__name__ for e in executors_seen] == ["ClientExecutor"] * 3


@pytest.mark.parametrize("extra, message", [
    (["--workers", "0"], "argument --workers: must be positive"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"], "not allowed with argument"),
])
@pytest.mark.parametrize("command", SWEEPS, ids=lambda c: " ".join(c[:2]))
def test_bad_worker_options_are_a_usage_error(command, extra, message, executors_seen, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*command, *extra])
    assert exc.value.code == 2 and message in capsys.readouterr().err
    assert executors_seen == []


def test_a_scheduler_without_dask_is_an_error_not_a_traceback(executors_seen, monkeypatch, capsys):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "distributed" else
                        find_spec(name, *a))
    assert main(["train", "--out", "w.npz", "--scheduler", "tcp://127.0.0.1:8786"]) == 1
    assert "error: --scheduler needs dask.distributed" in capsys.readouterr().err
    assert executors_seen == []
