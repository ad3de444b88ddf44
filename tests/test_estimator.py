"""Stress-rate estimation: exact inversion of the circuit, accuracy on known stresses,
streaming against offline, input checks."""
import numpy as np
import pytest
import scipy.signal
import tactile_mirror as tm
from hypothesis import given, settings
from hypothesis import strategies as st
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import (
    StressRateEstimator,
    differentiator_sos,
    equalizer_sos,
    estimate_stress_rate,
)
from tactile_mirror.filters import SosFilter
from tactile_mirror.lab.testing import known_load

FAST = settings(max_examples=25, deadline=None)


def test_known_load_derivatives_are_consistent():
    t = np.arange(200000) / 1e5
    s, d, d2 = known_load(t)
    np.testing.assert_allclose(np.gradient(s, t), d, atol=1e-3 * np.abs(d).max())
    np.testing.assert_allclose(np.gradient(d, t), d2, atol=1e-3 * np.abs(d2).max())


def rel_rms(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))


def signals(fs, duration, transients=True, noise=0.0, seed=0, circuit=None):
    c = circuit or PVDFCircuit()
    t = np.arange(round(duration * fs)) / fs
    s, d, d2 = known_load(t, transients)
    stress = np.zeros((3, t.size))
    stress[2] = s
    v, u = c.simulate(stress, fs, noise=noise, seed=seed)
    return c, v, u, d, d2


# ---------------------------------------------------------------- design
@pytest.mark.parametrize("fs", [1000.0, 10000.0])
@pytest.mark.parametrize("order,bandwidth", [(2, 100.0), (3, 50.0), (4, 300.0)])
@pytest.mark.parametrize("kind", ["butter", "bessel"])
def test_equalizer_inverts_circuit_exactly(fs, order, bandwidth, kind):
    # circuit sections followed by the equaliser = bilinear differentiator(s) x digital low-pass
    c = PVDFCircuit()
    f = np.logspace(-1, np.log10(0.45 * fs), 300)
    if kind == "butter":
        lp = scipy.signal.butter(order, bandwidth, fs=fs, output="sos")
    else:
        lp = scipy.signal.bessel(order, bandwidth, fs=fs, output="sos", norm="mag")
    _, h_lp = scipy.signal.sosfreqz(lp, f, fs=fs)
    d_bil = 2j * fs * np.tan(np.pi * f / fs)
    for out, power in (("v", 1), ("u", 2)):
        chain = np.vstack([c.sos(fs, out), equalizer_sos(c, fs, out, order, bandwidth, kind)])
        _, h = scipy.signal.sosfreqz(chain, f, fs=fs)
        np.testing.assert_allclose(h, d_bil**power * h_lp, rtol=1e-7, atol=0)
    # the -3 dB point is where it was asked for
    _, h3 = scipy.signal.sosfreqz(lp, [bandwidth], fs=fs)
    assert abs(h3[0]) == pytest.approx(2**-0.5, rel=1e-6)


def test_equalizer_units_on_a_ramp():
    # a steady load ramp: the estimate settles at the ramp's rate (Pa/s), rate2 at zero
    c = PVDFCircuit(Rf=3e9, Cf=1e-12, load=(1.0, 0.0, 0.0))
    fs = 2000.0
    t = np.arange(4000) / fs
    stress = np.zeros((3, t.size))
    stress[0] = 7e4 * t
    v, u = c.simulate(stress, fs)
    rate, rate2 = estimate_stress_rate(v, u, c, fs, order=3, bandwidth=150.0)
    assert rate[-1] == pytest.approx(7e4, rel=1e-9)
    assert abs(rate2[-1]) < 1e-6 * 7e4 * fs
    rate_b, rate2_b = estimate_stress_rate(v, None, c, fs, order=3, bandwidth=150.0)
    np.testing.assert_array_equal(rate_b, rate)
    assert abs(rate2_b[-1]) < 1e-6 * 7e4 * fs


