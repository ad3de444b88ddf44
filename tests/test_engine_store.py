"""ResultStore: one file per key, atomic and bounded, evicting the files used longest ago."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest
from tactile_mirror._npzfile import Member
from tactile_mirror.engine.store import (
    DEFAULT_LIMIT,
    ResultStore,
    StoreWarning,
    default_folder,
    parse_size,
)

ID = {"package": "0.1.0", "core": "abc", "simd": "baseline"}
MEMBERS = {"y": Member("f", 1, (1000,)), "n": Member("i", 0)}


def payload(k):
    return {"y": np.arange(100.0) * k, "n": np.array(k)}, {"k": k, "text": "é"}


def test_a_saved_result_reads_back_whole_and_the_key_names_input_and_build(tmp_path):
    store = ResultStore(tmp_path)
    arrays, meta = payload(3)
    path = store.save("input-a", ID, arrays, meta)
    got, got_meta = store.load("input-a", ID, MEMBERS)
    np.testing.assert_array_equal(got["y"], arrays["y"])
    assert int(got["n"]) == 3 and got_meta == meta
    assert os.path.basename(path) == store.key("input-a", ID) + ".npz"
    assert store.key("input-a", ID) == ResultStore.key("input-a", dict(reversed(list(ID.items()))))
    assert len({store.key("input-a", ID), store.key("input-b", ID), store.key("input-a", {**ID, "simd": "avx2"})}) == 3
    assert store.load("input-b", ID, MEMBERS) is None  # absent: a quiet miss
    assert store.load("input-a", {**ID, "core": "def"}, MEMBERS) is None
    assert os.listdir(tmp_path) == [os.path.basename(path)]  # no temporary left


def test_a_file_beyond_the_readers_bounds_or_that_decode_refuses_is_a_miss(tmp_path):
    store = ResultStore(tmp_path)
    store.save("big", ID, {"y": np.zeros(5000), "n": np.array(1)}, {})
    with pytest.warns(StoreWarning, match="y has 5000 entries along axis 0, at most 1000"):
        assert store.load("big", ID, MEMBERS) is None

    def refuse(arrays, meta):
        raise ValueError("3 ridges, the scene has 1")

    store.save("small", ID, *payload(1))
    with pytest.warns(StoreWarning, match="does not hold a result of this input: 3 ridges"):
        assert store.load("small", ID, MEMBERS, refuse) is None
    assert store.load("small", ID, MEMBERS, lambda a, m: m["k"]) == 1


def test_over_the_limit_the_files_used_longest_ago_go_first(tmp_path):
    store = ResultStore(tmp_path)
    paths = [store.save(f"input-{k}", ID, *payload(k)) for k in range(4)]
    size = os.path.getsize(paths[0])
    now = time.time()
    for k, p in enumerate(paths):  # written in order, an hour apart
        os.utime(p, (now - 3600 * (4 - k), now - 3600 * (4 - k)))
    assert store.load("input-0", ID, MEMBERS) is not None  # a read makes input-0 the newest
    (tmp_path / "notes.txt").write_text("not the store's")
    stale = tmp_path / f".{'a' * 64}.npz.0123abcd.tmp"
    fresh = tmp_path / f".{'b' * 64}.npz.0123abcd.tmp"
    stale.write_bytes(b"x")
    fresh.write_bytes(b"x")
    os.utime(stale, (now - 7200, now - 7200))
    small = ResultStore(tmp_path, limit=int(2.5 * size))
    small.save("input-4", ID, *payload(4))  # five files: over the limit, back to two
    left = sorted(os.listdir(tmp_path))
    assert os.path.basename(paths[1]) not in left and os.path.basename(paths[2]) not in left
    assert os.path.basename(paths[3]) not in left
    assert small.load("input-0", ID, MEMBERS) is not None and small.load("input-4", ID, MEMBERS) is not None
    assert "notes.txt" in left and fresh.name in left and stale.name not in left
    assert small.size() == 2 * size


def test_settings_come_from_arguments_then_the_environment(tmp_path, monkeypatch):
    monkeypatch.delenv("TM_CACHE_DIR", raising=False)
    monkeypatch.delenv("TM_CACHE_LIMIT", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_folder() == str(tmp_path / "xdg" / "tactile-mirror")
    assert ResultStore().limit == DEFAULT_LIMIT
    monkeypatch.setenv("TM_CACHE_DIR", str(tmp_path / "env"))
    monkeypatch.setenv("TM_CACHE_LIMIT", "1.5G")
    store = ResultStore()
    assert store.folder == str(tmp_path / "env") and store.limit == int(1.5 * 2**30)
    assert ResultStore(tmp_path / "arg", limit="20M").limit == 20 * 2**20
    assert [parse_size(v) for v in (4096, "4096", "4K", "4 KiB", "2m", "1T")] == [4096, 4096, 4096, 4096, 2**21, 2**40]
    for bad, error, match in ((0, ValueError, "limit must be positive"), ("lots", ValueError, "suffix K, M, G"),
                              (1.5, TypeError, "integer number of bytes"), (True, TypeError, "integer")):
        with pytest.raises(error, match=match):
            ResultStore(tmp_path, limit=bad)
    monkeypatch.setenv("TM_CACHE_LIMIT", "-3")
    with pytest.raises(ValueError, match="TM_CACHE_LIMIT must be a size"):
        ResultStore(tmp_path)
    (tmp_path / "file").write_text("x")
    with pytest.raises(NotADirectoryError, match="is a file"):
        ResultStore(tmp_path / "file", limit=10)
    with pytest.raises(TypeError, match="folder must be a path"):
        ResultStore(3.5, limit=10)
    store = ResultStore(tmp_path / "s", limit=10**6)
    with pytest.raises(TypeError, match="must be a numpy array of numbers"):
        store.save("k", ID, {"y": np.array([object()])}, {})
    with pytest.raises(TypeError, match="meta must be JSON-serialisable"):
        store.save("k", ID, {}, {"x": object()})
    assert not os.path.exists(tmp_path / "s") or os.listdir(tmp_path / "s") == []


def test_a_result_larger_than_the_limit_is_not_kept_and_costs_no_other_file(tmp_path):
    store = ResultStore(tmp_path, limit=100_000)
    kept = [store.save(f"input-{k}", ID, *payload(k)) for k in range(3)]
    with pytest.warns(StoreWarning, match="larger than the store's limit of 100000 bytes: not kept"):
        assert store.save("huge", ID, {"y": np.zeros(20_000), "n": np.array(0)}, {}) is None
    assert sorted(os.listdir(tmp_path)) == sorted(os.path.basename(p) for p in kept)
    # the file just written is never the one trimmed, and a replaced file is counted once
    small = ResultStore(tmp_path, limit=os.path.getsize(kept[0]) + 10)
    path = small.save("input-9", ID, *payload(9))
    assert os.listdir(tmp_path) == [os.path.basename(path)]
    assert small.save("input-9", ID, *payload(9)) == path and os.path.exists(path)


def test_keys_a_file_cannot_hold_are_refused_when_saved_not_missed_forever(tmp_path):
    store = ResultStore(tmp_path)
    with pytest.raises(ValueError, match="content_key has 300 characters, more than the 256"):
        store.save("k" * 300, ID, *payload(1))
    with pytest.raises(ValueError, match="identity takes .* more than the 8192"):
        store.save("k", {"huge": "x" * 9000}, *payload(1))
    assert os.listdir(tmp_path) == []
