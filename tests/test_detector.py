"""Slip detector: numpy reference, BPTT gradient, weights file, C++ kernel parity and API."""
from __future__ import annotations

import json
import re
import zipfile

import numpy as np
import pytest
import tactile_mirror as tm
from tactile_mirror.detector import (
    DetectorWeights,
    Params,
    SlipDetector,
    WeightsError,
    forward,
    init_params,
    loss_and_grad,
    reference_run,
)
from tactile_mirror.lab.detector import TrainingSet, make_training_set, train_detector
from tactile_mirror.lab.detector.synthetic import synthetic_scene

core = pytest.importorskip("tactile_mirror._core")

FS = 1000.0


def random_weights(n_hidden=16, seed=0, scale=1.0, fs=1000.0):
    rng = np.random.default_rng(seed)
    p = Params(scale * rng.normal(size=(n_hidden, 5)), rng.normal(size=n_hidden),
               scale * rng.normal(size=(2, n_hidden)), rng.normal(size=2))
    p.w1[:, -1] = 3.0 * rng.normal(size=n_hidden)  # strong feedback: a real recurrence
    return DetectorWeights(p, rng.normal(size=4), rng.uniform(0.5, 2.0, 4), fs,
                           {"features": "stress_rate"})


def random_features(n_ridges, n, seed=1):
    rng = np.random.default_rng(seed)
    # Piecewise-slow signals with bursts: exercise saturated and linear regions.
    x = np.cumsum(rng.normal(size=(n_ridges, 4, n)), axis=-1) * 0.05
    x += rng.standard_t(2, size=(n_ridges, 4, n)) * 0.3
    return x


# -- numpy reference and gradient -----------------------------------------------------------

def test_forward_matches_naive_loop():
    w = random_weights(5, seed=3)
    x = random_features(2, 50)
    xn = (x - w.input_mean[None, :, None]) / w.input_scale[None, :, None]
    ys, yp = forward(w.params, xn)
    p = w.params
    for s in range(2):
        prev = 0.0
        for t in range(50):
            u = np.append(xn[s, :, t], prev)
            h = 1 / (1 + np.exp(-(p.w1 @ u + p.b1)))
            o = 1 / (1 + np.exp(-(p.w2 @ h + p.b2)))
            assert ys[s, t] == pytest.approx(o[0], abs=1e-14)
            assert yp[s, t] == pytest.approx(o[1], abs=1e-14)
            prev = o[1]


@pytest.mark.parametrize("feedback", [True, False])
def test_bptt_gradient_matches_finite_differences(feedback):
    rng = np.random.default_rng(0)
    n_hidden, s, n = 5, 3, 40
    theta = init_params(4, n_hidden, seed=1).pack() + 0.3 * rng.normal(size=n_hidden * 5 + n_hidden + 2 * n_hidden + 2)
    x = rng.normal(size=(s, 4, n))
    ts = (rng.uniform(size=(s, n)) > 0.6).astype(float)
    tp = rng.uniform(size=(s, n))
    ws = rng.uniform(size=(s, n)) / (s * n)
    wp = rng.uniform(size=(s, n)) / (s * n)
    args = (x, ts, tp, ws, wp, 4, n_hidden)
    f0, g = loss_and_grad(theta, *args, l2=1e-2, feedback=feedback)
    h = 1e-6
    num = np.empty_like(theta)
    for k in range(theta.size):
        e = np.zeros_like(theta)
        e[k] = h
        num[k] = (loss_and_grad(theta + e, *args, l2=1e-2, feedback=feedback)[0]
                  - loss_and_grad(theta - e, *args, l2=1e-2, feedback=feedback)[0]) / (2 * h)
    if not feedback:
        fb = np.arange(n_hidden) * 5 + 4
        num[fb] = 0.0  # held at zero in the no-feedback net
        assert np.all(g[fb] == 0.0)
    np.testing.assert_allclose(g, num, rtol=1e-5, atol=1e-8)
    # The feedback path matters: the recurrent gradient differs from a truncated one.
    assert np.isfinite(f0)


def _loss_problem(seed=0, n_hidden=6, s=11, n=300, scale=1.0):
    rng = np.random.default_rng(seed)
    theta = scale * rng.normal(size=n_hidden * 5 + 3 * n_hidden + 2)
    x = rng.normal(size=(s, 4, n)) + rng.standard_t(2, size=(s, 4, n)) * 0.3
    length = rng.integers(1, n + 1, s)
    length[0] = n
    length[1] = 0  # an empty sequence contributes nothing
    real = np.arange(n)[None, :] < length[:, None]
    x *= real[:, None, :]
    ts = (rng.uniform(size=(s, n)) > 0.6).astype(float)
    tp = rng.uniform(size=(s, n))
    ws = rng.uniform(size=(s, n)) / (s * n) * real
    wp = rng.uniform(size=(s, n)) / (s * n) * real
    return theta, x, ts, tp, ws, wp, length


@pytest.mark.parametrize("scale", [1.0, 8.0])
def test_cpp_loss_and_gradient_match_numpy(scale):
    theta, x, ts, tp, ws, wp, length = _loss_problem(scale=scale)
    f_ref, g_ref = loss_and_grad(theta, x, ts, tp, ws, wp, 4, 6)
    f1, g1 = core.jordan_loss_grad(theta, x, ts, tp, ws, wp, length, 6, 1)
    np.testing.assert_allclose(f1, f_ref, rtol=1e-12)
    np.testing.assert_allclose(g1, g_ref, rtol=1e-12, atol=1e-12 * np.abs(g_ref).max())
    # The sums are made in fixed blocks: the thread count changes no bit.
    f3, g3 = core.jordan_loss_grad(theta, x, ts, tp, ws, wp, length, 6, 3)
    assert f3 == f1
    np.testing.assert_array_equal(g3, g1)