@pytest.mark.parametrize("order", [1, 2, 3])
def test_differentiator_of_a_sine(order):
    fs = 1000.0
    f0 = 3.0
    t = np.arange(5000) / fs
    x = np.sin(2 * np.pi * f0 * t)
    y = scipy.signal.sosfilt(differentiator_sos(fs, order, 100.0), x)
    _, h = scipy.signal.sosfreqz(differentiator_sos(fs, order, 100.0), [f0, 0.0], fs=fs)
    assert abs(h[0]) == pytest.approx(2 * np.pi * f0, rel=2e-3)
    assert h[1] == 0
    # after the start-up transient, amplitude 2 pi f0 and a small lag
    amp = np.abs(y[2000:]).max()
    assert amp == pytest.approx(2 * np.pi * f0, rel=2e-3)


# ---------------------------------------------------------------- accuracy
def test_recovers_derivatives_of_a_smooth_load():
    c, v, u, d, d2 = signals(1000.0, 1.2, transients=False)
    rate, rate2 = estimate_stress_rate(v, u, c, 1000.0)  # order 2, 100 Hz
    assert rel_rms(rate, d) < 0.025
    assert rel_rms(rate2, d2) < 0.05
    _, rate2_diff = estimate_stress_rate(v, None, c, 1000.0)
    assert rel_rms(rate2_diff, d2) < 0.08
    # on the ramp (0.6-0.75 s) the estimate is exact
    np.testing.assert_allclose(rate[600:750], d[600:750], rtol=1e-3)


def test_error_on_transients_with_noise():
    # the bench case: stop and slip transients, 1 mV rms sensor noise (regression bounds)
    c, v, u, d, d2 = signals(1000.0, 2.0, transients=True, noise=1e-3, seed=3)
    rate, rate2 = estimate_stress_rate(v, u, c, 1000.0, order=2, bandwidth=100.0)
    assert rel_rms(rate, d) < 0.13
    assert rel_rms(rate2, d2) < 0.45
    # most of it is the filter's delay: aligned by 2 samples the error is much smaller
    assert rel_rms(rate[2:], d[:-2]) < 0.06
    # narrower band: more lag, more error
    rate_n, _ = estimate_stress_rate(v, u, c, 1000.0, order=2, bandwidth=50.0)
    assert rel_rms(rate_n, d) > rel_rms(rate, d)


def test_estimates_follow_the_equivalent_load_of_any_stress():
    # three stress components: the estimator reports rates of Q / q
    c = PVDFCircuit()
    fs = 1000.0
    t = np.arange(1200) / fs
    s, d, d2 = known_load(t, transients=False)
    stress = np.stack([0.5 * s, -0.2 * s, s])
    k = c.equivalent_load(stress[:, 700:701])[0] / s[700]
    v, u = c.simulate(stress, fs)
    rate, rate2 = estimate_stress_rate(v, u, c, fs)
    assert rel_rms(rate, k * d) < 0.025
    assert rel_rms(rate2, k * d2) < 0.05


