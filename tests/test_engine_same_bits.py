"""The same sweep gives the same bits wherever it runs.

One small sweep of each big job (a few contact scenes, one envelope class with short paths,
a tiny detector build with its hidden-size study, checkpoints and calibration) runs in this
process, on a thread pool, on a pool of spawned processes and on a dask ``LocalCluster``
with worker processes behind nannies. The parent's BLAS/OpenMP pools are set to 2 threads
here (threadpoolctl), and the thread variables to "2" for the workers it starts (the dask
nanny's too), so that no result can lean on the one-thread settings CI and the pools give:
each task pins its own. Asserted: identical arrays, byte-identical results files, the
same chosen net, and that an envelope resumed on workers resubmits only its missing rows.
"""
from __future__ import annotations

import concurrent.futures
import json
import multiprocessing
import os

import numpy as np
import pytest
from tactile_mirror.engine.threads import THREAD_VARIABLES

PLACES = ["threads", "processes", "dask"]
#: The scenes of the sweep: the build's training ranges, four short ones (about 0.05 s each).
N_SCENES = 4
ENVELOPE = {"speeds": (0.005,), "n_seeds": 2, "laws": ("open loop", "paper", "default"), "duration": 1.0}


@pytest.fixture(scope="module")
def parent_two_threads():
    """This process's BLAS/OpenMP pools at 2 threads and the thread variables at "2" (what
    the workers started from here read), for the whole module."""
    from threadpoolctl import threadpool_limits

    with pytest.MonkeyPatch.context() as mp:
        for name in THREAD_VARIABLES:
            mp.setenv(name, "2")
        with threadpool_limits(limits=2):
            yield


