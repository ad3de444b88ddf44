"""The filter-bank detector inside the real-time pipeline and the C ABI.

The pipeline runs the bank (detector_bank.hpp) on its own stress rates, so a
``"jordan_bank"`` net gives in the loop what it gives offline: tested against the
scipy + numpy reference pipeline, against ``SlipDetector.run`` on the pipeline's own
features, through the C ABI bit for bit and through recordings. The overflow guard
with the bank (its undo, and the window bounds over the bank's states) is tested with
the paper's net in test_pipeline.py and test_rt_safety.py.
"""
from __future__ import annotations

import numpy as np
import pytest
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.detector import SlipDetector
from tactile_mirror.detector.bank import DEFAULT_BANK, bank_channels, bank_config, bank_features
from tactile_mirror.detector.network import init_params
from tactile_mirror.detector.weights import DetectorWeights
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.loop.capi import CAPIError, CPipeline
from tactile_mirror.loop.recording import Recording
from tactile_mirror.pipeline import MirrorPipeline, NoController, ReferencePipeline, VelocityController

FS = 1000.0
# A bank other than the bundled one (12 inputs: the kernel's generic path; the
# bundled 17-input net runs the unrolled one).
SMALL_BANK = {"lp_taus": [0.003, 0.05], "abs_taus": [0.02], "load_tau": 0.3, "peak_tau": 0.1}


def small_bank_weights(seed=5, n_hidden=8):
    bank = bank_config(SMALL_BANK)
    nf = len(bank_channels(bank))
    rng = np.random.default_rng(seed)
    p = init_params(nf, n_hidden, seed)
    p.b2[:] = [0.3, -0.2]
    scale = np.concatenate([[3e2, 3e2, 3e4, 3e4], np.full(nf - 4, 3e2)]) * rng.uniform(0.5, 2.0, nf)
    scale[-3:] = 1.0  # load, press, peak (Pa)
    return DetectorWeights(p, rng.normal(size=nf) * 0.01, scale, FS, {"features": "stress_rate_bank", "bank": bank})


def knee_bank_weights(seed=6, n_hidden=8):
    """The small bank with compressed inputs (knees near the test signals' levels)."""
    nf = len(bank_channels(SMALL_BANK))
    rng = np.random.default_rng(seed)
    knee = np.concatenate([[1e2, 1e2, 1e4, 1e4], np.full(nf - 7, 1e2), [0.3, 0.3, 0.3]]) * rng.uniform(0.5, 2.0, nf)
    knee[1], knee[3] = knee[0], knee[2]
    bank = bank_config({**SMALL_BANK, "knee": [float(k) for k in knee]})
    p = init_params(nf, n_hidden, seed)
    p.b2[:] = [0.3, -0.2]
    return DetectorWeights(p, rng.normal(size=nf) * 0.01, rng.uniform(0.5, 2.0, nf), FS,
                           {"features": "stress_rate_bank", "bank": bank})


def pad_bank_weights(seed=7, n_hidden=16):
    """The default bank with the pad's mean (34 inputs: the kernel's unrolled net with the
    mean's share computed once per tick), compressed."""
    nf = len(bank_channels())
    rng = np.random.default_rng(seed)
    own = np.concatenate([[1e2, 1e2, 1e4, 1e4], np.full(nf - 7, 1e2), [0.3, 0.3, 0.3]])
    knee = np.concatenate([own, own]) * rng.uniform(0.5, 2.0, 2 * nf)
    bank = bank_config({**DEFAULT_BANK, "pad_mean": True, "knee": [float(k) for k in knee]})
    p = init_params(2 * nf, n_hidden, seed)
    p.b2[:] = [0.3, -0.2]
    return DetectorWeights(p, rng.normal(size=2 * nf) * 0.01, rng.uniform(0.5, 2.0, 2 * nf), FS,
                           {"features": "stress_rate_bank", "bank": bank})


DETECTORS = {"bundled": lambda: SlipDetector.bank(), "early": lambda: SlipDetector.early(),
             "small": lambda: SlipDetector(small_bank_weights()),
             "compressed": lambda: SlipDetector(knee_bank_weights()), "pad": lambda: SlipDetector(pad_bank_weights())}


def signals(n, ni, seed=1, scale=0.05):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    base = np.sin(2 * np.pi * 3 * t)[:, None] * np.linspace(0.5, 1.5, ni)[None]
    return scale * (base + 0.3 * rng.normal(size=(n, ni)))


def make(det="bundled", n_ridges=6, controller=None, dtype=np.float64, detector_dtype=None, use_u=True, **kw):
    est = StressRateEstimator(PVDFCircuit(), FS, 2 * n_ridges, use_u=use_u, dtype=dtype)
    return MirrorPipeline(DETECTORS[det](), FS, n_ridges, estimator=est, controller=controller, dtype=dtype,
                          detector_dtype=detector_dtype, **kw)