def test_loss_is_exact_when_outputs_saturate():
    # Logits of +-60: y rounds to 1.0 or 0.0, where log(1 - y) would give -inf or a
    # clipped constant; softplus(o) - t o stays the exact cross-entropy.
    p = Params(np.zeros((1, 5)), np.zeros(1), np.array([[0.0], [0.0]]), np.array([60.0, -60.0]))
    x = np.zeros((1, 4, 3))
    ts, tp = np.zeros((1, 3)), np.ones((1, 3))
    w = np.full((1, 3), 1.0)
    f, g = loss_and_grad(p.pack(), x, ts, tp, w, w, 4, 1)
    assert f == pytest.approx(3 * 60.0 + 3 * 60.0, rel=1e-12)
    f_c, g_c = core.jordan_loss_grad(p.pack(), x, ts, tp, w, w, np.array([3]), 1)
    assert f_c == pytest.approx(f, rel=1e-12)
    np.testing.assert_allclose(g_c, g, rtol=1e-12)


def test_cpp_loss_validation_names_arguments():
    theta, x, ts, tp, ws, wp, length = _loss_problem(s=3, n=20)
    ok = (theta, x, ts, tp, ws, wp, length, 6)
    with pytest.raises(ValueError, match="theta must have shape"):
        core.jordan_loss_grad(theta[:-1], *ok[1:])
    bad = theta.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="theta must be finite"):
        core.jordan_loss_grad(bad, *ok[1:])
    with pytest.raises(ValueError, match="t_pred must have shape"):
        core.jordan_loss_grad(theta, x, ts, tp[:, :-1], ws, wp, length, 6)
    with pytest.raises(ValueError, match="length must be in"):
        core.jordan_loss_grad(theta, x, ts, tp, ws, wp, np.array([1, 2, 21]), 6)
    with pytest.raises(TypeError, match="length must be an integer"):
        core.jordan_loss_grad(theta, x, ts, tp, ws, wp, length.astype(float), 6)
    with pytest.raises(TypeError, match="xn must have dtype float64"):
        core.jordan_loss_grad(theta, x.astype(np.float32), ts, tp, ws, wp, length, 6)
    with pytest.raises(ValueError, match="n_threads"):
        core.jordan_loss_grad(*ok, 0)


@pytest.mark.parametrize("feedback", [True, False])
def test_cpp_training_objective_with_weight_decay_matches_numpy(feedback):
    from tactile_mirror.lab.detector.training import cpp_loss, loss_weights

    ts = small_set(2)
    xn = ts.x / ts.x.std(axis=(0, 2))[None, :, None]
    ws, wp = loss_weights(ts, 4.0, 10.0)
    theta = np.random.default_rng(0).normal(size=6 * 5 + 6 * 3 + 2)
    f_c, g_c = cpp_loss(xn, ts, ws, wp, 6, 1e-2, feedback, 2)(theta)
    f_n, g_n = loss_and_grad(theta, xn, ts.y_slip, ts.y_pred, ws, wp, 4, 6, l2=1e-2, feedback=feedback)
    assert f_c == pytest.approx(f_n, rel=1e-12)
    np.testing.assert_allclose(g_c, g_n, rtol=1e-12, atol=1e-12 * np.abs(g_n).max())


def test_training_backends_agree():
    ts = small_set(3)
    w_c = train_detector(ts, n_hidden=4, maxiter=10, seed=3, progress=False, backend="cpp")
    w_n = train_detector(ts, n_hidden=4, maxiter=10, seed=3, progress=False, backend="numpy")
    assert w_c.metadata["training"]["backend"] == "cpp"
    # Same function to round-off: a few L-BFGS steps end at the same weights.
    np.testing.assert_allclose(w_c.params.pack(), w_n.params.pack(), rtol=1e-6, atol=1e-8)
    w_nf = train_detector(ts, n_hidden=3, maxiter=5, feedback=False, progress=False, backend="cpp")
    assert np.all(w_nf.params.w1[:, -1] == 0.0)
    with pytest.raises(ValueError, match="backend"):
        train_detector(ts, n_hidden=3, maxiter=1, progress=False, backend="torch")
    with pytest.raises(ValueError, match="n_threads"):
        train_detector(ts, n_hidden=3, maxiter=1, progress=False, n_threads=0)


def small_set(n_scenes=4, seed=0, ridges=2):
    res = [synthetic_scene(seed=seed + k, n_ridges=ridges, duration=1.6) for k in range(n_scenes)]
    return make_training_set(res)


def test_training_is_deterministic_and_reduces_loss():
    ts = small_set()
    w1 = train_detector(ts, n_hidden=4, maxiter=15, seed=7, progress=False)
    w2 = train_detector(ts, n_hidden=4, maxiter=15, seed=7, progress=False)
    np.testing.assert_array_equal(w1.params.pack(), w2.params.pack())
    w0 = train_detector(ts, n_hidden=4, maxiter=1, seed=7, progress=False)
    assert w1.metadata["training"]["loss"] < w0.metadata["training"]["loss"]
    assert w1.fs == ts.fs
    assert w1.metadata["features"] == "stress_rate"


