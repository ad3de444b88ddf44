"""A load cell under the pad as the loop's shear signal (``force_input``): the C++ pipeline
against its numpy reference and the C ABI, the signal's meaning, the checks, the design,
and the closed loop through a friction change that the strips' signal cannot hold."""
from __future__ import annotations

import numpy as np
import pytest
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.loop import StageLimits
from tactile_mirror.loop.design import design_loop, loop_response
from tactile_mirror.pipeline import MirrorPipeline, PaperController, ReferencePipeline, VelocityController

FS = 1000.0
STAGE = StageLimits(-0.02, 0.02, 0.03, 1.0)


def _weights(h=6, seed=5):
    rng = np.random.default_rng(seed)
    return {"w1": rng.normal(size=(h, 5)), "b1": rng.normal(size=h), "w2": 3 * rng.normal(size=(2, h)),
            "b2": rng.normal(size=2), "input_mean": np.zeros(4), "input_gain": np.array([3e-3, 3e-3, 3e-5, 3e-5]),
            "fs": FS}


def _pipe(controller, n_ridges=2, **kw):
    est = StressRateEstimator(PVDFCircuit(), FS, 2 * n_ridges, bandwidth=100.0)
    return MirrorPipeline(_weights(), FS, n_ridges, estimator=est, controller=controller, v_limit=5.0, u_limit=5.0,
                          activation="exact", force_input=True, force_limit=20.0, **kw)


def _signals(n, n_ridges=2, seed=0):
    rng = np.random.default_rng(seed)
    nv = 4 * n_ridges
    x = np.empty((n, nv + 1))
    x[:, :nv] = 0.05 * np.sin(np.arange(n)[:, None] * 0.02 * np.arange(1, nv + 1)) + 0.01 * rng.normal(size=(n, nv))
    x[:, nv] = 2.0 * np.sin(2 * np.pi * 1.5 * np.arange(n) / FS) + 0.01 * rng.normal(size=n)  # N
    return x


def _law(**kw):
    return VelocityController(v_max=0.004, a_max=0.2, shear_gain=2e-3, shear_integral=60.0, rate_gain=1e-5,
                              arm_delay=0.05, slip_hold=0.02, slip_confirm=0.002, **kw)


def test_force_input_runs_as_its_reference_and_the_c_abi():
    from tactile_mirror.loop.capi import CPipeline

    pipe = _pipe(_law())
    assert pipe.n_inputs == 9 and pipe.config["force_input"] is True and pipe.config["force_limit"] == 20.0
    x = _signals(1500)
    x[300, 8] = np.nan      # a lost force sample
    x[600, 8] = 25.0        # beyond the cell's range
    x[900, 2] = np.inf      # a lost voltage
    out = pipe.process_block(x)[0]
    assert np.ptp(out[:, 0]) > 1e-4  # the law moves on the force
    st = pipe.status
    assert (st["rejected"], st["nonfinite"], st["out_of_range"]) == (3, 2, 1)
    ref = ReferencePipeline(pipe.config).process_block(x)
    np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-13)
    with CPipeline(pipe.config) as cp:  # through tm.h (ABI 10): bit for bit
        assert np.array_equal(cp.process_block(x)[0].view(np.uint64), out.view(np.uint64))
    # step() is process_block() tick by tick
    pipe.reset()
    o = np.zeros(pipe.n_outputs)
    steps = np.array([(pipe.step(row, o), o.copy())[1] for row in x])
    assert np.array_equal(steps.view(np.uint64), out.view(np.uint64))
    # the float32 pipeline runs it too (its filters and detector in float)
    p32 = MirrorPipeline(_weights(), FS, 2, estimator=StressRateEstimator(PVDFCircuit(), FS, 4, bandwidth=100.0),
                         controller=_law(), v_limit=5.0, u_limit=5.0, force_input=True, force_limit=20.0,
                         dtype=np.float32)
    assert np.max(np.abs(p32.process_block(x)[0][:, 0] - out[:, 0])) < 1e-6


