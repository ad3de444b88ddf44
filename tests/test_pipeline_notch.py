"""The estimator's mains notch in the real-time pipeline: its features (v -> rate, u -> rate2)
equal the offline estimator's with the same notch, through pybind11 and through the C ABI."""
from __future__ import annotations

import numpy as np
import pytest
from tactile_mirror import MirrorPipeline, SlipDetector
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator, estimate_stress_rate

FS = 1000.0
R = 3


@pytest.fixture(scope="module")
def detector():
    return SlipDetector.default()


def hum_recording(n: int = 3000, seed: int = 5):
    """v_out, u_out (2R, n) V: a slow load ramp plus 2 mV of 50 Hz hum and its 3rd harmonic."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    ch = np.arange(2 * R)[:, None]
    ramp = 1e-3 * np.clip(t - 0.5, 0.0, None) * (1 + ch)
    hum = 2e-3 * np.sin(2 * np.pi * 50.0 * t + ch) + 5e-4 * np.sin(2 * np.pi * 150.0 * t + 2 * ch)
    v = ramp + hum + 1e-5 * rng.standard_normal((2 * R, n))
    u = 0.5 * ramp + hum + 1e-5 * rng.standard_normal((2 * R, n))
    return v, u


def offline_features(v, u, use_u, notch):
    rate, rate2 = estimate_stress_rate(v, u if use_u else None, PVDFCircuit(), FS, notch=notch)
    return np.stack([rate[0::2].T, rate[1::2].T, rate2[0::2].T, rate2[1::2].T], axis=-1)  # (n, R, 4)


def ticks(v, u, use_u):
    return np.ascontiguousarray(np.concatenate([v, u]).T if use_u else v.T)


@pytest.mark.parametrize("use_u", [True, False])
@pytest.mark.parametrize("notch", [50.0, (50.0, 150.0)])
def test_pipeline_features_equal_the_offline_estimator_with_its_notch(detector, use_u, notch):
    v, u = hum_recording()
    est = StressRateEstimator(PVDFCircuit(), FS, 2 * R, use_u=use_u, notch=notch)
    pipe = MirrorPipeline(detector, FS, R, estimator=est)
    out, feat = pipe.process_block(ticks(v, u, use_u), features=True)
    ref = offline_features(v, u, use_u, notch)
    scale = np.max(np.abs(ref), axis=(0, 1))
    np.testing.assert_allclose(feat / scale, ref / scale, rtol=0, atol=1e-12)
    assert np.all(np.isfinite(out))
    # the notch is in the path: without it the features carry the hum
    plain = offline_features(v, u, use_u, None)
    assert np.max(np.abs(plain - ref) / scale) > 1e-3
    # and the sections the pipeline runs are the estimator's, notch first
    cfg = pipe.config
    np.testing.assert_array_equal(cfg["sos_v"][: len(est.sos_notch)], est.sos_notch)


@pytest.mark.parametrize("use_u", [True, False])
def test_notch_pipeline_rebuilt_from_its_config_and_through_the_c_abi(detector, use_u):
    from tactile_mirror.loop.capi import CPipeline

    v, u = hum_recording(n=1500)
    est = StressRateEstimator(PVDFCircuit(), FS, 2 * R, use_u=use_u, notch=(50.0, 150.0), notch_q=20.0)
    pipe = MirrorPipeline(detector, FS, R, estimator=est)
    x = ticks(v, u, use_u)
    out, feat = pipe.process_block(x, features=True)
    again = MirrorPipeline.from_config(pipe.config)
    out2, feat2 = again.process_block(x, features=True)
    np.testing.assert_array_equal(feat2, feat)
    np.testing.assert_array_equal(out2, out)
    rate, rate2 = estimate_stress_rate(v, u if use_u else None, PVDFCircuit(), FS, notch=(50.0, 150.0), notch_q=20.0)
    ref = np.stack([rate[0::2].T, rate[1::2].T, rate2[0::2].T, rate2[1::2].T], axis=-1)
    scale = np.max(np.abs(ref), axis=(0, 1))
    with CPipeline(pipe.config) as c:
        got = np.empty_like(feat)
        cout = np.empty_like(out)
        for i, row in enumerate(x):
            c.step(row, cout[i])
            got[i] = c.features
    np.testing.assert_allclose(got / scale, ref / scale, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(cout, out)


def test_notch_in_float32_pipeline_matches_the_float32_estimator(detector):
    v, u = hum_recording(n=2000)
    est = StressRateEstimator(PVDFCircuit(), FS, 2 * R, use_u=True, notch=50.0, dtype=np.float32)
    pipe = MirrorPipeline(detector, FS, R, estimator=est, dtype=np.float32)
    _, feat = pipe.process_block(ticks(v, u, True), features=True)
    rate, rate2 = est.process(v, u)  # the same sections in the same float32 structures
    ref = np.stack([rate[0::2].T, rate[1::2].T, rate2[0::2].T, rate2[1::2].T], axis=-1)
    np.testing.assert_array_equal(feat, ref.astype(np.float64))
    off = offline_features(v, u, True, 50.0)
    scale = np.max(np.abs(off), axis=(0, 1))
    assert np.max(np.abs(feat - off) / scale) < 1e-4  # float32 against float64