def test_no_feedback_training_keeps_feedback_weights_zero():
    w = train_detector(small_set(2), n_hidden=3, maxiter=5, feedback=False, progress=False)
    assert np.all(w.params.w1[:, -1] == 0.0)
    assert w.metadata["feedback"] is False


def test_training_set_validation():
    with pytest.raises(ValueError, match="x must have shape"):
        TrainingSet(np.zeros((2, 3, 5)), np.zeros((2, 5)), np.zeros((2, 5)), np.ones((2, 5), bool), 1000.0)
    with pytest.raises(ValueError, match="y_pred"):
        TrainingSet(np.zeros((2, 4, 5)), np.zeros((2, 5)), np.zeros((2, 4)), np.ones((2, 5), bool), 1000.0)
    with pytest.raises(ValueError, match="n_hidden"):
        train_detector(small_set(1), n_hidden=0, progress=False)
    # sets that trained on nothing, or reached the optimiser as "theta must be finite"
    x, y, m = np.zeros((2, 4, 5)), np.zeros((2, 5)), np.ones((2, 5), bool)
    with pytest.raises(ValueError, match="no real sample"):
        TrainingSet(x, y, y, np.zeros((2, 5), bool), 1000.0)
    with pytest.raises(ValueError, match="no real sample"):
        TrainingSet(np.zeros((0, 4, 5)), np.zeros((0, 5)), np.zeros((0, 5)), np.zeros((0, 5), bool), 1000.0)
    with pytest.raises(ValueError, match=r"y_slip targets must lie in \[0, 1\]"):
        TrainingSet(x, np.full((2, 5), 5.0), y, m, 1000.0)
    with pytest.raises(ValueError, match="y_pred targets"):
        TrainingSet(x, y, np.full((2, 5), np.nan), m, 1000.0)
    for kw in ({"l2": float("nan")}, {"pred_weight": -1.0}, {"negative_weight": float("inf")}):
        with pytest.raises(ValueError, match=next(iter(kw))):
            train_detector(small_set(1), progress=False, **kw)


def test_seeds_iterations_and_save_folders_are_named_in_their_errors(tmp_path, capsys):
    from tactile_mirror.cli import main
    from tactile_mirror.lab.detector.training import make_training_set, train_detector

    with pytest.raises(SystemExit):
        main(["evaluate", "--seed", "-5"])
    assert "argument --seed: must be non-negative" in capsys.readouterr().err
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        tm.SensorNoise().draw(1000.0, 10, seed=-1)
    ts = make_training_set([synthetic_scene(seed=0, n_ridges=1, duration=0.5)])
    for kw, match in (({"seed": -1}, "seed"), ({"maxiter": "3"}, "maxiter"), ({"maxiter": float("nan")}, "maxiter")):
        with pytest.raises(ValueError, match=match):
            train_detector(ts, n_hidden=2, progress=False, **kw)
    # the save's message names the file asked for, not the hidden temporary beside it
    with pytest.raises(FileNotFoundError, match=r"cannot save .*w\.npz.*does not exist") as exc:
        tm.SlipDetector.default().save(tmp_path / "no" / "sub" / "w.npz")
    assert ".tmp" not in str(exc.value)


# -- C++ kernel parity ------------------------------------------------------------------------

@pytest.mark.parametrize("path", ["generic", "avx2+fma"])
def test_cpp_float64_parity_over_a_million_steps(path):
    w = random_weights(16, seed=5)
    x = random_features(6, 170_000, seed=2)  # 6 ridges x 170k = 1.02e6 recurrent steps
    det = SlipDetector(w, dtype=np.float64)
    k = det.kernel(6)
    if path == "avx2+fma" and not core.detector_cpu_has_avx2_fma():
        pytest.skip("CPU without AVX2+FMA")
    k.set_simd_path(path)
    ys, yn, yp = det.run(x)
    rs, rn, rp = reference_run(w, x)
    assert np.max(np.abs(ys - rs)) <= 1e-12
    assert np.max(np.abs(yp - rp)) <= 1e-12
    assert np.max(np.abs(yn - rn)) <= 1e-12
    # The feedback is exercised: y_pred spans a wide range.
    assert rp.min() < 0.1 and rp.max() > 0.9


@pytest.mark.slow
def test_cpp_float64_parity_single_chain_of_a_million_steps():
    w = random_weights(16, seed=6)
    x = random_features(1, 1_000_000, seed=4)
    ys, _, yp = SlipDetector(w).run(x)
    rs, _, rp = reference_run(w, x)
    assert np.max(np.abs(ys - rs)) <= 1e-12 and np.max(np.abs(yp - rp)) <= 1e-12


@pytest.mark.parametrize("activation", ["exact", "fast"])
@pytest.mark.parametrize("path", ["generic", "avx2+fma"])
def test_cpp_float32_parity(activation, path):
    w = random_weights(16, seed=8)
    x = random_features(6, 40_000, seed=3)
    det = SlipDetector(w, dtype=np.float32, activation=activation)
    if path == "avx2+fma" and not core.detector_cpu_has_avx2_fma():
        pytest.skip("CPU without AVX2+FMA")
    det.kernel(6).set_simd_path(path)
    ys, _, yp = det.run(x)
    assert ys.dtype == np.float32
    rs, _, rp = reference_run(w, x.astype(np.float32))
    assert np.max(np.abs(ys - rs)) <= 1e-5
    assert np.max(np.abs(yp - rp)) <= 1e-5


