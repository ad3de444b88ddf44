"""The tactile-mirror command: help, errors without tracebacks, and real outputs."""
import numpy as np
import pytest
from tactile_mirror.cli import build_parser, main


@pytest.mark.parametrize("command", [[], ["demo"], ["simulate"], ["figure"], ["train"], ["evaluate"]])
def test_help_everywhere(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*command, "--help"])
    assert exc.value.code == 0
    assert "usage: tactile-mirror" in capsys.readouterr().out


@pytest.mark.parametrize("argv,message", [
    (["simulate", "--friction", "-1"], "must be positive"),
    (["simulate", "--ridges", "two"], "expected a int"),
    (["simulate", "--scene", "fig9"], "invalid choice"),
    (["figure", "9"], "invalid choice"),
    (["train", "--hidden", "0"], "must be positive"),
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
    assert "detect %" in out and "false %" in out


def test_missing_weights_file_is_an_error(tmp_path, capsys):
    assert main(["evaluate", "--weights", str(tmp_path / "none.npz"), "--scenes", "1"]) == 1
    assert capsys.readouterr().err.startswith("error:")


def test_parser_lists_the_subcommands():
    text = build_parser().format_help()
    for name in ("demo", "simulate", "figure", "train", "evaluate"):
        assert name in text


def test_train_writes_loadable_weights(tmp_path, capsys):
    out = tmp_path / "det.npz"
    assert main(["train", "--n-train", "2", "--n-test", "2", "--maxiter", "3", "--hidden", "4",
                 "--out", str(out)]) == 0
    from tactile_mirror import SlipDetector

    det = SlipDetector.load(out)
    assert det.n_hidden == 4
    assert "detect %" in capsys.readouterr().out