def test_the_shear_signal_is_the_force_since_the_tare_and_survives_lost_ticks():
    # a law that never moves: its asymmetry integrator is what the pipeline feeds it
    pipe = _pipe(PaperController(threshold=0.99, gain=0.0, asym_tau=1e9, arm_delay=0.01))
    x = _signals(400)
    x[:, 8] = np.linspace(-3.0, 5.0, 400)
    x[200:205, 8] = np.nan  # five lost force samples: the next difference spans them
    o = np.zeros(pipe.n_outputs)
    tare = None
    for k, row in enumerate(x):
        pipe.step(row, o)
        if k == 9:  # the arming tares at its 10th tick
            tare = row[8]
            assert pipe.controller_state["asymmetry"] == 0.0
    assert pipe.controller_state["asymmetry"] == pytest.approx(x[-1, 8] - tare, rel=1e-9)
    # without the force the same law integrates the strips' rates instead
    strips = MirrorPipeline(_weights(), FS, 2, estimator=StressRateEstimator(PVDFCircuit(), FS, 4, bandwidth=100.0),
                            controller=PaperController(threshold=0.99, gain=0.0, asym_tau=1e9, arm_delay=0.01),
                            v_limit=5.0, u_limit=5.0)
    strips.process_block(np.ascontiguousarray(np.nan_to_num(x[:, :8])))
    assert strips.controller_state["asymmetry"] != pytest.approx(x[-1, 8] - tare, rel=1e-3)


def test_a_rejected_force_keeps_the_state():
    pipe = _pipe(_law())
    x = _signals(300)
    o1 = np.zeros(pipe.n_outputs)
    pipe.process_block(x[:200])
    before = (pipe.controller_state, pipe.features.copy())
    bad = x[200].copy()
    bad[8] = -np.inf
    pipe.step(bad, o1)
    assert pipe.status["last_bad_channel"] == 8 and pipe.status["last_reason"] == "nonfinite"
    assert pipe.features.tolist() == before[1].tolist()
    # no new shear on a rejected tick: the integrator only leaks
    st = pipe.controller_state
    assert st["asymmetry"] == pytest.approx(before[0]["asymmetry"] * np.exp(-1 / (FS * _law().asym_tau)), rel=1e-12)
    # and the next accepted force difference is taken from the last accepted force
    pipe.step(x[201], o1)
    assert pipe.status["consecutive_rejected"] == 0


@pytest.mark.parametrize("kw, exc, match", [
    ({"force_input": 1}, TypeError, "force_input must be True or False"),
    ({"force_input": True, "force_limit": np.inf}, ValueError, "force_limit"),
    ({"force_input": True, "force_limit": -1.0}, ValueError, "force_limit"),
    ({"force_input": True, "force_limit": 1e300}, ValueError, r"force_limit must lie in \(0, 1e6\] N"),
    ({"force_input": True, "force_limit": "5"}, TypeError, "force_limit"),
])
def test_force_options_are_checked(kw, exc, match):
    est = StressRateEstimator(PVDFCircuit(), FS, 4, bandwidth=100.0)
    with pytest.raises(exc, match=match):
        MirrorPipeline(_weights(), FS, 2, estimator=est, **kw)


def test_configs_without_the_force_keys_still_load_and_the_c_abi_checks_the_limit():
    from tactile_mirror.loop.capi import CAPIError, CPipeline

    pipe = _pipe(_law())
    old = {k: v for k, v in MirrorPipeline(_weights(), FS, 2, estimator=StressRateEstimator(
        PVDFCircuit(), FS, 4, bandwidth=100.0)).config.items() if k not in ("force_input", "force_limit")}
    assert MirrorPipeline.from_config(old).n_inputs == 8  # a recording made before the load cell
    assert MirrorPipeline.from_config(pipe.config).n_inputs == 9
    with pytest.raises(CAPIError, match="force_limit"):
        CPipeline({**pipe.config, "force_limit": -2.0}, check=False)