LAW = VelocityController(threshold=0.3, y_full=0.8, v_max=0.01, a_max=0.5, shear_gain=2e-3, asym_tau=0.2)


@pytest.mark.parametrize("det", list(DETECTORS))
@pytest.mark.parametrize("use_u", [True, False])
@pytest.mark.parametrize("controller", [NoController(), LAW], ids=["none", "velocity"])
def test_bank_pipeline_matches_reference(det, use_u, controller):
    pipe = make(det, n_ridges=3, controller=controller, use_u=use_u, activation="exact", v_limit=5.0, u_limit=5.0)
    assert pipe.detector_kind == "jordan_bank" and pipe.config["bank"] is not None
    x = signals(1500, pipe.n_inputs)
    x[300, 2] = np.nan
    x[700, 0] = 9.0  # beyond v_limit: rejected, the bank's states kept
    out, acc = pipe.process_block(x, accepted=True)
    ref = ReferencePipeline(pipe.config).process_block(x)
    assert acc.sum() == 1498 and not acc[300] and not acc[700]
    np.testing.assert_allclose(out[:, 2:], ref[:, 2:], rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[:, :2], ref[:, :2], rtol=1e-9, atol=1e-12)
    assert np.ptp(out[:, 2::3]) > 0.05  # the detector does react


@pytest.mark.parametrize("det", list(DETECTORS))
def test_bank_pipeline_equals_the_offline_detector_on_its_own_features(det):
    """The loop's detector is the offline one: SlipDetector.run on the pipeline's
    stress rates gives the pipeline's outputs (the same kernel, step vs block path)."""
    pipe = make(det, activation="exact")
    x = signals(2000, pipe.n_inputs, seed=4)
    out, feat = pipe.process_block(x, features=True)
    ys, yn, yp = DETECTORS[det]().run(np.transpose(feat, (1, 2, 0)))
    np.testing.assert_allclose(out[:, 2::3].T, ys, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[:, 4::3].T, yp, rtol=0, atol=1e-12)


def test_bank_and_paper_pipelines_differ_and_the_bank_has_memory():
    """The bank's states carry history the paper's net does not have: after a reset the
    same tick gives the same outputs, after other ticks it does not."""
    pipe = make()
    x = signals(400, pipe.n_inputs, seed=7)
    a = pipe.process_block(x)[0]
    pipe.reset()
    b = pipe.process_block(x)[0]
    np.testing.assert_array_equal(a, b)
    pipe.reset()
    c = pipe.process_block(np.concatenate([signals(300, pipe.n_inputs, seed=8), x]))[0][300:]
    assert np.max(np.abs(c[:, 2:] - a[:, 2:])) > 1e-3


@pytest.mark.parametrize("dtype,ddt", [(np.float64, None), (np.float32, None), (np.float64, np.float32)],
                         ids=["f64", "f32", "f64-f32"])
@pytest.mark.parametrize("det", list(DETECTORS))
def test_c_abi_runs_the_bank_bit_for_bit(det, dtype, ddt):
    pipe = make(det, controller=LAW, dtype=dtype, detector_dtype=ddt)
    c = CPipeline(pipe.config)
    x = signals(800, pipe.n_inputs, seed=3)
    x[100, 5] = np.inf
    out, acc = pipe.process_block(x, accepted=True)
    oc, accc = c.process_block(x, accepted=True)
    np.testing.assert_array_equal(out, oc)
    np.testing.assert_array_equal(acc, accc)
    assert c.status["nonfinite"] == 1
    c.close()


def test_float32_bank_pipeline_error_bound():
    """float32 filters and bank against the float64 pipeline: the measured bound the
    README states (|dy| <= 1e-3 on these signals)."""
    x = signals(3000, make().n_inputs, seed=9)
    ref = make(activation="exact").process_block(x)[0]
    f32 = make(activation="exact", dtype=np.float32).process_block(x)[0]
    err = np.max(np.abs(f32[:, 2:] - ref[:, 2:]))
    assert 0 < err <= 1e-3


def test_c_abi_refuses_a_bad_bank_naming_the_field():
    cfg = make().config
    cfg["bank"] = dict(cfg["bank"], load_tau=-1.0)
    with pytest.raises(CAPIError) as e:
        CPipeline(cfg, check=False)
    assert e.value.code == -3 and "bank_load_tau" in str(e.value)
    cfg = make().config
    cfg["bank"] = dict(cfg["bank"], lp_taus=[])
    with pytest.raises(CAPIError) as e:
        CPipeline(cfg, check=False)
    assert e.value.code == -3 and "bank_n_lp" in str(e.value)
    cfg = make("compressed").config
    cfg["bank"] = dict(cfg["bank"], knee=[1.0] * 11 + [float("nan")])
    with pytest.raises(CAPIError) as e:
        CPipeline(cfg, check=False)
    assert e.value.code == -3 and "bank_knee" in str(e.value)
    with pytest.raises(ValueError, match="knee"):  # and from Python, before any C++
        MirrorPipeline.from_config(cfg)