@pytest.fixture(scope="module")
def places(parent_two_threads):
    """The executors, started once: a thread pool, a spawned process pool, a dask
    ``LocalCluster`` (2 worker processes, 1 thread each; its nannies start the workers with
    the thread variables at 2); ``None`` for dask where it is not installed."""
    pools = {"threads": concurrent.futures.ThreadPoolExecutor(2),
             "processes": concurrent.futures.ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn"))}
    cluster = client = None
    try:
        import dask
        from dask.distributed import Client, LocalCluster
    except ImportError:
        pools["dask"] = None
    else:
        environ = {f"distributed.nanny.pre-spawn-environ.{name}": "2" for name in THREAD_VARIABLES}
        with dask.config.set(environ):
            cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
        pools["dask"] = client.get_executor()
        pools["dask workers' OMP_NUM_THREADS"] = set(client.run(lambda: os.environ.get("OMP_NUM_THREADS")).values())
    try:
        yield pools
    finally:
        if client is not None:
            client.close()
            cluster.close()
        pools["threads"].shutdown()
        pools["processes"].shutdown()


def _scenes():
    from tactile_mirror import scenes
    from tactile_mirror.lab.detector.build_options import TRAIN_KWARGS, TRAIN_SEED

    return scenes.random(N_SCENES, seed=TRAIN_SEED, **TRAIN_KWARGS)


def _build_options(n: int):
    from tactile_mirror.lab.detector.build_options import BuildOptions

    return BuildOptions(n_train=n, n_test=n, n_validation=n, n_hidden=3, maxiter=6, candidates=2,
                        checkpoint_every=3, study_sizes=(2, 3), progress=False,
                        calibrate_conditions={"noise-free": 0.1, "1 mV rms white": 0.1})


def sweep(executor, folder, train_results=None) -> dict:
    """The sweep on ``executor``: the scenes' results, the envelope's results file (bytes),
    the tiny build's weights and report (on ``train_results``, the serial run's scenes)."""
    from tactile_mirror.lab.detector.build import build_default
    from tactile_mirror.lab.detector.scene_cache import simulate_scenes
    from tactile_mirror.lab.loop.envelope import run_envelope

    folder.mkdir()
    out = {"scenes": simulate_scenes(_scenes(), False, executor=executor)}
    run_envelope(folder / "envelope.json", progress=False, executor=executor, **ENVELOPE)
    out["envelope"] = (folder / "envelope.json").read_bytes()
    res = out["scenes"] if train_results is None else train_results
    out["weights"], out["report"] = build_default(folder / "w.npz", _build_options(len(res)),
                                                  results=(res, res, res), executor=executor)
    return out


@pytest.fixture(scope="module")
def serial(places, tmp_path_factory):
    return sweep(None, tmp_path_factory.mktemp("same-bits") / "serial")


@pytest.fixture(scope="module")
def spread(places, serial, tmp_path_factory):
    """The sweep on each place, run once (the tests below read parts of it)."""
    done = {}

    def get(place):
        if place not in done:
            if places[place] is None:
                pytest.skip("dask.distributed is not installed")
            done[place] = sweep(places[place], tmp_path_factory.mktemp("same-bits") / place, serial["scenes"])
        return done[place]

    return get


SIGNALS = ("t", "plate_y", "indent", "stress", "v_out", "u_out", "slip_fraction", "ridge_slip_time", "force_y",
           "force_z")


def test_the_parent_and_the_dask_workers_start_with_two_threads(places):
    from threadpoolctl import threadpool_info

    assert os.environ["OMP_NUM_THREADS"] == "2"
    assert all(p["num_threads"] == 2 for p in threadpool_info() if p["user_api"] in ("blas", "openmp"))
    if places["dask"] is not None:
        assert places["dask workers' OMP_NUM_THREADS"] == {"2"}


@pytest.mark.parametrize("place", PLACES)
def test_scenes_are_the_same_arrays(place, serial, spread):
    got = spread(place)["scenes"]
    assert len(got) == len(serial["scenes"]) == N_SCENES
    for k, (a, b) in enumerate(zip(serial["scenes"], got)):
        for name in SIGNALS:
            x, y = getattr(a, name), getattr(b, name)
            if x is None:
                assert y is None, f"scene {k}: {name}"
                continue
            assert np.asarray(x).dtype == np.asarray(y).dtype, f"scene {k}: {name}"
            np.testing.assert_array_equal(x, y, err_msg=f"scene {k}: {name}")
        assert (a.slip_time, a.solves, a.events) == (b.slip_time, b.solves, b.events)


@pytest.mark.parametrize("place", PLACES)
def test_the_envelope_file_is_the_same_bytes(place, serial, spread):
    got = spread(place)["envelope"]
    rows = json.loads(serial["envelope"])["rows"]
    assert len(rows) == 2 * 3 and [r["law"] for r in rows[:3]] == ["open loop", "paper", "default"]
    assert got == serial["envelope"]


@pytest.mark.parametrize("place", PLACES)
def test_the_build_chooses_the_same_net(place, serial, spread):
    w0, r0 = serial["weights"], serial["report"]
    w1, r1 = spread(place)["weights"], spread(place)["report"]
    for name in ("w1", "b1", "w2", "b2"):
        np.testing.assert_array_equal(getattr(w0.params, name), getattr(w1.params, name), err_msg=name)
    np.testing.assert_array_equal(w0.input_mean, w1.input_mean)
    np.testing.assert_array_equal(w0.input_scale, w1.input_scale)
    assert r0["candidates"]["n_candidates"] == 2 * 3
    for part in ("candidates", "slip_calibration", "evaluation"):  # (assert_equal: a NaN equals a NaN)
        np.testing.assert_equal(r1[part], r0[part], err_msg=part)

    def study(r):
        return [{k: v for k, v in row.items() if k != "seconds"} for row in r["hidden_size_study"]]

    np.testing.assert_equal(study(r1), study(r0))
    assert [row["n_hidden"] for row in study(r0)] == [2, 3]


class CountingExecutor(concurrent.futures.Executor):
    """Another executor's tasks, counted: the rows (job tuples) apart from the warm-ups."""

    def __init__(self, inner):
        self.inner, self.submitted, self.warm_ups = inner, 0, 0

    def submit(self, fn, /, *args, **kwargs):
        if isinstance(args[1], tuple):
            self.submitted += 1
        else:
            self.warm_ups += 1
        return self.inner.submit(fn, *args, **kwargs)


def test_an_envelope_resumed_on_workers_runs_only_the_missing_rows(places, serial, tmp_path):
    """A run stopped after two rows (its file as the sink left it: no table yet) resumed on
    the process pool: the four missing rows are submitted, the file ends as the serial one."""
    from tactile_mirror.files import write_json
    from tactile_mirror.lab.loop.envelope import run_envelope

    data = json.loads(serial["envelope"])
    del data["table"]
    data["rows"] = data["rows"][:2]
    path = tmp_path / "envelope.json"
    write_json(path, data, indent=1)
    counting = CountingExecutor(places["processes"])
    run_envelope(path, progress=False, executor=counting, **ENVELOPE)
    assert counting.submitted == 4
    assert counting.warm_ups == os.cpu_count()  # (no pool size to read through the wrapper)
    assert path.read_bytes() == serial["envelope"]


def test_the_envelope_takes_an_executor_or_workers_not_both(tmp_path):
    from tactile_mirror.lab.loop.envelope import run_envelope

    with pytest.raises(ValueError, match="give executor or workers, not both"):
        run_envelope(tmp_path / "envelope.json", executor=concurrent.futures.ThreadPoolExecutor(1), workers=2,
                     **ENVELOPE)
    assert not (tmp_path / "envelope.json").exists()


def test_the_training_gradients_threads_do_not_change_the_weights():
    """Each training task runs the C++ gradient with the thread count the driver fixes (1 on
    workers, up to 2 here): the kept weights must not depend on it."""
    from tactile_mirror.lab.detector.selection import ValidationScorer, task_threads, train_selected
    from tactile_mirror.lab.detector.synthetic import synthetic_scene
    from tactile_mirror.lab.detector.training import make_training_set

    ts = make_training_set([synthetic_scene(seed=s, n_ridges=2, duration=1.2) for s in range(3)])
    scorer = ValidationScorer([synthetic_scene(seed=50 + s, n_ridges=1, duration=1.2) for s in range(2)])
    kept = [train_selected(ts, 3, 8, 0, 2, 4, scorer, progress=False, n_threads=n) for n in (1, 2, 3)]
    for w, k, scores in kept[1:]:
        assert k == kept[0][1]
        np.testing.assert_equal(scores, kept[0][2])
        for name in ("w1", "b1", "w2", "b2"):
            np.testing.assert_array_equal(getattr(w.params, name), getattr(kept[0][0].params, name))
    assert task_threads({}, spread=True) == 1 and task_threads({"n_threads": 3}, spread=True) == 3
    assert task_threads({}, spread=False) == min(2, os.cpu_count() or 1)