def test_design_on_a_load_cell_has_no_estimator_delay():
    strips = design_loop(STAGE, (1.0, 4.8e7), FS, stage_delay=0.001, stage_lag=0.002)
    cell = design_loop(STAGE, (1.0, 7.6e4), FS, stage_delay=0.001, stage_lag=0.002, sensor="force")
    assert cell.delays["estimator_group_delay"] == 0.5 / FS < strips.delays["estimator_group_delay"]
    assert cell.sensor == "force" and cell.pipeline_kwargs()["force_input"] is True
    assert strips.pipeline_kwargs()["force_input"] is False
    # less delay: a higher crossover and a larger acceleration constant, the same margins
    assert cell.crossover_hz > strips.crossover_hz and cell.acceleration_constant > strips.acceleration_constant
    assert cell.phase_margin_deg >= 45.0 - 1e-9 and cell.gain_margin_db >= 6.0 - 1e-9
    # the backward difference of the force is the rate: ~ j w at low frequencies
    f = np.array([0.5, 1.0])
    L = loop_response(f, 10.0, 0.0, 1.0, FS, 0.0, 0.0, asym_tau=1e9, sensor="force")
    np.testing.assert_allclose(L, (10.0 + 1.0 * 2j * np.pi * f) / (2j * np.pi * f), rtol=2e-2)
    with pytest.raises(ValueError, match="sensor"):
        design_loop(STAGE, (1.0, 7.6e4), FS, stage_delay=0.001, stage_lag=0.002, sensor="camera")


@pytest.fixture(scope="module")
def sweat_runs():
    """One finger path (seed 7000: in no tuning or reported set), friction 0.76 -> 0.45 under
    load at 1.75 s: the default law on the strips and on a load cell."""
    from tactile_mirror.lab.loop.envelope import law_controllers
    from tactile_mirror.lab.loop.experiment import default_weights, weights_dict
    from tactile_mirror.loop.scene import LoopScene, run_scene

    w = weights_dict(default_weights("fem"))
    laws, design = law_controllers(w, FS, STAGE, 0.001, 0.002, 6, "fem", load_cell=True)
    traj = {"amplitude": 10e-3, "bandwidth": 2.0, "v_max": 0.01, "a_max": 0.5}
    runs = {}
    for name in ("default", "load cell"):
        sc = LoopScene(seed=7000, duration=3.0, plant="fem", trajectory=traj, mu_change=(1.75, 0.45),
                       load_cell=name == "load cell")
        runs[name] = run_scene(sc, w, laws[name], limits=STAGE,
                               shear_weights=design.shear_weights if name == "default" else None)
    return runs


def test_a_load_cell_holds_the_contact_through_sweat(sweat_runs):
    strips, cell = sweat_runs["default"], sweat_runs["load cell"]
    assert strips.gross_slips >= 1            # the strips' phantom runs the law into a slip
    assert cell.gross_slips == 0              # the force has none
    assert cell.tracking_rms < 0.01e-3 and cell.tracking_max < 0.05e-3
    assert np.all(np.isfinite(cell.log["load_cell"]))
    # the cell reads the finger's force minus the pad's inertia, with its noise
    resid = cell.log["load_cell"] - cell.log["force_y"]
    assert 1e-3 < np.std(resid[600:]) < 5e-3


