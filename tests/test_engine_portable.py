"""The baseline kernels: one process-wide switch (kernels.use_baseline, TM_SIMD=baseline), and
the portable mode of run_tasks that gives a worker on AVX2+FMA and one on the baseline the
same bits, where without it the worker of the other path is refused."""
from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import subprocess
import sys

import numpy as np
import pytest
from tactile_mirror import kernels
from tactile_mirror.engine import BuildMismatch, run_tasks

HAS_AVX2 = kernels.simd_paths()["contact"] == "avx2+fma"


def scene_and_detector(scene):
    """A scene simulated and two detectors run on it (the fast sigmoid, float64 and float32),
    with the paths the kernels reported inside the task."""
    import tactile_mirror as tm
    from tactile_mirror.detector import SlipDetector, features_from_result

    res = tm.simulate(scene)
    out = {"paths": kernels.simd_paths(), "v_out": res.v_out, "u_out": res.u_out, "force_y": res.force_y}
    for name, det in (("bank", SlipDetector.default(activation="fast")),
                      ("paper", SlipDetector.paper(activation="fast", dtype=np.float32))):
        out[name] = np.stack(det.run(features_from_result(res, det.features)))
    return out


def baseline_now(_):
    return kernels.baseline_in_use()


def _pool(monkeypatch, simd):
    """A pool of one spawned process, started with TM_SIMD=``simd`` (None: unset)."""
    with monkeypatch.context() as m:
        if simd is None:
            m.delenv("TM_SIMD", raising=False)
        else:
            m.setenv("TM_SIMD", simd)
        pool = concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        assert pool.submit(os.getenv, "TM_SIMD").result(timeout=120) == simd  # started now, with it
    return pool


@pytest.fixture(scope="module")
def pools():
    mp = pytest.MonkeyPatch()
    best, base = _pool(mp, None), _pool(mp, "baseline")
    yield best, base
    best.shutdown()
    base.shutdown()


def test_use_baseline_holds_every_family_to_the_baseline_and_restores_the_best():
    import tactile_mirror as tm
    from tactile_mirror.detector import SlipDetector

    best = kernels.simd_paths()
    assert not kernels.baseline_in_use()
    before = SlipDetector.paper()
    before.run(np.zeros((4, 8)))
    kernels.use_baseline(True)
    try:
        assert kernels.baseline_in_use()
        assert set(kernels.simd_paths().values()) == {"sse2" if best["filters"] != "generic" else "generic"}
        assert tm.simd_path() == kernels.simd_paths()["filters"] and not kernels.detector_has_avx2_fma()
        after = SlipDetector.paper()
        after.run(np.zeros((4, 8)))
        assert after.simd_path == kernels.simd_paths()["detector"]  # built under the switch
        assert before.simd_path == best["detector"]  # built before: keeps its path
        if HAS_AVX2:
            with pytest.raises(ValueError, match="held to the baseline"):
                after.kernel(1).set_simd_path("avx2+fma")
    finally:
        kernels.use_baseline(False)
    assert kernels.simd_paths() == best and not kernels.baseline_in_use()
    with pytest.raises(TypeError, match="on must be a bool"):
        kernels.use_baseline("yes")
    assert kernels.simd_paths() == best


def test_tm_simd_is_read_at_import_and_a_wrong_value_is_named():
    code = "from tactile_mirror import kernels; print(kernels.baseline_in_use(), kernels.simd_paths()['contact'])"
    env = {**os.environ, "TM_SIMD": "baseline"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[0] == "True" and out.stdout.split()[1] in ("sse2", "generic", "native")
    env["TM_SIMD"] = "avx512"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode != 0
    assert "TM_SIMD must be 'baseline' or 'auto' (or unset), got 'avx512'" in out.stderr


@pytest.mark.skipif(not HAS_AVX2, reason="needs a CPU with AVX2+FMA for two paths")
def test_portable_mode_gives_a_best_path_worker_and_a_baseline_worker_the_same_bits(pools):
    import tactile_mirror as tm

    best, base = pools
    scene = tm.scenes.paper("fig6", duration=0.6, noise=1e-3)
    # without the portable mode each worker runs its own path, and the bits differ ...
    fast = run_tasks(scene_and_detector, [scene], executor=best, progress=False)[0]
    assert set(fast["paths"].values()) == {"avx2+fma"}
    with pytest.raises(BuildMismatch, match=r"simd: driver \{'filters': 'avx2\+fma'.*worker [^ ]+ "
                                            r"\{'filters': 'sse2'") as info:
        run_tasks(scene_and_detector, [scene], executor=base, progress=False)
    assert list(info.value.differences) == ["simd"]
    # ... with it, both run the baseline: the same bits
    a = run_tasks(scene_and_detector, [scene], executor=best, portable=True, progress=False)[0]
    b = run_tasks(scene_and_detector, [scene], executor=base, portable=True, progress=False)[0]
    assert set(a["paths"].values()) == set(b["paths"].values()) == {"sse2"}
    differ = []
    for name in ("v_out", "u_out", "force_y", "bank", "paper"):
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
        if not np.array_equal(a[name], fast[name]):
            differ.append(name)
    assert "v_out" in differ and "paper" in differ  # the paths really round apart
    # the worker started on the baseline stays there after a portable task; this process too
    assert run_tasks(baseline_now, [0], executor=base, check_build=False, progress=False)[0] is True
    serial = run_tasks(scene_and_detector, [scene], portable=True, progress=False)[0]
    assert not kernels.baseline_in_use()
    np.testing.assert_array_equal(serial["paper"], a["paper"])