def test_fast_sigmoid_float64_error_bound():
    w = random_weights(16, seed=9)
    x = random_features(6, 20_000, seed=5)
    ys, _, yp = SlipDetector(w, activation="fast").run(x)
    rs, _, rp = reference_run(w, x)
    # 5e-10 per sigmoid, amplified by at most a few through the layers and the feedback.
    assert np.max(np.abs(ys - rs)) <= 1e-8
    assert np.max(np.abs(yp - rp)) <= 1e-8


def test_step_equals_run_and_state_carries_over():
    w = random_weights(8, seed=10)
    x = random_features(6, 300, seed=6)
    det = SlipDetector(w)
    ys, yn, yp = det.run(x)
    det2 = SlipDetector(w)
    out = np.stack([det2.step(x[:, :, t]) for t in range(300)], axis=-1)  # (6, 3, n)
    np.testing.assert_allclose(out[:, 0], ys, atol=1e-13)
    np.testing.assert_allclose(out[:, 1], yn, atol=1e-13)
    np.testing.assert_allclose(out[:, 2], yp, atol=1e-13)
    # Two blocks with reset=False equal one block.
    a = det.run(x[:, :, :120])
    b = det.run(x[:, :, 120:], reset=False)
    np.testing.assert_allclose(np.concatenate([a[2], b[2]], axis=1), yp, atol=1e-15)
    k = det.kernel(6)
    np.testing.assert_allclose(k.state, yp[:, -1], atol=1e-15)
    k.reset()
    assert np.all(k.state == 0)
    for n in (0, 2**40, 2.0, True):
        with pytest.raises(ValueError, match=r"n_ridges must be an integer in \[1, 65536\]"):
            det.kernel(n)
    # a complex sample is refused as run() refuses complex features (numpy would drop its
    # imaginary part with only a warning), and the state stays
    for backend in ("cpp", "numpy"):
        d = SlipDetector(w, backend=backend)
        before = d.step(x[:, :, 0])
        with pytest.raises(TypeError, match="sample must hold real numbers"):
            d.step(x[:, :, 1] * (1 + 1j))
        np.testing.assert_allclose(d.step(x[:, :, 1]), out[:, :, 1], atol=1e-13)
        assert before.shape == (6, 3)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("n_inputs", [4, 8, 17, 5])
def test_kernel_step_and_block_give_the_same_bits(n_inputs, dtype):
    # The block path precomputes the input projections of a chunk (8 and 17 inputs,
    # several groups of ridges) and adds the feedback afterwards; summed in the same
    # order, it must give step()'s bits, for every group size and activation.
    cls = getattr(core, "JordanMLPf64" if dtype == np.float64 else "JordanMLPf32")
    rng = np.random.default_rng(n_inputs)
    for n_ridges in (1, 2, 3, 6, 7, 13):
        for act in ("exact", "fast"):
            w1, b1 = rng.normal(size=(16, n_inputs + 1)), rng.normal(size=16)
            w2, b2 = rng.normal(size=(2, 16)), rng.normal(size=2)
            mean, gain = rng.normal(size=n_inputs), rng.uniform(0.5, 2.0, size=n_inputs)
            a = cls(w1, b1, w2, b2, mean, gain, n_ridges, act)
            b = cls(w1, b1, w2, b2, mean, gain, n_ridges, act)
            x = rng.normal(size=(n_ridges, n_inputs, 150)).astype(dtype)  # > 2 chunks
            ys, _, yp = a.run(x)
            steps = np.stack([b.step(np.ascontiguousarray(x[:, :, t])) for t in range(x.shape[2])], axis=-1)
            np.testing.assert_array_equal(steps[:, 0], ys, err_msg=f"{n_ridges} ridges, {act}")
            np.testing.assert_array_equal(steps[:, 2], yp, err_msg=f"{n_ridges} ridges, {act}")


def test_numpy_backend_matches_cpp():
    w = random_weights(8, seed=11)
    x = random_features(3, 500, seed=7)
    a = SlipDetector(w, backend="numpy").run(x)
    b = SlipDetector(w).run(x)
    for u, v in zip(a, b):
        np.testing.assert_allclose(u, v, atol=1e-12)


def test_kernel_input_validation_names_arguments_and_keeps_state():
    w = random_weights(4, seed=12)
    k = SlipDetector(w).kernel(6)
    k.run(random_features(6, 10))
    before = k.state.copy()
    with pytest.raises(ValueError, match="x must have shape"):
        k.run(np.zeros((5, 4, 10)))
    with pytest.raises(TypeError, match="x must have dtype float64"):
        k.run(np.zeros((6, 4, 10), np.float32))
    with pytest.raises(ValueError, match="x must have shape"):
        k.step(np.zeros((6, 3)))
    with pytest.raises(ValueError, match="state must have shape"):
        k.state = np.zeros(5)
    np.testing.assert_array_equal(k.state, before)
    with pytest.raises(ValueError, match="w2 must have shape"):
        core.JordanMLPf64(np.zeros((4, 5)), np.zeros(4), np.zeros((2, 3)), np.zeros(2), np.zeros(4),
                          np.ones(4), 6)
    with pytest.raises(ValueError, match="input_gain must be finite"):
        core.JordanMLPf64(np.zeros((4, 5)), np.zeros(4), np.zeros((2, 4)), np.zeros(2), np.zeros(4),
                          np.array([1, np.nan, 1, 1]), 6)
    with pytest.raises(ValueError, match="n_instances"):
        core.JordanMLPf64(np.zeros((4, 5)), np.zeros(4), np.zeros((2, 4)), np.zeros(2), np.zeros(4),
                          np.ones(4), 0)
    with pytest.raises(ValueError, match="activation"):
        core.JordanMLPf32(np.zeros((4, 5)), np.zeros(4), np.zeros((2, 4)), np.zeros(2), np.zeros(4),
                          np.ones(4), 6, "tanh")
    with pytest.raises(ValueError, match="path"):
        k.set_simd_path("neon")