def test_the_load_cell_design_predicts_its_closed_loop_error():
    """The force design's linear prediction e = S x_finger against the FEM closed loop on a
    load cell, within 30 % (as the strips' design is tested), on a path faster than any tuning
    path (25 mm/s peak, seed 5000: in no tuning or reported set)."""
    from tactile_mirror.lab.loop.experiment import calibrate_shear, default_weights, weights_dict
    from tactile_mirror.loop.scene import LoopScene, run_scene

    w = weights_dict(default_weights("fem"))
    d = design_loop(STAGE, calibrate_shear(w, FS, 6, plant="fem", load_cell=True), FS, stage_delay=0.001,
                    stage_lag=0.002, sensor="force")
    sc = LoopScene(seed=5000, duration=2.0, plant="fem", load_cell=True,
                   trajectory={"amplitude": 10e-3, "bandwidth": 1.0, "v_max": 0.025, "a_max": 0.25})
    r = run_scene(sc, w, d.controller, limits=STAGE)
    assert r.gross_slips == 0
    n0 = round(0.5 * FS)
    e_sim = (r.finger - r.log["pad"][: r.t.size])[n0:]
    e_pred = d.predict_error(r.finger[n0:])
    rms_sim, rms_pred = np.sqrt(np.mean(e_sim**2)), np.sqrt(np.mean(e_pred**2))
    assert rms_pred == pytest.approx(rms_sim, rel=0.3)
    assert rms_sim < 0.01e-3


