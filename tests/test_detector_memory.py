"""The load-memory detector: feature stage, C++ kernel against numpy, BPTT gradient, weights kinds."""
from __future__ import annotations

import json
import math
import zipfile

import numpy as np
import pytest
from tactile_mirror import _core
from tactile_mirror.detector import SlipDetector
from tactile_mirror.detector.core import reference_run
from tactile_mirror.detector.memory import MEMORY_CHANNELS, memory_features
from tactile_mirror.detector.network import Params, init_params, loss_and_grad
from tactile_mirror.detector.weights import FORMAT_VERSION, DetectorWeights, WeightsError

FS = 1000.0


def _signals(n_r=6, n=700, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    x = np.empty((n_r, 4, n))
    for r in range(n_r):
        ramp = np.clip((t - 0.1 * (r + 1) / n_r) * 8.0, 0, 1)
        x[r, 0] = 3e4 * ramp + 2e3 * rng.standard_normal(n)
        x[r, 1] = -2e4 * ramp + 2e3 * rng.standard_normal(n)
        x[r, 2] = 1e6 * rng.standard_normal(n)
        x[r, 3] = 1e6 * rng.standard_normal(n)
    return x


def _memory_weights(seed=3, n_hidden=16, tau=0.4):
    p = init_params(8, n_hidden, seed)
    p.b2[:] = [0.5, -0.5]
    x = memory_features(_signals(), FS, tau)
    scale = np.sqrt(np.mean(x ** 2, axis=(0, 2)))
    meta = {"features": "stress_rate_memory", "load_tau": tau}
    return DetectorWeights(p, np.zeros(8), scale, FS, meta)


def test_memory_features_recurrence_and_pad_channels():
    x = _signals(n_r=3, n=200)
    tau = 0.25
    f = memory_features(x, FS, tau)
    assert f.shape == (3, len(MEMORY_CHANNELS), 200)
    a = math.exp(-1.0 / (FS * tau))
    load = np.zeros((3, 2))
    for t in range(200):
        load[:, 0] = a * load[:, 0] + (x[:, 0, t] - x[:, 1, t]) / FS
        load[:, 1] = a * load[:, 1] + (x[:, 0, t] + x[:, 1, t]) / FS
        np.testing.assert_allclose(f[:, 4:6, t], load, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(f[:, 6, t], np.mean(x[:, 0, t] - x[:, 1, t]), rtol=1e-12)
        np.testing.assert_allclose(f[:, 7, t], np.mean(load[:, 0]), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(f[:, :4], x)


def test_memory_features_state_continues_across_blocks():
    x = _signals(n_r=2, n=300)
    whole = memory_features(x, FS, 0.5)
    a, s = memory_features(x[..., :117], FS, 0.5, return_state=True)
    b = memory_features(x[..., 117:], FS, 0.5, state=s)
    np.testing.assert_allclose(np.concatenate([a, b], axis=-1), whole, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("bad", [0.0, -1.0, np.inf, np.nan])
def test_memory_features_bad_tau(bad):
    with pytest.raises(ValueError, match="tau"):
        memory_features(_signals(n_r=1, n=10), FS, bad)


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-11), (np.float32, 2e-4)])
def test_cpp_memory_kernel_matches_numpy(dtype, tol):
    w = _memory_weights()
    x = _signals()
    ys_ref, _, yp_ref = reference_run(w, x)
    det = SlipDetector(w, dtype=dtype)
    ys, yn, yp = det.run(x)
    assert np.max(np.abs(ys - ys_ref)) < tol
    assert np.max(np.abs(yp - yp_ref)) < tol
    np.testing.assert_allclose(yn, 1 - ys, atol=1e-6 if dtype == np.float32 else 1e-15)
    # The numpy backend is the same reference.
    ys_np, _, _ = SlipDetector(w, backend="numpy").run(x)
    np.testing.assert_allclose(ys_np, ys_ref, atol=1e-14)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_cpp_memory_step_equals_run_and_blocks_continue(dtype):
    w = _memory_weights()
    x = _signals(n=150).astype(dtype)
    det = SlipDetector(w, dtype=dtype)
    ys, _, yp = det.run(x)
    det2 = SlipDetector(w, dtype=dtype)
    steps = np.stack([det2.step(x[:, :, t]) for t in range(x.shape[2])], axis=-1)  # (n_r, 3, n)
    rtol = 1e-12 if dtype == np.float64 else 1e-5
    np.testing.assert_allclose(steps[:, 0], ys, rtol=rtol, atol=rtol)
    np.testing.assert_allclose(steps[:, 2], yp, rtol=rtol, atol=rtol)
    det3 = SlipDetector(w, dtype=dtype)
    a = det3.run(x[..., :70])
    b = det3.run(x[..., 70:], reset=False)
    np.testing.assert_allclose(np.concatenate([a[0], b[0]], axis=-1), ys, rtol=rtol, atol=rtol)


def test_cpp_memory_rejects_nan_and_keeps_state():
    w = _memory_weights()
    x = _signals(n=50)
    det = SlipDetector(w)
    det.run(x[..., :20])
    k = det.kernel(x.shape[0])
    before = tuple(np.copy(s) for s in k.state)
    bad = x[..., 20:].copy()
    bad[2, 1, 5] = np.nan
    with pytest.raises(ValueError, match="ridge 2, channel 1, sample 5"):
        det.run(bad, reset=False)
    after = k.state
    np.testing.assert_array_equal(before[0], after[0])
    np.testing.assert_array_equal(before[1], after[1])


def test_bptt_gradient_eight_inputs_cpp_matches_numpy_and_finite_differences():
    rng = np.random.default_rng(1)
    s, n, h = 3, 60, 5
    xn = rng.standard_normal((s, 8, n))
    ts = (rng.random((s, n)) > 0.7).astype(float)
    tp = rng.random((s, n))
    ws = rng.random((s, n)) / (s * n)
    wp = rng.random((s, n)) / (s * n)
    theta = init_params(8, h, 4).pack()
    loss, grad = loss_and_grad(theta, xn, ts, tp, ws, wp, 8, h)
    length = np.full(s, n, dtype=np.intp)
    loss_c, grad_c = _core.jordan_loss_grad(theta, xn, ts, tp, ws, wp, length, h, 2)
    assert abs(loss_c - loss) < 1e-12 * max(1.0, abs(loss))
    np.testing.assert_allclose(grad_c, grad, rtol=1e-9, atol=1e-13)
    eps = 1e-6
    for j in rng.choice(theta.size, 12, replace=False):
        d = np.zeros_like(theta)
        d[j] = eps
        num = (loss_and_grad(theta + d, xn, ts, tp, ws, wp, 8, h)[0]
               - loss_and_grad(theta - d, xn, ts, tp, ws, wp, 8, h)[0]) / (2 * eps)
        assert abs(num - grad[j]) < 1e-6 * max(1.0, abs(num))


def test_weights_kind_roundtrip(tmp_path):
    w = _memory_weights()
    assert w.kind == "jordan_memory" and w.load_tau == 0.4
    path = tmp_path / "m.npz"
    w.save(path)
    with zipfile.ZipFile(path) as zf:
        assert "kind.npy" in zf.namelist()
    back = DetectorWeights.load(path)
    assert back.kind == "jordan_memory" and back.load_tau == 0.4
    np.testing.assert_array_equal(back.params.w1, w.params.w1)
    assert SlipDetector(back).kind == "jordan_memory"


def test_weights_memory_kind_needs_load_tau():
    w = _memory_weights()
    meta = dict(w.metadata)
    del meta["load_tau"]
    with pytest.raises(WeightsError, match="load_tau"):
        DetectorWeights(w.params, w.input_mean, w.input_scale, w.fs, meta)
    with pytest.raises(WeightsError, match="channels"):
        DetectorWeights(Params(w.params.w1[:, :5].copy(), w.params.b1, w.params.w2, w.params.b2),
                        w.input_mean[:4], w.input_scale[:4], w.fs, w.metadata)


def test_weights_kind_mismatch_is_refused(tmp_path):
    w = _memory_weights()
    path = tmp_path / "m.npz"
    w.save(path)
    data = dict(np.load(path, allow_pickle=False))
    data["kind"] = np.array("jordan")
    np.savez(tmp_path / "bad.npz", **data)
    with pytest.raises(WeightsError, match="does not match"):
        DetectorWeights.load(tmp_path / "bad.npz")
    data["kind"] = np.array("elman")
    np.savez(tmp_path / "bad2.npz", **data)
    with pytest.raises(WeightsError, match="kind must be one of"):
        DetectorWeights.load(tmp_path / "bad2.npz")


def test_version1_file_loads_as_jordan(tmp_path):
    """The paper's weights as bundled before ``kind`` existed (format_version 1) still load."""
    w = SlipDetector.paper().weights
    data = dict(np.load(_bundled("paper_detector.npz"), allow_pickle=False))
    assert int(data["format_version"]) == 1 and "kind" not in data
    back = DetectorWeights.load(_bundled("paper_detector.npz"))
    assert back.kind == "jordan" and back.load_tau is None
    np.testing.assert_array_equal(back.params.w1, w.params.w1)
    # Saved again, it becomes a version-2 file with kind "jordan".
    back.save(tmp_path / "p.npz")
    again = dict(np.load(tmp_path / "p.npz", allow_pickle=False))
    assert int(again["format_version"]) == FORMAT_VERSION == 2 and str(again["kind"]) == "jordan"
    # A version-2 file without kind is damaged.
    del again["kind"]
    np.savez(tmp_path / "nokind.npz", **again)
    with pytest.raises(WeightsError, match="kind"):
        DetectorWeights.load(tmp_path / "nokind.npz")


def _bundled(name):
    from importlib import resources

    return resources.files("tactile_mirror.detector").joinpath("data", name)


def test_memory_kernel_refuses_wrong_shapes():
    w = _memory_weights()
    p = w.params
    with pytest.raises(ValueError, match="w1 must have shape"):
        _core.MemoryJordanf64(p.w1[:, :5], p.b1, p.w2, p.b2, w.input_mean[:4], w.input_gain[:4], 6, FS, 0.5)
    with pytest.raises(ValueError, match="tau"):
        _core.MemoryJordanf64(p.w1, p.b1, p.w2, p.b2, w.input_mean, w.input_gain, 6, FS, 0.0)
    k = _core.MemoryJordanf64(p.w1, p.b1, p.w2, p.b2, w.input_mean, w.input_gain, 6, FS, 0.5)
    with pytest.raises(ValueError, match=r"x must have shape \(6, 4\)"):
        k.step(np.zeros((6, 8)))
    with pytest.raises(TypeError, match="float64"):
        k.step(np.zeros((6, 4), dtype=np.float32))


def test_memory_metadata_json():
    w = _memory_weights()
    json.dumps(w.metadata)


def test_build_options_kind_and_load_tau():
    from tactile_mirror.lab.detector.build_options import BuildOptions

    assert BuildOptions(kind="jordan_memory").kind == "jordan_memory"
    with pytest.raises(ValueError, match="kind"):
        BuildOptions(kind="elman")
    with pytest.raises(ValueError, match="load_tau"):
        BuildOptions(kind="jordan_memory", load_tau=0.0)


def test_training_memory_kind_from_results_records_tau():
    from types import SimpleNamespace

    from tactile_mirror.lab.detector.training import make_training_set, train_detector

    x = _signals(n_r=2, n=300)
    t = np.arange(300) / FS
    frac = np.zeros((2, 300))
    frac[:, 200:] = 1.0
    res = SimpleNamespace(features=x, fs=FS, t=t, slip_fraction=frac, v_out=np.zeros((2, 2, 300)))
    ts = make_training_set([res], features="stress_rate_memory", load_tau=0.2)
    assert ts.x.shape == (2, 8, 300) and ts.load_tau == 0.2
    w = train_detector(ts, n_hidden=3, maxiter=3, progress=False)
    assert w.kind == "jordan_memory" and w.load_tau == 0.2
    assert w.metadata["channels"] == list(MEMORY_CHANNELS)
    # The trained weights run in the C++ kernel like the numpy reference.
    ys, _, _ = SlipDetector(w).run(x)
    np.testing.assert_allclose(ys, reference_run(w, x)[0], atol=1e-11)


def test_pipeline_refuses_memory_weights_by_name():
    import tactile_mirror as tm

    with pytest.raises(ValueError, match="jordan_memory"):
        tm.MirrorPipeline(SlipDetector(_memory_weights()), FS, n_ridges=6)


def test_bundled_memory_net_loads_and_runs_like_numpy():
    det = SlipDetector.memory()
    assert det.kind == "jordan_memory" and det.features == "stress_rate" and det.n_channels == 4
    x = _signals(n_r=1, n=400)
    np.testing.assert_allclose(det.run(x)[0], reference_run(det.weights, x)[0], atol=1e-11)