# ---------------------------------------------------------------- streaming == offline
@FAST
@given(
    channels=st.integers(1, 4),
    use_u=st.booleans(),
    order=st.integers(2, 4),
    bandwidth=st.sampled_from([30.0, 100.0, 250.0]),
    cuts=st.lists(st.integers(0, 400), max_size=6),
    n_steps=st.integers(0, 5),
    seed=st.integers(0, 2**32 - 1),
)
def test_streaming_equals_offline(channels, use_u, order, bandwidth, cuts, n_steps, seed):
    rng = np.random.default_rng(seed)
    c = PVDFCircuit()
    fs = 1000.0
    n = 400
    v = rng.normal(0, 0.05, (channels, n))
    u = rng.normal(0, 0.05, (channels, n)) if use_u else None
    rate, rate2 = estimate_stress_rate(v, u, c, fs, order=order, bandwidth=bandwidth)
    est = StressRateEstimator(c, fs, channels, order=order, bandwidth=bandwidth, use_u=use_u)
    out1, out2 = [], []
    pos = 0
    for stop in sorted(set(cuts)) + [n]:
        # a few single steps, then a block up to the next cut
        for _ in range(min(n_steps, stop - pos)):
            r1, r2 = est.step(v[:, pos], u[:, pos] if use_u else None)
            assert r1.shape == r2.shape == (channels,)
            out1.append(r1[:, None])
            out2.append(r2[:, None])
            pos += 1
        if stop > pos:
            r1, r2 = est.process(v[:, pos:stop], u[:, pos:stop] if use_u else None)
            out1.append(r1)
            out2.append(r2)
            pos = stop
    got1 = np.concatenate(out1, axis=1)
    got2 = np.concatenate(out2, axis=1)
    np.testing.assert_allclose(got1, rate, rtol=0, atol=1e-12 * np.abs(rate).max())
    np.testing.assert_allclose(got2, rate2, rtol=0, atol=1e-12 * np.abs(rate2).max())


def test_reset_and_attributes():
    c = PVDFCircuit()
    est = StressRateEstimator(c, 1000.0, 2)
    v = np.random.default_rng(0).normal(0, 0.1, (2, 300))
    u = v[::-1].copy()
    a = est.process(v, u)
    est.reset()
    b = est.process(v, u)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_array_equal(est.sos_rate, equalizer_sos(c, 1000.0, "v", 2, 100.0))
    np.testing.assert_array_equal(est.sos_rate2, equalizer_sos(c, 1000.0, "u", 2, 100.0))
    assert est.sos_diff is None
    est2 = StressRateEstimator(c, 1000.0, 2, use_u=False, order=1, diff_order=2, diff_bandwidth=80.0)
    np.testing.assert_array_equal(est2.sos_diff, differentiator_sos(1000.0, 2, 80.0))
    assert est2.sos_rate2 is None


def test_offline_any_axis():
    c, v, u, _, _ = signals(1000.0, 0.6)
    vv = np.stack([v, 2 * v, -v])  # (3, n)
    uu = np.stack([u, 2 * u, -u])
    r, r2 = estimate_stress_rate(vv, uu, c, 1000.0)
    rt, r2t = estimate_stress_rate(vv.T, uu.T, c, 1000.0, axis=0)
    np.testing.assert_allclose(rt.T, r, rtol=1e-13, atol=0)
    np.testing.assert_allclose(r2t.T, r2, rtol=1e-13, atol=0)
    np.testing.assert_allclose(r[1], 2 * r[0], rtol=1e-12)


def test_float32_estimator_close_to_float64():
    c, v, u, _, _ = signals(1000.0, 1.2, transients=False)
    est = StressRateEstimator(c, 1000.0, 1, dtype=np.float32)
    r, r2 = est.process(v[None].astype(np.float32), u[None].astype(np.float32))
    ref, ref2 = estimate_stress_rate(v, u, c, 1000.0)
    assert np.abs(r[0] - ref).max() < 1e-4 * np.abs(ref).max()
    assert np.abs(r2[0] - ref2).max() < 1e-4 * np.abs(ref2).max()


