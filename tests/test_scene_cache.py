"""The detector build's scene cache: one file per scene, a stopped sweep resumes, sets share
their scenes, an unusable file is a miss with a warning."""
from __future__ import annotations

import os
import zipfile

import numpy as np
import pytest
from tactile_mirror.contact import simulation
from tactile_mirror.engine import StoreWarning, TaskError, pinned_threads
from tactile_mirror.engine.store import ResultStore
from tactile_mirror.lab.detector import scene_cache
from tactile_mirror.lab.detector.scene_cache import simulate_cached, simulate_scenes

KW = {"duration": 1.0, "noise": 1e-3}
ARRAYS = ("t", "plate_y", "indent", "stress", "v_out", "u_out", "slip_fraction", "ridge_slip_time", "force_y",
          "force_z")


@pytest.fixture
def counted(monkeypatch):
    """The scenes simulate() was called with (the sweeps run in this process: workers=1);
    ``fail_at``: the call that raises instead, as a crash half-way through a sweep."""
    real = simulation.simulate
    calls = []
    fail_at = []

    def simulate(scene, **kwargs):
        if len(calls) in fail_at:
            raise RuntimeError("the machine went away")
        calls.append(scene)
        return real(scene, **kwargs)

    monkeypatch.setattr(simulation, "simulate", simulate)
    simulate.calls, simulate.fail_at, simulate.real = calls, fail_at, real
    return simulate


def assert_same(a, b):
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert (a.slip_time, a.solves, a.events, a.fs) == (b.slip_time, b.solves, b.events, b.fs)


def files(folder):
    return sorted(n for n in os.listdir(folder) if n.endswith(".npz"))


@pytest.mark.parametrize("stop", ["a task fails", "ctrl-c in the sink"])
def test_a_sweep_stopped_half_way_resumes_with_the_missing_scenes_only(stop, tmp_path, counted, monkeypatch):
    if stop == "a task fails":
        counted.fail_at.append(3)
        with pytest.raises(TaskError, match="task 3 failed"):
            simulate_cached(6, 5, KW, tmp_path, progress=False, workers=1)
    else:
        real_save, saved = ResultStore.save, []

        def save(self, *args):
            if len(saved) == 3:
                raise KeyboardInterrupt
            saved.append(real_save(self, *args))

        monkeypatch.setattr(ResultStore, "save", save)
        with pytest.raises(KeyboardInterrupt):
            simulate_cached(6, 5, KW, tmp_path, progress=False, workers=1)
        monkeypatch.setattr(ResultStore, "save", real_save)
    assert len(files(tmp_path)) == 3  # each result written as it arrived
    done = list(counted.calls)
    counted.fail_at.clear()
    res = simulate_cached(6, 5, KW, tmp_path, progress=False, workers=1)
    scenes = scene_cache.random_scenes(6, 5, **KW)
    assert counted.calls[len(done):] == scenes[3:]  # only the missing ones
    assert len(files(tmp_path)) == 6
    assert [r.scene for r in res] == scenes
    again = simulate_cached(6, 5, KW, tmp_path, progress=False, workers=1)
    assert len(counted.calls) == len(done) + 3  # all read back
    with pinned_threads(1):
        direct = [counted.real(s) for s in scenes]
    for r, a, d, s in zip(res, again, direct, scenes):
        assert a.scene == s
        assert_same(r, d)
        assert_same(a, d)


def test_sets_that_overlap_share_their_scenes_and_read_back_the_same_bits(tmp_path, counted):
    small = simulate_cached(3, 9, KW, tmp_path, progress=False, workers=1)
    assert len(counted.calls) == 3
    big = simulate_cached(5, 9, KW, tmp_path, progress=False, workers=1)  # the first 3 are small's
    assert len(counted.calls) == 5
    for a, b in zip(small, big):
        assert_same(a, b)
    other = scene_cache.random_scenes(2, 10, **KW)
    mixed = simulate_scenes([big[4].scene, other[0], big[0].scene], progress=False, workers=1, cache_dir=tmp_path)
    assert counted.calls[5:] == [other[0]]
    assert_same(mixed[0], big[4])
    assert_same(mixed[2], big[0])
    # the portable mode's results are kept apart (other bits on an AVX2 machine)
    simulate_scenes([other[0]], progress=False, workers=1, cache_dir=tmp_path, portable=True)
    assert counted.calls[6:] == [other[0]]
    assert len(files(tmp_path)) == 7


