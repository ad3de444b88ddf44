"""Scene compares and hashes by content: a scene that went to a worker equals the one sent, and
its content key is the same in every process."""
from __future__ import annotations

import concurrent.futures
import dataclasses
import multiprocessing
import pickle

import numpy as np
import tactile_mirror as tm
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.engine import run_tasks
from tactile_mirror.geometry import RidgeGeometry
from tactile_mirror.noise import SensorNoise


def echo(scene):
    return scene, scene.content_key


def with_trajectory(**kw):
    y = np.linspace(0.0, 1e-4, 300)
    z = np.full(300, 2e-5)
    return tm.Scene(trajectory=(y, z), **kw)


def test_equal_content_is_equal_and_any_field_that_differs_makes_another_scene():
    a, b = tm.scenes.paper("fig7"), tm.scenes.paper("fig7")
    assert a is not b and a == b and hash(a) == hash(b) and a.content_key == b.content_key
    assert len(a.content_key) == 64 and int(a.content_key, 16) >= 0
    assert tm.Scene(duration=2) == tm.Scene(duration=2.0) == tm.Scene(duration=np.float64(2.0))
    assert tm.Scene(seed=3) == tm.Scene(seed=np.int64(3))
    assert with_trajectory() == with_trajectory()
    base = tm.Scene()
    others = [tm.Scene(duration=2.0 + 1e-12), tm.Scene(stops=((1.0, 1.05),)), tm.Scene(friction=0.5),
              tm.Scene(outputs=frozenset({"forces"})), tm.Scene(geometry=RidgeGeometry(mesh_size=0.3e-3)),
              tm.Scene(circuit=PVDFCircuit(Rf=2e9)), tm.Scene(noise_model=SensorNoise(hum=1e-3)),
              tm.Scene(n_ridges=2), tm.Scene(stop_after_slip=0.0), with_trajectory()]
    keys = {s.content_key for s in others} | {base.content_key}
    assert len(keys) == len(others) + 1
    assert all(s != base for s in others)
    y, z = with_trajectory().trajectory
    y2 = y.copy()
    y2[150] = np.nextafter(y2[150], 1.0)  # one ulp of one sample
    assert tm.Scene(trajectory=(y2, z)) != with_trajectory()
    assert tm.Scene(outputs=frozenset({"forces", "slip"})) == tm.Scene(outputs={"slip", "forces"})
    assert base != "a scene" and base != dataclasses.asdict(base)
    assert len({a, b, base, tm.Scene()}) == 2  # usable as dict keys and in sets
    assert dataclasses.replace(a, friction=0.5) != a and dataclasses.replace(a, friction=0.5) == \
        tm.scenes.paper("fig7", friction=0.5)


def test_a_scene_sent_through_any_executor_comes_back_equal_with_the_same_key():
    scenes = [tm.scenes.paper("fig8", noise_model=SensorNoise(hum=1e-3)), with_trajectory(noise=1e-3)]
    keys = [s.content_key for s in scenes]
    assert "content_key" not in pickle.loads(pickle.dumps(scenes[0])).__dict__  # recomputed, not carried
    back = pickle.loads(pickle.dumps(scenes[1]))
    assert back == scenes[1] and back.trajectory[0] is not scenes[1].trajectory[0]
    with concurrent.futures.ThreadPoolExecutor(2) as threads, \
            concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as procs:
        for executor in (None, threads, procs):
            out = run_tasks(echo, scenes, executor=executor, progress=False)
            assert [s for s, _ in out] == scenes
            assert [k for _, k in out] == keys  # the same key in another process (another hash seed)



def test_a_float32_field_is_not_the_float64_scene_and_an_unpickled_scene_stays_read_only():
    # simulate computes a float32 friction otherwise than the float64 of its value
    assert tm.Scene(friction=np.float32(0.5)) != tm.Scene(friction=0.5)
    assert tm.Scene(friction=np.float32(0.5)) == tm.Scene(friction=np.float32(0.5))
    back = pickle.loads(pickle.dumps(with_trajectory()))
    assert not back.trajectory[0].flags.writeable and not back.trajectory[1].flags.writeable
    assert back == pickle.loads(pickle.dumps(back))