def test_detector_run_validation_and_fs_check():
    det = SlipDetector(random_weights(4, fs=1000.0))
    with pytest.raises(ValueError, match="features must have shape"):
        det.run(np.zeros((6, 5, 10)))
    with pytest.raises(TypeError, match="features must hold real numbers"):
        det.run(np.zeros((6, 4, 10), dtype=complex))
    with pytest.raises(WeightsError, match="fs=2000.0 Hz"):
        det.run(np.zeros((6, 4, 10)), fs=2000.0)
    ys, _yn, _yp = det.run(np.zeros((4, 10)), fs=1000.0)
    assert ys.shape == (10,)
    with pytest.raises(TypeError, match="dtype"):
        SlipDetector(random_weights(4), dtype=np.int32)
    with pytest.raises(ValueError, match="backend"):
        SlipDetector(random_weights(4), backend="torch")


def _detector(backend, dtype=np.float64):
    w = DetectorWeights(init_params(4, 6, seed=0), input_mean=np.zeros(4), input_scale=np.ones(4), fs=FS)
    return SlipDetector(w, dtype=dtype, backend=backend)


@pytest.mark.parametrize("backend,dtype", [("cpp", np.float64), ("cpp", np.float32), ("numpy", np.float64)])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_features_are_refused_naming_the_sample(backend, dtype, value):
    det = _detector(backend, dtype)
    x = np.random.default_rng(1).normal(size=(3, 4, 20))
    first = x[:, :, :10].copy()
    det.run(first)
    x[1, 2, 5] = value
    x[2, 0, 7] = value
    with pytest.raises(ValueError, match=r"ridge 1, channel 2, sample 5"):
        det.run(x)
    with pytest.raises(ValueError, match=r"ridge 1, channel 2, sample 5"):
        det.run(x, reset=False)
    # the state is what the last good call left
    ref = _detector(backend, dtype)
    ref.run(first)
    good = np.random.default_rng(2).normal(size=(3, 4, 5))
    np.testing.assert_array_equal(det.run(good, reset=False)[2], ref.run(good, reset=False)[2])
    if backend == "cpp":
        with pytest.raises(ValueError, match="ridge 0, channel 3, sample 0"):
            det.step(np.array([[0, 0, 0, value], [0, 0, 0, 0], [0, 0, 0, 0]], dtype=float))


def _rates(n_ridges, n, seed=0):
    return np.random.default_rng(seed).normal(0, 1e3, (n_ridges, 4, n))


@pytest.mark.parametrize("make", [lambda: tm.SlipDetector.default(), lambda: tm.SlipDetector.memory(),
                                  lambda: tm.SlipDetector.pad(),
                                  lambda: tm.SlipDetector.default(backend="numpy"),
                                  lambda: tm.SlipDetector.memory(backend="numpy")])
def test_finite_features_that_overflow_a_filter_are_refused_with_the_state_kept(make):
    """1e308 is finite and passed the NaN/Inf check, but the filter bank's leaky integrals
    overflowed to inf and every later output was one constant (NaN in numpy) until reset()."""
    det, ref = make(), make()
    x = _rates(6, 40)
    det.run(x[..., :20])
    ref.run(x[..., :20])
    with pytest.raises(ValueError, match="overflow"):
        det.run(np.full((6, 4, 30), 1e308), reset=False)
    if det.backend == "cpp":
        with pytest.raises(ValueError, match="overflow"):
            for _ in range(200):  # a few ticks in a row: the integrals reach inf
                det.step(np.full((6, 4), 1e308))
    # the state is what it was: the continuation equals the undisturbed detector's
    for a, b in zip(det.run(x[..., 20:], reset=False), ref.run(x[..., 20:], reset=False)):
        np.testing.assert_array_equal(a, b)


def test_float32_detector_names_a_value_beyond_float32():
    det = tm.SlipDetector.default(dtype=np.float32)
    x = _rates(1, 12)
    x[0, 2, 7] = 1e300
    with pytest.raises(ValueError, match="fit float32.*ridge 0, channel 2, sample 7"):
        det.run(x)


def test_numpy_backend_runs_an_empty_block_as_the_compiled_one_does():
    for backend in ("numpy", "cpp"):
        det = tm.SlipDetector.paper(backend=backend)
        det.run(_rates(2, 10))
        ys, yn, yp = det.run(np.zeros((2, 4, 0)), reset=False)
        assert ys.shape == yn.shape == yp.shape == (2, 0)


def test_no_subnormal_outputs_in_float32_kernel():
    w = random_weights(8, seed=13, scale=50.0)  # saturates everything
    x = random_features(6, 2000, seed=8) * 100
    for act in ("exact", "fast"):
        ys, _, yp = SlipDetector(w, dtype=np.float32, activation=act).run(x)
        tiny = np.finfo(np.float32).tiny
        for y in (ys, yp):
            assert not np.any((y != 0) & (np.abs(y) < tiny))
            assert np.all((y >= 0) & (y <= 1))


