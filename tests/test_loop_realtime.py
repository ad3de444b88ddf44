"""The wall-clock paced loop against the simulated FEM pad (hardware in the loop
without the hardware). Functional checks only: counters and the per-tick record are
consistent, and pacing does not change what is computed. Timing is measured in
bench/bench_contact.py, never asserted here."""
import numpy as np
import pytest
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.contact.plants import FemPad
from tactile_mirror.lab.loop.experiment import PLANTS, default_weights
from tactile_mirror.loop.runner import LoopRunner
from tactile_mirror.loop.scene import LoopScene, PlantSource, loop_pipeline, scene_finger
from tactile_mirror.loop.stage import SimulatedStage
from tactile_mirror.pipeline.controller import NoController

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


def test_realtime_pad_is_the_fem_pad_at_coarser_contact_elements():
    from tactile_mirror.contact.plants import REALTIME_CONTACT_MESH_SIZE
    from tactile_mirror.geometry import RidgeGeometry

    rt, default = FemPad.realtime(3, fs=1000.0), FemPad(3, fs=1000.0)
    g_rt, g_def = rt.pad.model.geometry, default.pad.model.geometry
    assert g_rt.contact_mesh_size == REALTIME_CONTACT_MESH_SIZE > g_def.contact_mesh_size
    # only the contact zone is coarser: the strips sit in the same mesh
    assert (g_rt.mesh_size, g_rt.strip_mesh_size) == (g_def.mesh_size, g_def.strip_mesh_size)
    assert rt.pad.model.n_nodes < default.pad.model.n_nodes and rt.pad.threads == 1
    # a geometry or thread count given wins; the keyword arguments reach FemPad
    own = FemPad.realtime(1, mu=0.6, geometry=RidgeGeometry(contact_mesh_size=0.1e-3), threads=2)
    assert own.pad.model.geometry.contact_mesh_size == 0.1e-3 and own.pad.threads == 2 and own.mu == 0.6
    with pytest.raises(ValueError, match="threads"):
        FemPad(1, threads=0)
    # the same press and slide: the same load within the resolution, two threads or one
    # (3 ridges: the outer two are mirror images, so two of them compute)
    finger = np.concatenate([np.zeros(40), np.linspace(0.0, 40e-6, 60)])
    two = FemPad.realtime(3, threads=2)
    runs = [[p.advance(float(d)) for d in finger] for p in (rt, default, two)]
    assert len(set(two.pad._stepper.sources)) == 2
    fy = np.array([[s.force_y for s in r] for r in runs])
    fz = np.array([[s.force_z for s in r] for r in runs])
    np.testing.assert_array_equal(fy[0], fy[2])  # threads do not change a bit
    np.testing.assert_array_equal(fz[0], fz[2])
    assert fz[1, -1] > 0 and abs(fz[0, -1] / fz[1, -1] - 1) < 0.01
    assert abs(fy[1, -1]) > 0 and abs(fy[0, -1] / fy[1, -1] - 1) < 0.02