# ---------------------------------------------------------------- bad input
def test_bad_design_arguments():
    c = PVDFCircuit()
    with pytest.raises(ValueError, match="bandwidth"):
        equalizer_sos(c, 1000.0, "v", 2, 500.0)  # at Nyquist
    with pytest.raises(ValueError, match="bandwidth"):
        equalizer_sos(c, 1000.0, "v", 2, 0.0)
    with pytest.raises(ValueError, match="bandwidth"):
        differentiator_sos(1000.0, 1, 600.0)
    with pytest.raises(TypeError, match="bandwidth"):
        differentiator_sos(1000.0, 1, "100")
    with pytest.raises(ValueError, match="order"):
        equalizer_sos(c, 1000.0, "u", 1, 100.0)  # u needs >= 2 to be proper
    with pytest.raises(ValueError, match="order"):
        equalizer_sos(c, 1000.0, "v", 0, 100.0)
    with pytest.raises(TypeError, match="order"):
        equalizer_sos(c, 1000.0, "v", 2.5, 100.0)
    with pytest.raises(ValueError, match="output"):
        equalizer_sos(c, 1000.0, "w")
    with pytest.raises(ValueError, match="kind"):
        equalizer_sos(c, 1000.0, "v", kind="cheby1")
    with pytest.raises(TypeError, match="circuit"):
        equalizer_sos("pvdf", 1000.0)
    with pytest.raises(ValueError, match="fs"):
        equalizer_sos(c, -1000.0)
    with pytest.raises(ValueError, match="fs"):
        differentiator_sos(float("nan"))


def test_bad_estimator_arguments():
    c = PVDFCircuit()
    with pytest.raises(ValueError, match="channels"):
        StressRateEstimator(c, 1000.0, 0)
    with pytest.raises(ValueError, match="order"):
        StressRateEstimator(c, 1000.0, 2, order=1)  # use_u needs order >= 2
    StressRateEstimator(c, 1000.0, 2, order=1, use_u=False)
    with pytest.raises(ValueError, match="diff_bandwidth"):
        StressRateEstimator(c, 1000.0, 2, use_u=False, diff_bandwidth=700.0)
    with pytest.raises(ValueError, match="bandwidth"):
        StressRateEstimator(c, 100.0, 2, bandwidth=100.0)
    est = StressRateEstimator(c, 1000.0, 2)
    with pytest.raises(ValueError, match="u"):
        est.process(np.zeros((2, 5)))
    with pytest.raises(ValueError, match="v must have shape"):
        est.process(np.zeros((3, 5)), np.zeros((3, 5)))
    with pytest.raises(ValueError, match="u must have"):
        est.process(np.zeros((2, 5)), np.zeros((2, 4)))
    with pytest.raises(TypeError, match="v"):
        est.process(np.zeros((2, 5), dtype=complex), np.zeros((2, 5)))
    with pytest.raises(ValueError, match="v_sample"):
        est.step(np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="u_sample"):
        est.step(np.zeros(2), np.zeros(1))
    no_u = StressRateEstimator(c, 1000.0, 2, use_u=False)
    with pytest.raises(ValueError, match="u must be None"):
        no_u.process(np.zeros((2, 5)), np.zeros((2, 5)))
    bad = np.zeros((2, 5))
    bad[1, 3] = np.nan
    with pytest.raises(ValueError):
        est.process(bad, np.zeros((2, 5)))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("use_u", [True, False])
def test_a_refused_call_leaves_the_estimator_as_it_was(dtype, use_u):
    # Each call runs two filters; when the second refuses (a NaN in u, a block that
    # overflows it, a u sample of the wrong shape) or another thread holds the
    # estimator, the first one must not have moved: the next good call gives what a
    # twin that never saw the bad call gives, bit for bit.
    rng = np.random.default_rng(4)
    v, u = rng.standard_normal((2, 2, 64))
    est = StressRateEstimator(PVDFCircuit(), 1000.0, 2, use_u=use_u, dtype=dtype)
    twin = StressRateEstimator(PVDFCircuit(), 1000.0, 2, use_u=use_u, dtype=dtype)
    for e in (est, twin):
        e.process(v, u if use_u else None)
    nan_u = u.copy()
    nan_u[1, 40] = np.nan
    refused = [lambda: est.step(v[:, 0], u[:1, 0] if use_u else u[:, 0])]
    if use_u:
        refused += [lambda: est.process(v, nan_u), lambda: est.process(v, np.full_like(u, 1e308))]
    else:
        # the differentiator's block (the rate) is finite; a v that overflows the first
        # filter is refused by it before the second runs
        refused += [lambda: est.process(np.full_like(v, 1e308))]
    for call in refused:
        with np.errstate(over="ignore"), pytest.raises(ValueError):
            call()
    with est._claim(), pytest.raises(RuntimeError, match="another thread"):
        est.step(v[:, 0], u[:, 0] if use_u else None)
    for a, b in zip(est.process(v, u if use_u else None), twin.process(v, u if use_u else None)):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(est.step(v[:, 5], u[:, 5] if use_u else None), twin.step(v[:, 5], u[:, 5] if use_u else None)):
        np.testing.assert_array_equal(a, b)