# -- weights file ---------------------------------------------------------------------------

def test_weights_roundtrip(tmp_path):
    w = random_weights(6, seed=14)
    w.metadata["training"] = {"seed": 3}
    path = tmp_path / "w.npz"
    w.save(path)
    w2 = DetectorWeights.load(path)
    np.testing.assert_array_equal(w2.params.pack(), w.params.pack())
    np.testing.assert_array_equal(w2.input_scale, w.input_scale)
    assert w2.fs == w.fs and w2.metadata == w.metadata
    det = SlipDetector.load(path)
    x = random_features(2, 50)
    np.testing.assert_array_equal(det.run(x)[0], SlipDetector(w).run(x)[0])


def _rewrite(path, out, **changes):
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            del data[k]
        else:
            data[k] = v
    with open(out, "wb") as f:
        np.savez(f, **data)


@pytest.mark.parametrize("changes, message", [
    ({"format_version": np.array(3)}, "format_version 3 is not supported"),
    ({"format_version": None}, "format_version missing"),
    ({"format": np.array("something-else")}, "not a detector weights file"),
    ({"w2": np.zeros((3, 6))}, r"w2 must have shape \(2, 6\)"),
    ({"b1": np.zeros(5)}, r"b1 must have shape \(6,\)"),
    ({"input_scale": np.array([1.0, 0.0, 1.0, 1.0])}, "input_scale must be positive"),
    ({"w1": np.full((6, 5), np.nan)}, "w1 contains non-finite values"),
    ({"w1": np.zeros((6, 5), dtype=np.int64)}, "w1 must be a float array"),
    ({"fs": np.array(-5.0)}, "fs must be a positive"),
    ({"metadata": np.array("{not json")}, "metadata is not valid JSON"),
    ({"metadata": np.array(json.dumps({"features": "pressure"}))}, "metadata\\['features'\\]"),
    ({"input_mean": None}, "key 'input_mean' missing"),
])
def test_corrupt_weights_files_are_rejected(tmp_path, changes, message):
    good = tmp_path / "good.npz"
    random_weights(6, seed=15).save(good)
    bad = tmp_path / "bad.npz"
    _rewrite(good, bad, **changes)
    with pytest.raises(WeightsError, match=message):
        DetectorWeights.load(bad)


