"""The wall-clock paced loop against the simulated FEM pad (hardware in the loop
without the hardware). Functional checks only: counters and the per-tick record are
consistent, and pacing does not change what is computed. Timing is measured in
bench/bench_contact.py, never asserted here."""
import numpy as np
import pytest
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.contact.plants import FemPad
from tactile_mirror.loop.controller import NoController
from tactile_mirror.loop.experiment import PLANTS, default_weights
from tactile_mirror.loop.runner import LoopRunner
from tactile_mirror.loop.scene import LoopScene, PlantSource, loop_pipeline, scene_finger
from tactile_mirror.loop.stage import SimulatedStage

pytest.importorskip("skfem")


def run(realtime, n_ridges=2):
    sc = LoopScene(seed=1, duration=0.15, press=0.05, plant="fem", trajectory=PLANTS["fem"]["trajectory"])
    finger = scene_finger(sc)
    source = PlantSource(sc, FemPad(n_ridges, fs=sc.fs), PVDFCircuit(), finger)
    pipe = loop_pipeline(default_weights("fem", sc.fs), sc.fs, NoController(), n_ridges)
    res = LoopRunner(pipe, SimulatedStage(), source, realtime=realtime).run(n_ticks=finger.size, x0=0.0)
    res.config = pipe.config
    return res, source


def test_realtime_fem_pad_counters_are_consistent():
    res, source = run(realtime=True)
    n = 150
    assert res.realtime and len(res.t) == n and source.k == n
    assert res.tick_ns.shape == res.latency_ns.shape == (n,)
    assert np.all(res.latency_ns > 0) and np.all(res.tick_ns >= res.latency_ns)  # the tick includes the plant
    assert 0 <= res.overruns <= n and 0 <= res.late_starts <= n
    for p in (res.tick_percentiles(), res.latency_percentiles()):
        assert p["p50"] <= p["p99"] <= p["p99.9"] <= p["max"]
    assert res.tick_percentiles()["max"] == pytest.approx(res.tick_ns.max() / 1e3)
    assert source.log["force_z"][n - 1] > 0  # the finger pressed the pad
    meta = res.to_recording(res.config).metadata
    assert meta["tick_us"] == res.tick_percentiles() and meta["overruns"] == res.overruns


def test_pacing_does_not_change_the_run():
    paced, sp = run(realtime=True)
    free, sf = run(realtime=False)
    np.testing.assert_array_equal(paced.samples, free.samples)
    np.testing.assert_array_equal(paced.outputs, free.outputs)
    np.testing.assert_array_equal(sp.log["force_y"], sf.log["force_y"])
    assert not free.realtime and free.late_starts == 0