def test_estimator_errors_say_which_input_was_refused():
    est = tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 2)
    v = np.zeros((2, 5))
    with pytest.raises(ValueError, match="^u: "):
        est.process(v, np.full((2, 5), np.inf))
    with pytest.raises(ValueError, match="^v: "):
        est.process(np.full((2, 5), np.nan), v)
    with pytest.raises(ValueError, match="^u_out contains"):
        tm.estimate_stress_rate(np.zeros((1, 50)), np.full((1, 50), np.inf), tm.PVDFCircuit(), 1000.0)
    with pytest.raises(ValueError, match="^v_out contains"):
        tm.estimate_stress_rate(np.full((1, 50), np.nan), None, tm.PVDFCircuit(), 1000.0)


def test_bad_offline_arguments():
    c = PVDFCircuit()
    v = np.zeros((2, 50))
    with pytest.raises(ValueError, match="u_out"):
        estimate_stress_rate(v, np.zeros((2, 49)), c, 1000.0)
    with pytest.raises(ValueError, match="axis"):
        estimate_stress_rate(v, v, c, 1000.0, axis=2)
    with pytest.raises(TypeError, match="v_out"):
        estimate_stress_rate(v.astype(complex), None, c, 1000.0)
    with pytest.raises(ValueError, match="v_out"):
        estimate_stress_rate(np.float64(1.0), None, c, 1000.0)
    with pytest.raises(TypeError, match="circuit"):
        estimate_stress_rate(v, v, None, 1000.0)
    with pytest.raises(ValueError, match="bandwidth"):
        estimate_stress_rate(v, v, c, 1000.0, bandwidth=2000.0)


def test_signal_paths_refuse_bools_and_name_the_argument():
    """SosFilter.process and the estimator took True/False samples while SosFilter.step
    refused them; an axis of True was taken as axis 1. sosfilt, the drop-in for
    scipy.signal.sosfilt, casts them as scipy does."""
    from scipy import signal

    sos = signal.butter(2, 0.1, output="sos")
    flags = np.array([True, False, True, True])
    assert np.allclose(tm.sosfilt(sos, flags), signal.sosfilt(sos, flags))
    filt = SosFilter(sos)
    with pytest.raises(TypeError, match="block"):
        filt.process(flags)
    assert np.all(filt.zi == 0)
    est = StressRateEstimator(PVDFCircuit(), 1000.0, 2)
    with pytest.raises(TypeError, match="^v must"):
        est.process(np.ones((2, 5), bool), np.ones((2, 5)))
    with pytest.raises(TypeError, match="^u must"):
        est.process(np.ones((2, 5)), np.ones((2, 5), bool))
    z = np.zeros((2, 50))
    with pytest.raises(TypeError, match="v_out"):
        tm.estimate_stress_rate(z.astype(bool), None, PVDFCircuit(), 1000.0)
    with pytest.raises(TypeError, match="axis"):
        tm.estimate_stress_rate(z, z, PVDFCircuit(), 1000.0, axis=True)
    with pytest.raises(TypeError, match="channels"):
        StressRateEstimator(PVDFCircuit(), 1000.0, 2.0)
    with pytest.raises(ValueError, match="channels"):
        StressRateEstimator(PVDFCircuit(), 1000.0, 0)
    # ints are numbers, as in scipy
    assert np.allclose(tm.sosfilt(sos, np.arange(4)), signal.sosfilt(sos, np.arange(4.0)))