def test_python_refuses_inconsistent_bank_weights():
    w = small_bank_weights()
    est = StressRateEstimator(PVDFCircuit(), FS, 12)
    with pytest.raises(ValueError, match="w1"):
        MirrorPipeline({"w1": w.params.w1[:, 1:], "b1": w.params.b1, "w2": w.params.w2, "b2": w.params.b2,
                        "input_mean": w.input_mean[1:], "input_gain": 1 / w.input_scale[1:], "fs": FS,
                        "detector_kind": "jordan_bank", "bank": SMALL_BANK}, FS, 6, estimator=est)
    with pytest.raises(ValueError, match="lp_taus"):
        MirrorPipeline({"w1": w.params.w1, "b1": w.params.b1, "w2": w.params.w2, "b2": w.params.b2,
                        "input_mean": w.input_mean, "input_gain": 1 / w.input_scale, "fs": FS,
                        "detector_kind": "jordan_bank", "bank": dict(SMALL_BANK, lp_taus=[0.0, 0.1])},
                       FS, 6, estimator=est)
    with pytest.raises(ValueError, match="bank"):
        MirrorPipeline({"w1": w.params.w1, "b1": w.params.b1, "w2": w.params.w2, "b2": w.params.b2,
                        "input_mean": w.input_mean, "input_gain": 1 / w.input_scale, "fs": FS,
                        "bank": SMALL_BANK}, FS, 6, estimator=est)


@pytest.mark.parametrize("det", ["bundled", "compressed", "pad"])
def test_from_config_and_recording_replay_bit_for_bit(tmp_path, det):
    pipe = make(det, controller=LAW)
    x = signals(600, pipe.n_inputs, seed=11)
    out, acc = pipe.process_block(x, accepted=True)
    again = MirrorPipeline.from_config(pipe.config)
    assert again.detector_kind == "jordan_bank"
    np.testing.assert_array_equal(again.process_block(x)[0], out)
    rec = Recording(fs=FS, samples=x, outputs=out, accepted=acc, stage_position=out[:, 0], config=pipe.config)
    rec.save(tmp_path / "bank.npz")
    back = Recording.load(tmp_path / "bank.npz")
    assert back.config["bank"] == pipe.config["bank"] and back.config["detector_kind"] == "jordan_bank"
    np.testing.assert_array_equal(back.replay()[0], out)


def test_reference_bank_features_are_the_offline_ones():
    """The reference pipeline's bank state after n ticks equals bank_features' state on
    the same rates (the reference is not a second specification)."""
    pipe = make(n_ridges=2, activation="exact")
    ref = ReferencePipeline(pipe.config)
    x = signals(300, pipe.n_inputs, seed=12)
    _, feat = pipe.process_block(x, features=True)
    ref.process_block(x)
    _, state = bank_features(np.transpose(feat, (1, 2, 0)), FS, pipe.config["bank"], return_state=True)
    np.testing.assert_allclose(ref.bank_state, state, rtol=1e-12, atol=1e-6)


def test_memory_net_is_refused_by_name():
    det = SlipDetector.memory()
    est = StressRateEstimator(PVDFCircuit(), FS, 12)
    with pytest.raises(ValueError, match="jordan_memory"):
        MirrorPipeline(det, FS, 6, estimator=est)


def test_c_abi_5_struct_runs_the_paper_net():
    """A program built against ABI 5 (tm_config ending before detector_kind) gets the
    paper's net whatever lies beyond its struct: the bank fields are not read."""
    from tactile_mirror.loop.capi import load, new_config

    ffi, lib = load()
    cfg = new_config(ffi, lib)
    assert cfg.detector_kind == 0
    cfg.detector_kind = 1  # beyond the ABI-5 struct: must be ignored
    cfg.bank_n_lp = 99
    cfg.weights_fs = cfg.fs
    cfg.n_hidden = 16
    cfg.struct_size = ffi.offsetof("tm_config", "detector_kind")
    cfg.abi_version = 5
    h = ffi.new("tm_pipeline*")
    assert lib.tm_pipeline_create(cfg, h) == lib.TM_ERR_ARGUMENT  # accepted; fails on the missing weights
    assert b"w1" in ffi.string(lib.tm_last_error())
    cfg.struct_size = ffi.sizeof("tm_config")
    cfg.abi_version = 6
    assert lib.tm_pipeline_create(cfg, h) == lib.TM_ERR_ARGUMENT
    assert b"bank_n_lp" in ffi.string(lib.tm_last_error())