def test_loop_design_command_designs_for_a_load_cell(tmp_path, capsys):
    import json

    from tactile_mirror.cli import main

    assert main(["loop", "design", "--load-cell", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "load cell" in printed and "N/mm" in printed
    summary = json.loads((tmp_path / "loop_design_load_cell.json").read_text())
    assert summary["sensor"] == "force" and summary["delays_s"]["estimator_group_delay"] == pytest.approx(5e-4)
    assert 70e3 < summary["asym_per_m"] < 85e3  # N/m: the FEM pad's stuck stiffness
    assert (tmp_path / "loop_design_load_cell.png").stat().st_size > 0
    assert not (tmp_path / "loop_design.json").exists()  # the strips' design is not overwritten


def test_a_recording_with_the_force_replays_bit_for_bit(tmp_path):
    from tactile_mirror.loop.recording import Recording, RecordingError
    from tactile_mirror.loop.scene import LoopScene, run_scene

    sc = LoopScene(seed=3, duration=0.3, plant="brush", load_cell=True, drop_rate=0.05,
                   trajectory={"amplitude": 1e-3, "bandwidth": 2.0, "v_max": 0.005, "a_max": 0.5})
    r = run_scene(sc, _weights(), _law(), limits=STAGE)
    rec = r.run.to_recording(r.config)
    assert rec.samples.shape[1] == 4 * 6 + 1 and np.isnan(rec.samples[:, -1]).any()  # dropped ticks lose the force
    rec.save(tmp_path / "r.npz")
    back = Recording.load(tmp_path / "r.npz")
    assert back.config["force_input"] is True and back.verify()
    with pytest.raises(RecordingError, match=r"samples must have shape \(300, 25\)"):
        Recording(**{**vars(back), "samples": back.samples[:, :24]}).validate()


def test_loop_realtime_runs_the_load_cell_law(tmp_path, capsys):
    import json

    from tactile_mirror.cli import main
    from tactile_mirror.loop.recording import Recording

    assert main(["loop", "realtime", "--law", "load cell", "--duration", "0.8", "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    summary = json.loads((tmp_path / "realtime.json").read_text())
    assert summary["law"] == "load cell" and summary["gross_slips"] == 0
    rec = Recording.load(tmp_path / "realtime_recording.npz")
    assert rec.config["force_input"] is True and rec.samples.shape == (800, 25) and rec.verify()



def test_extreme_gains_cannot_slip_a_nan_command_through_the_unguarded_window():
    """With gains of 1e303 the law's products overflow (inf - inf) long before |a| reaches
    the window's bound: the tick must be refused as an overflow, as the reference refuses it."""
    est = StressRateEstimator(PVDFCircuit(), FS, 4, bandwidth=100.0)
    law = VelocityController(v_max=0.004, a_max=0.2, shear_gain=1e303, rate_gain=1e303, arm_delay=0.0)
    pipe = MirrorPipeline(_weights(), FS, 2, estimator=est, controller=law, v_limit=5.0, u_limit=5.0,
                          activation="exact", force_input=True, force_limit=1e6)
    x = np.zeros((40, 9))
    x[10:, 8] = 1e6
    x[20:, 8] = 5e5
    out = pipe.process_block(x)[0]
    ref = ReferencePipeline(pipe.config)
    ro = ref.process_block(x)
    assert np.all(np.isfinite(out)) and pipe.status["overflow"] > 0
    assert pipe.status["overflow"] == ref.rejected["overflow"]
    np.testing.assert_allclose(out, ro, rtol=1e-9, atol=1e-13)


def test_time_step_ns_leaves_a_float32_pipeline_as_it_was():
    """The timing loop restores the state bit for bit (it went through the filters' scipy
    layout, which float delta sections do not keep exactly)."""
    def make():
        return MirrorPipeline(_weights(), FS, 2, estimator=StressRateEstimator(PVDFCircuit(), FS, 4, bandwidth=100.0),
                              controller=_law(), v_limit=5.0, u_limit=5.0, dtype=np.float32, force_input=True)

    a, b = make(), make()
    x = _signals(600)
    a.process_block(x[:300])
    b.process_block(x[:300])
    a.time_step_ns(2000, 1)
    assert np.array_equal(a.process_block(x[300:])[0].view(np.uint64), b.process_block(x[300:])[0].view(np.uint64))


def test_a_reference_of_a_config_without_the_force_limit_uses_the_default():
    cfg = {k: v for k, v in _pipe(_law()).config.items() if k != "force_limit"}
    ref = ReferencePipeline(cfg)
    x = _signals(50)
    x[10, 8] = 150.0  # beyond the default 100 N
    ref.process_block(x)
    assert ref.rejected["out_of_range"] == 1


def test_the_load_cell_law_has_no_slip_guard_and_unloads_the_contact_after_a_slip():
    """A finger jump of 0.2 mm in 8 ms (more than the contact carries) on a path of 20 mm/s
    peak (seed 9201: in no tuning or reported set). The force law, without the strips' slip
    guard, brings the force back near zero; with the guard, its re-tare takes the sliding
    friction as the reference and the contact ends at its friction limit."""
    import dataclasses

    from tactile_mirror.contact.plants import FemPad
    from tactile_mirror.lab.loop.envelope import law_controllers
    from tactile_mirror.lab.loop.experiment import default_weights, weights_dict
    from tactile_mirror.loop.scene import LoopScene, run_scene, scene_finger

    w = weights_dict(default_weights("fem"))
    stage = StageLimits(-0.015, 0.015, 0.03, 1.0)
    laws, design = law_controllers(w, FS, stage, 0.002, 0.002, 6, "fem", load_cell=True)
    law = laws["load cell"]
    assert law.slip_hold == 0.0 and design.controller.slip_hold > 0.0   # (the strips' law keeps its guard)
    sc = LoopScene(seed=9201, duration=2.5, plant="fem", load_cell=True,
                   trajectory={"amplitude": 10e-3, "bandwidth": 2.0, "v_max": 0.02, "a_max": 0.5})
    f = scene_finger(sc)
    f = f + 0.2e-3 * np.clip((np.arange(f.size) / FS - 1.3) / 0.008, 0.0, 1.0)
    end = {}
    for name, ctl in (("no guard", law), ("guard", dataclasses.replace(law, slip_hold=0.1))):
        r = run_scene(sc, w, ctl, limits=stage, finger=f, plant=FemPad.realtime(6, fs=FS))
        end[name] = (r.gross_slips, float(np.abs(r.log["load_cell"][-300:]).max()))
    assert end["no guard"][0] <= 1 and end["no guard"][1] < 1.0, end     # measured: 0 slips, 0.36 N
    assert end["guard"][1] > 5.0, end                                       # measured: 2 slips, 8.97 N