def test_truncated_and_garbage_files_are_rejected(tmp_path):
    good = tmp_path / "good.npz"
    random_weights(6, seed=16).save(good)
    data = good.read_bytes()
    trunc = tmp_path / "trunc.npz"
    trunc.write_bytes(data[: len(data) // 2])
    with pytest.raises(WeightsError, match="not a readable detector weights file"):
        DetectorWeights.load(trunc)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"\x00" * 100)
    with pytest.raises(WeightsError):
        DetectorWeights.load(garbage)
    # A zip of non-array members.
    z = tmp_path / "zip.npz"
    with zipfile.ZipFile(z, "w") as f:
        f.writestr("w1.npy", b"not an array")
    with pytest.raises(WeightsError):
        DetectorWeights.load(z)
    with pytest.raises(FileNotFoundError):
        DetectorWeights.load(tmp_path / "missing.npz")


def test_weights_with_a_subnormal_scale_are_refused_at_load_naming_the_file(tmp_path):
    """input_scale = 1e-320 passed "> 0", but the kernel's gain 1 / scale is inf: the first
    run failed naming input_gain, and the numpy backend returned NaN."""
    orig = str(tmp_path / "orig.npz")
    tm.SlipDetector.paper().weights.save(orig)
    with np.load(orig) as f:
        data = dict(f)
    data["input_scale"] = data["input_scale"].copy()
    data["input_scale"][1] = 1e-320
    path = str(tmp_path / "w.npz")
    np.savez(path, **data)
    with pytest.raises(WeightsError, match=r"w\.npz.*input_scale must be positive and normal"):
        DetectorWeights.load(path)


def test_weights_object_validation():
    w = random_weights(4)
    with pytest.raises(WeightsError, match="fs must be a positive"):
        DetectorWeights(w.params, w.input_mean, w.input_scale, 0.0, {})
    with pytest.raises(WeightsError, match="metadata must be JSON"):
        DetectorWeights(w.params, w.input_mean, w.input_scale, 1000.0, {"x": object()})
    with pytest.raises(WeightsError, match=r"input_mean must have shape \(4,\)"):
        DetectorWeights(w.params, np.zeros(3), w.input_scale, 1000.0, {})
    with pytest.raises(WeightsError, match="fs=500.0 Hz does not match"):
        w.check_compatible(fs=500.0)
    with pytest.raises(WeightsError, match="features='circuit'"):
        w.check_compatible(features="circuit")


@pytest.mark.parametrize("dtype, tol", [(np.float64, 1e-13), (np.float32, 2e-6)])
@pytest.mark.parametrize("activation", ["exact", "fast"])
def test_step_one_scalar_path_matches_block_run(dtype, tol, activation):
    w = random_weights(16, seed=17)
    x = random_features(3, 400, seed=9)
    det = SlipDetector(w, dtype=dtype, activation=activation)
    ys, yn, yp = det.run(x)
    k = SlipDetector(w, dtype=dtype, activation=activation).kernel(3)
    for r in range(3):
        out = np.stack([k.step_one(r, x[r, :, t].astype(dtype)) for t in range(400)], axis=-1)
        np.testing.assert_allclose(out[0], ys[r], atol=tol)
        np.testing.assert_allclose(out[1], yn[r], atol=tol)
        np.testing.assert_allclose(out[2], yp[r], atol=tol)
    with pytest.raises(ValueError, match="instance must be in"):
        k.step_one(3, x[0, :, 0].astype(dtype))


def test_timing_loop_restores_state():
    k = SlipDetector(random_weights(16, seed=18), dtype=np.float32).kernel(6)
    k.run(random_features(6, 50).astype(np.float32))
    before = k.state.copy()
    assert k.time_step_ns(1000, repeats=1) > 0
    assert k.time_step_ns(1000, repeats=1, mode="scalar") > 0
    np.testing.assert_array_equal(k.state, before)
    with pytest.raises(ValueError, match="mode"):
        k.time_step_ns(10, mode="vector")


@pytest.mark.parametrize("dtype, activation, bound", [
    (np.float64, "exact", 1e-15), (np.float64, "fast", 5e-10),
    (np.float32, "exact", 1.2e-7), (np.float32, "fast", 2.5e-7)])
@pytest.mark.parametrize("path", ["generic", "avx2+fma"])
def test_sigmoid_error_bound(dtype, activation, bound, path):
    from scipy.special import expit

    if path == "avx2+fma" and not core.detector_cpu_has_avx2_fma():
        pytest.skip("CPU without AVX2+FMA")
    a = np.linspace(-100, 100, 400_001).astype(dtype)
    y = core.detector_sigmoid(a, activation, path).astype(np.float64)
    assert np.max(np.abs(y - expit(a.astype(np.float64)))) <= bound
    assert np.all((y >= 0) & (y <= 1))
    tiny = np.finfo(dtype).tiny
    assert not np.any((y != 0) & (y < tiny))


def test_onset_windows_mark_the_first_samples_of_every_slip():
    from tactile_mirror.lab.detector.training import onset_windows

    y = np.array([[0, 0, 1, 1, 1, 1, 0, 1, 1, 0, 0],
                  [1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0],
                  [0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1]], dtype=float)
    mask = np.ones(y.shape, dtype=bool)
    mask[2, 9:] = False  # padding is never a window sample
    w = onset_windows(y, mask, 3)
    np.testing.assert_array_equal(w.astype(int), [[0, 0, 1, 1, 1, 0, 0, 1, 1, 0, 0],
                                                  [1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0],
                                                  [0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0]])
    assert not onset_windows(y, mask, 0).any()


def test_onset_weight_adds_the_window_as_a_class_of_its_own():
    from tactile_mirror.lab.detector.training import loss_weights, onset_windows

    ts = small_set(2)
    base, wp = loss_weights(ts, 4.0, 10.0)
    ws, wp2 = loss_weights(ts, 4.0, 10.0, onset_weight=2.0, onset_window=0.02)
    win = onset_windows(ts.y_slip, ts.mask, int(round(0.02 * ts.fs)))
    assert win.any()
    np.testing.assert_array_equal(ws[~win], base[~win])  # only the window's samples change
    assert ws[win].sum() - base[win].sum() == pytest.approx(0.5 * 2.0)  # half the weight of the slip class x 2
    np.testing.assert_array_equal(wp2, wp)
    w = train_detector(ts, n_hidden=3, maxiter=2, progress=False, onset_weight=2.0, onset_window=0.02)
    assert w.metadata["training"]["onset_weight"] == 2.0
    assert "onset_weight" not in train_detector(ts, n_hidden=3, maxiter=2, progress=False).metadata["training"]
    for bad in ({"onset_weight": -1.0}, {"onset_weight": np.nan}, {"onset_window": 0.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            train_detector(ts, n_hidden=3, maxiter=1, progress=False, **bad)


def test_sample_weight_multiplies_the_slip_loss_and_is_checked():
    ts = small_set(2)
    w0 = train_detector(ts, n_hidden=3, maxiter=4, seed=1, progress=False)
    ones = train_detector(ts, n_hidden=3, maxiter=4, seed=1, progress=False, sample_weight=np.ones(ts.mask.shape))
    np.testing.assert_array_equal(ones.params.pack(), w0.params.pack())  # x 1 is no change, bit for bit
    assert ones.metadata["training"]["sample_weight"] == "per-sample multipliers"
    assert "sample_weight" not in w0.metadata["training"]
    heavy = np.ones(ts.mask.shape)
    heavy[0] = 50.0  # one sequence dominates
    w1 = train_detector(ts, n_hidden=3, maxiter=4, seed=1, progress=False, sample_weight=heavy)
    assert not np.allclose(w1.params.pack(), w0.params.pack())
    for bad, msg in ((np.ones((1, 3)), "shape"), (-heavy, ">= 0"), (np.full(ts.mask.shape, np.nan), "finite"),
                     (np.ones(ts.mask.shape, dtype=complex), "real array")):
        with pytest.raises(ValueError, match=f"sample_weight.*{re.escape(msg)}"):
            train_detector(ts, n_hidden=3, maxiter=1, progress=False, sample_weight=bad)


def test_warm_start_continues_from_the_given_weights():
    ts = small_set(2)
    w = train_detector(ts, n_hidden=3, maxiter=10, seed=2, progress=False)
    more = train_detector(ts, n_hidden=3, maxiter=5, seed=99, progress=False, init=w)
    # L-BFGS-B never ends above where it started: the warm start's objective is w's own
    assert more.metadata["training"]["loss"] <= w.metadata["training"]["loss"] * (1 + 1e-12)
    assert more.metadata["training"]["warm_start"] is True
    # the seed plays no part in a warm start
    again = train_detector(ts, n_hidden=3, maxiter=5, seed=5, progress=False, init=w)
    np.testing.assert_array_equal(again.params.pack(), more.params.pack())
    with pytest.raises(ValueError, match="init has 3 hidden units"):
        train_detector(ts, n_hidden=4, maxiter=1, progress=False, init=w)
    with pytest.raises(ValueError, match="normalised differently"):
        train_detector(small_set(2, seed=10), n_hidden=3, maxiter=1, progress=False, init=w)
    with pytest.raises(TypeError, match="init must be DetectorWeights"):
        train_detector(ts, n_hidden=3, maxiter=1, progress=False, init=w.params)


def test_hard_example_weights_mark_near_false_alarms_and_missed_onsets():
    from tactile_mirror.lab.detector.training import hard_example_weights

    y = np.array([[0, 0, 0, 1, 1, 1, 1, 0, 0, 0, 0, 0],
                  [0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 0, 0]], dtype=float)
    mask = np.ones(y.shape, dtype=bool)
    mask[1, 10:] = False
    ts = TrainingSet(np.zeros((2, 4, 12)), y, y, mask, 1000.0)
    out = np.array([[0.1, 0.6, 0.2, 0.3, 0.9, 0.9, 0.9, 0.1, 0.1, 0.5, 0.1, 0.1],   # onset found (0.9 within 3)
                    [0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.3, 0.7, 0.7, 0.95, 0.9, 0.9]])  # onset missed; padding high
    m = hard_example_weights(out, ts, factor=3.0, negative_level=0.5, onset_window=0.003)
    want = np.ones(y.shape)
    want[0, 1] = want[0, 9] = 3.0           # near false alarms, at and above the level
    want[1, 6:9] = 3.0                      # the missed onset's window (its first 3 samples)
    np.testing.assert_array_equal(m, want)  # the found onset, its later samples and the padding stay 1
    # examples that stay hard gain weight round after round
    np.testing.assert_array_equal(hard_example_weights(out, ts, factor=3.0, onset_window=0.003, previous=m),
                                  np.where(want > 1, 9.0, 1.0))
    with pytest.raises(ValueError, match="y_slip_out"):
        hard_example_weights(out[:, :5], ts)
    with pytest.raises(ValueError, match="factor"):
        hard_example_weights(out, ts, factor=0.5)
    with pytest.raises(ValueError, match="negative_level"):
        hard_example_weights(out, ts, negative_level=1.0)
    with pytest.raises(ValueError, match="previous"):
        hard_example_weights(out, ts, previous=np.ones(3))


def test_mining_and_sample_weights_refuse_what_would_train_silently_wrong():
    from tactile_mirror.lab.detector.training import hard_example_weights

    ts = small_set(2)
    out = np.full(ts.mask.shape, 0.1)
    # a diverged net's NaN outputs compare false both ways: no hard example at all
    with pytest.raises(ValueError, match="y_slip_out must be finite"):
        hard_example_weights(np.full(ts.mask.shape, np.nan), ts)
    with pytest.raises(TypeError, match="y_slip_out must be a real numeric array"):
        hard_example_weights(out + 0j, ts)
    with pytest.raises(TypeError, match="previous"):
        hard_example_weights(out, ts, previous=np.ones(ts.mask.shape, dtype=complex))
    with pytest.raises(ValueError, match="previous must be finite"):
        hard_example_weights(out, ts, previous=np.full(ts.mask.shape, -1.0))
    with pytest.raises(ValueError, match="factor"):
        hard_example_weights(out, ts, factor=1e308)
    with pytest.raises(TypeError, match="ts must be a TrainingSet"):
        hard_example_weights(out, None)
    # a window shorter than one sample weighted nothing, silently
    with pytest.raises(ValueError, match="onset_window .* shorter than one sample"):
        hard_example_weights(out, ts, onset_window=4e-4)
    with pytest.raises(ValueError, match="onset_window .* shorter than one sample"):
        train_detector(ts, n_hidden=3, maxiter=1, progress=False, onset_weight=5.0, onset_window=4e-4)
    with pytest.raises(ValueError, match="sample_weight must be at most"):
        train_detector(ts, n_hidden=3, maxiter=1, progress=False, sample_weight=np.full(ts.mask.shape, 1e200))
    with pytest.raises(ValueError, match="nothing to train on"):
        train_detector(ts, n_hidden=3, maxiter=1, progress=False, sample_weight=np.zeros(ts.mask.shape),
                       pred_weight=0.0)
    with pytest.raises(ValueError, match="sample_weight"):
        train_detector(ts, n_hidden=3, maxiter=1, progress=False, sample_weight=np.ones(ts.mask.shape, dtype=bool))


def test_an_unpickled_training_set_trains_as_the_original():
    """An unpickled float64 array has an equal but distinct dtype object: the kernel's
    check compared them by identity and refused it ("must have dtype float64, got float64")."""
    import pickle

    ts = small_set(2)
    ts2 = pickle.loads(pickle.dumps(ts))
    w1 = train_detector(ts, n_hidden=3, maxiter=3, seed=4, progress=False)
    w2 = train_detector(ts2, n_hidden=3, maxiter=3, seed=4, progress=False)
    np.testing.assert_array_equal(w1.params.pack(), w2.params.pack())