def _damage(path, how):
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif how == "empty":
        path.write_bytes(b"")
    elif how == "flipped bytes":  # inside an array's data: its CRC no longer holds
        m = len(data) // 2
        path.write_bytes(data[:m] + bytes(b ^ 0xFF for b in data[m:m + 16]) + data[m + 16:])
    elif how == "pickle":
        import pickle

        path.write_bytes(pickle.dumps({"rows": []}))
    elif how == "another format":
        np.savez(path.open("wb"), format=np.array("tactile-mirror recording"), format_version=np.array(1))
    elif how in ("another scene", "another build", "short arrays"):
        with zipfile.ZipFile(path) as z:
            members = {n: np.load(z.open(n)) for n in z.namelist()}
        arrays = {n[:-4]: a for n, a in members.items()}
        if how == "another scene":
            arrays["content"] = np.array("simulate " + "0" * 64)
        elif how == "another build":
            arrays["identity"] = np.array(str(arrays["identity"]).replace('"core":"', '"core":"x'))
        else:
            for name in ("t", "plate_y"):
                arrays["x_" + name] = arrays["x_" + name][:-1]
        with path.open("wb") as f:
            np.savez(f, **arrays)


@pytest.mark.parametrize("how", ["truncated", "empty", "flipped bytes", "pickle", "another format",
                                 "another scene", "another build", "short arrays"])
def test_an_unusable_cache_file_is_a_miss_with_a_warning_and_is_replaced(how, tmp_path, counted):
    first = simulate_cached(2, 4, KW, tmp_path, progress=False, workers=1)
    path = tmp_path / files(tmp_path)[1]
    _damage(path, how)
    with pytest.warns(StoreWarning, match=f"cache file unusable, a miss: '{path}'"):
        res = simulate_cached(2, 4, KW, tmp_path, progress=False, workers=1)
    assert len(counted.calls) == 3
    for a, b in zip(res, first):
        assert_same(a, b)
    assert files(tmp_path) == sorted(n for n in os.listdir(tmp_path))  # replaced in place, no temporary left
    assert len(files(tmp_path)) == 2
    simulate_cached(2, 4, KW, tmp_path, progress=False, workers=1)  # a hit again
    assert len(counted.calls) == 3


def test_the_cache_folder_is_checked_before_simulating_and_comes_from_the_environment(tmp_path, counted,
                                                                                       monkeypatch):
    target = tmp_path / "cache"
    target.write_text("not a folder")
    with pytest.raises(NotADirectoryError, match=f"cache_dir '{target}' is a file"):
        simulate_cached(2, 1, KW, target, progress=False)
    with pytest.raises(OSError, match="cache_dir"):
        simulate_cached(2, 1, KW, target / "sub", progress=False)  # its parent is a file
    with pytest.raises(TypeError, match="cache_dir"):
        simulate_cached(2, 1, KW, 3.5, progress=False)
    with pytest.raises(TypeError, match="kwargs must be a dict"):
        simulate_cached(2, 1, [("duration", 1.0)], progress=False)
    with pytest.raises(ValueError, match="workers must be a positive integer"):
        simulate_scenes(scene_cache.random_scenes(1, 1, **KW), workers=0)
    assert counted.calls == []
    monkeypatch.setenv("TM_CACHE_DIR", str(tmp_path / "env"))
    simulate_cached(1, 1, KW, progress=False)
    assert len(files(tmp_path / "env")) == 1
    monkeypatch.delenv("TM_CACHE_DIR")
    simulate_cached(1, 1, KW, progress=False)  # no folder: nothing kept, simulated again
    assert len(counted.calls) == 2


def test_a_run_that_stopped_before_its_field_times_reads_back_from_the_cache(tmp_path, counted):
    import warnings

    from tactile_mirror.scenes import Scene

    s = Scene(duration=2.0, outputs=frozenset({"stress", "fields"}), field_times=(1.9,), stop_after_slip=0.0,
              friction=0.3)
    first = simulate_scenes([s], progress=False, workers=1, cache_dir=tmp_path)[0]
    assert first.fields == {} and first.t[-1] < 1.9  # slipped and stopped before 1.9 s
    with warnings.catch_warnings():
        warnings.simplefilter("error", StoreWarning)
        again = simulate_scenes([s], progress=False, workers=1, cache_dir=tmp_path)[0]
    assert len(counted.calls) == 1 and again.fields == {}
    np.testing.assert_array_equal(again.stress, first.stress)
