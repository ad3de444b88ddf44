"""Same build or refuse: a worker whose identity differs from the driver's is refused with both
sides named, before any of its results is used; the check costs a dict comparison per task."""
from __future__ import annotations

import concurrent.futures
import multiprocessing

import pytest
from tactile_mirror.engine import BuildMismatch, build_identity, identity, run_tasks, spread, task_identity


def square(x):
    return x * x


def forge(entry, value):
    """Pool initializer: this worker reports ``value`` for ``entry`` of its identity (a worker
    with another core, another numpy, ...)."""
    real = identity.build_identity

    def forged():
        return {**real(), entry: value}

    spread.build_identity = forged


def forged_pool(entry, value):
    return concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                                  initializer=forge, initargs=(entry, value))


@pytest.mark.parametrize("portable", [False, True])
def test_a_worker_with_another_core_is_refused_naming_both_sides_before_a_result_is_used(portable):
    mine = build_identity()
    seen = []
    with forged_pool("core", "0123forged") as pool:
        with pytest.raises(BuildMismatch) as info:
            run_tasks(square, range(5), executor=pool, sink=lambda k, v: seen.append(k), portable=portable,
                      on_error="continue", progress=False)  # (a mismatch is never carried on)
    assert seen == []
    assert info.value.differences == {"core": (mine["core"], "0123forged")}
    message = str(info.value)
    assert f"core: driver {mine['core']!r}, worker " in message and "'0123forged'" in message
    assert "install the same wheel on every worker" in message


def test_a_forged_driver_is_refused_by_a_real_worker_and_portable_forgives_only_the_kernel_paths(monkeypatch):
    real = identity.build_identity
    monkeypatch.setattr(spread, "build_identity", lambda: {**real(), "numpy": "1.0.0"})
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        with pytest.raises(BuildMismatch, match=r"numpy: driver '1\.0\.0', worker [^ ]+ '"):
            run_tasks(square, [1, 2], executor=pool, progress=False)
        other_paths = {"filters": "neon", "detector": "neon", "contact": "neon"}
        monkeypatch.setattr(spread, "build_identity", lambda: {**real(), "simd": other_paths})
        with pytest.raises(BuildMismatch, match="simd: driver .*'neon'"):
            run_tasks(square, [1, 2], executor=pool, progress=False)
        assert list(run_tasks(square, [1, 2], executor=pool, portable=True, progress=False)) == [1, 4]
        assert list(run_tasks(square, [1, 2], executor=pool, check_build=False, progress=False)) == [1, 4]


def test_the_identity_is_computed_once_per_process_but_the_kernel_paths_each_time(monkeypatch):
    from tactile_mirror import kernels

    first = build_identity()
    assert list(first) == list(identity.IDENTITY_KEYS)

    def no_second_hash(*args, **kwargs):
        raise AssertionError("the core was hashed again")

    monkeypatch.setattr(identity.hashlib, "sha256", no_second_hash)
    monkeypatch.setattr(identity.metadata, "version", no_second_hash)
    assert build_identity() == first
    kernels.use_baseline(True)
    try:
        assert build_identity()["simd"] == kernels.simd_paths()
        assert task_identity(portable=True)["simd"] == "baseline"
    finally:
        kernels.use_baseline(False)
    assert build_identity() == first
    assert task_identity() == first
