"""The circuit-derived sensor noise model, scenes drawing from it, and the estimator's mains notch."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.signal
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator, estimate_stress_rate, notch_sos
from tactile_mirror.noise import BOLTZMANN, NOISE_SOURCES, SensorNoise

FS = 1000.0


def _welch_ratio(x, model, output, fs=FS, nperseg=1024):
    f, p = scipy.signal.welch(x, fs, nperseg=nperseg)
    # without DC, the first bin (which Welch's mean removal and the window's leakage from DC
    # lower) and Nyquist (half the degrees of freedom)
    f, p = f[2:-1], p[2:-1]
    return p / model.psd(f, fs, output)


@pytest.mark.parametrize("output", ["v", "u"])
def test_drawn_noise_matches_model_psd_and_rms(output):
    model = SensorNoise()
    v, u = model.draw(FS, 400_000, channels=1, seed=3)
    x = (v if output == "v" else u)[0]
    ratio = _welch_ratio(x, model, output)
    # Welch, 781 half-overlapping Hann segments: each bin within 15 % (about 3.5 standard
    # errors), the median of the 509 bins within 2 %
    assert np.all(np.abs(ratio - 1) < 0.15), np.abs(ratio - 1).max()
    assert abs(np.median(ratio) - 1) < 0.02
    assert x.std() == pytest.approx(model.rms(FS, output), rel=0.02)


def test_model_psd_follows_analog_in_band_and_the_noise_gains():
    model = SensorNoise()
    c = model.circuit
    f = np.array([1.0, 5.0, 20.0])
    # bilinear image of the analog noise gains: equal at low frequency
    np.testing.assert_allclose(model.psd(f, FS, "v"), model.psd_analog(f, "v"), rtol=2e-3)
    # below fc the feedback resistor's current noise sees Rf: sqrt(4 k T Rf) V/sqrt(Hz)
    np.testing.assert_allclose(model.psd_analog([0.01], "v", "Rf"), 4 * BOLTZMANN * model.temperature * c.Rf,
                               rtol=1e-6)
    # op-amp voltage noise at high frequency: gain 1 + Cp / Cf
    hi = model.psd_analog([1e6], "v", "e_n1")[0]
    assert hi == pytest.approx((model.e_n * (1 + model.source_capacitance / c.Cf)) ** 2, rel=1e-3)
    # u_out: v_out noise through the differentiator's own transfer function
    h = c.response(np.array([30.0]), "u") / c.response(np.array([30.0]), "v")
    assert model.psd_analog([30.0], "u", "Rf")[0] == pytest.approx(model.psd_analog([30.0], "v", "Rf")[0]
                                                                    * abs(h[0]) ** 2, rel=1e-9)
    assert set(NOISE_SOURCES) == {s.name for s in model.sources()}


@pytest.mark.parametrize("output", ["v", "u"])
def test_thermal_term_scales_with_sqrt_4kTR(output):
    base = SensorNoise()
    f = np.array([2.0])
    ref = base.psd(f, FS, output, "Rf")[0] / (4 * BOLTZMANN * base.temperature * base.circuit.Rf)
    for scale in (0.1, 10.0):
        # Rf and Cf scaled inversely keep the corner, so the gain below it is Rf and the
        # density sqrt(4 k T Rf) (V/sqrt(Hz)): the psd grows with R
        c = dataclasses.replace(base.circuit, Rf=base.circuit.Rf * scale, Cf=base.circuit.Cf / scale)
        m = SensorNoise(circuit=c)
        got = m.psd(f, FS, output, "Rf")[0] / (4 * BOLTZMANN * m.temperature * c.Rf)
        assert got == pytest.approx(ref, rel=1e-9)
        assert m.psd(f, FS, output, "Rf")[0] == pytest.approx(scale * base.psd(f, FS, output, "Rf")[0], rel=1e-9)
    hot = SensorNoise(temperature=600.0)
    assert hot.rms(FS, output, "Rf") == pytest.approx(math.sqrt(2) * base.rms(FS, output, "Rf"), rel=1e-9)
    # and the drawn noise follows: rms of a draw at 10x Rf (corner kept) is sqrt(10)x
    c = dataclasses.replace(base.circuit, Rf=base.circuit.Rf * 10, Cf=base.circuit.Cf / 10)
    quiet = {"e_n": 0.0, "i_n": 0.0}
    v1, u1 = SensorNoise(**quiet).draw(FS, 200_000, seed=5)
    v2, u2 = SensorNoise(circuit=c, **quiet).draw(FS, 200_000, seed=5)
    x1, x2 = (v1, v2) if output == "v" else (u1, u2)
    if output == "v":  # stage 2 thermal noise does not scale with Rf
        assert x2.std() / x1.std() == pytest.approx(math.sqrt(10), rel=0.02)


@pytest.mark.parametrize("mains", [50.0, 60.0])
def test_hum_lines_at_mains_and_harmonics_with_the_given_amplitude(mains):
    model = SensorNoise(hum=2e-3, mains=mains, harmonics=(1.0, 0.1, 0.3), e_n=0.0, i_n=0.0, temperature=1e-6)
    n = 20_000  # 20 s: whole periods of 50 and 60 Hz
    v, u = model.draw(FS, n, channels=2, seed=0)
    for x, output in ((v, "v"), (u, "u")):
        f_lines, a_lines = model.hum_lines(FS, output)
        np.testing.assert_allclose(f_lines, mains * np.arange(1, 4))
        spec = np.abs(np.fft.rfft(x, axis=-1)) * math.sqrt(2) / n  # rms amplitude per bin
        freqs = np.fft.rfftfreq(n, 1 / FS)
        for fl, al in zip(f_lines, a_lines):
            k = int(np.argmin(np.abs(freqs - fl)))
            np.testing.assert_allclose(spec[:, k], al, rtol=1e-3)
        others = np.ones(freqs.size, bool)
        for fl in f_lines:
            others &= np.abs(freqs - fl) > 0.5
        assert spec[:, others].max() < 1e-3 * a_lines.min()
    assert model.hum_lines(FS, "v")[1][0] == pytest.approx(2e-3)
    # u_out hum is v_out hum through the differentiator: its sampled sections (those the circuit
    # simulation runs), within 1.2 % of the analog one at 60 Hz (bilinear warping)
    c = model.circuit
    _, hu = scipy.signal.sosfreqz(c.sos(FS, "u"), worN=[mains], fs=FS)
    _, hv = scipy.signal.sosfreqz(c.sos(FS, "v"), worN=[mains], fs=FS)
    assert model.hum_lines(FS, "u")[1][0] == pytest.approx(2e-3 * abs(hu[0] / hv[0]), rel=1e-9)
    analog = abs(c.response(np.array([mains]), "u")[0] / c.response(np.array([mains]), "v")[0])
    assert model.hum_lines(FS, "u")[1][0] == pytest.approx(2e-3 * analog, rel=0.015)
    # total rms: broadband plus lines
    assert v.std(axis=-1) == pytest.approx(np.full(2, model.rms(FS, "v")), rel=1e-3)


def test_reproducible_per_seed_and_generator():
    model = SensorNoise(hum=1e-3)
    a = model.draw(FS, 3000, channels=(2, 2), seed=11)
    b = model.draw(FS, 3000, channels=(2, 2), seed=11)
    c = model.draw(FS, 3000, channels=(2, 2), seed=12)
    for x, y, z in zip(a, b, c):
        assert x.shape == (2, 2, 3000)
        np.testing.assert_array_equal(x, y)
        assert not np.allclose(x, z)
    g1, g2 = np.random.default_rng(4), np.random.default_rng(4)
    np.testing.assert_array_equal(model.draw(FS, 100, seed=g1)[1], model.draw(FS, 100, seed=g2)[1])


@pytest.mark.parametrize("kwargs, name", [
    ({"temperature": 0.0}, "temperature"), ({"temperature": -1.0}, "temperature"),
    ({"e_n": -1e-9}, "e_n"), ({"i_n": float("nan")}, "i_n"), ({"hum": -1e-3}, "hum"),
    ({"mains": 55.0}, "mains"), ({"harmonics": (0.5, 0.1)}, "harmonics"), ({"harmonics": ()}, "harmonics"),
    ({"harmonics": (1.0, -0.1)}, "harmonics"), ({"cable_capacitance": -1e-12}, "cable_capacitance"),
])
def test_bad_parameters_name_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SensorNoise(**kwargs)


@pytest.mark.parametrize("kw", [{"e_n": 1e200}, {"i_n": 1e160}, {"cable_capacitance": 1e300}, {"hum": 1e200}])
def test_noise_densities_beyond_any_part_are_refused(kw):
    import tactile_mirror as tm

    with pytest.raises(ValueError, match=f"{next(iter(kw))} must be at most"):
        tm.SensorNoise(**kw)


def test_bad_draw_and_spectrum_arguments_name_the_argument():
    model = SensorNoise()
    with pytest.raises(TypeError, match="circuit"):
        SensorNoise(circuit="pvdf")
    with pytest.raises(TypeError, match="e_n"):
        SensorNoise(e_n="15n")
    with pytest.raises(ValueError, match="fs"):
        model.draw(-1.0, 10)
    with pytest.raises(ValueError, match="n must"):
        model.draw(FS, -3)
    with pytest.raises(ValueError, match="channels"):
        model.draw(FS, 10, channels=(-1,))
    with pytest.raises(ValueError, match="output"):
        model.psd([1.0], FS, "w")
    with pytest.raises(ValueError, match="source"):
        model.psd([1.0], FS, "v", "R7")
    with pytest.raises(ValueError, match="f must"):
        model.psd([600.0], FS)
    with pytest.raises(ValueError, match="u_out"):
        model.apply(np.zeros((2, 5)), np.zeros((2, 4)), FS)


def test_scene_draws_noise_from_the_model():
    import tactile_mirror as tm
    from tactile_mirror.scenes import Scene

    base = {"duration": 0.7, "indent_duration": 0.5, "seed": 3, "stop_after_slip": None}
    clean = tm.simulate(Scene(**base))
    model = SensorNoise(hum=2e-3)
    noisy = tm.simulate(Scene(**base, noise_model=model))
    again = tm.simulate(Scene(**base, noise_model=model))
    np.testing.assert_array_equal(noisy.v_out, again.v_out)
    nv, nu = model.draw(clean.fs, clean.t.size, clean.v_out.shape[:-1], seed=[1, 3])
    np.testing.assert_allclose(noisy.v_out - clean.v_out, nv, atol=1e-15)
    np.testing.assert_allclose(noisy.u_out - clean.u_out, nu, atol=1e-15)
    # the white noise works as before, and adds to the model's
    both = tm.simulate(Scene(**base, noise=1e-3, noise_model=model))
    white = tm.simulate(Scene(**base, noise=1e-3))
    np.testing.assert_allclose(both.v_out - white.v_out, nv, atol=1e-15)
    with pytest.raises(TypeError, match="noise_model"):
        Scene(noise_model=1e-3)
    with pytest.raises(ValueError, match="noise_model"):
        Scene(noise_model=SensorNoise(circuit=PVDFCircuit(Rf=2e9)))


# ---------------------------------------------------------------------- the estimator's notch
def test_notch_removes_hum_by_40_dB_and_leaves_a_ramp():
    c = PVDFCircuit()
    n = 8000
    t = np.arange(n) / FS
    hum = SensorNoise(hum=2e-3, e_n=0.0, i_n=0.0, temperature=1e-6)
    nv, nu = hum.draw(FS, n, seed=0)
    plain = estimate_stress_rate(nv, nu, c, FS)
    notched = estimate_stress_rate(nv, nu, c, FS, notch=50.0)
    for a, b in zip(plain, notched):
        f, p0 = scipy.signal.periodogram(a[0, 2000:], FS, window="hann")
        f, p1 = scipy.signal.periodogram(b[0, 2000:], FS, window="hann")
        k = int(np.argmin(np.abs(f - 50.0)))
        assert 10 * np.log10(p0[k] / p1[k]) >= 40.0
    # harmonics too when asked
    all3 = estimate_stress_rate(nv, nu, c, FS, notch=(50.0, 100.0, 150.0))
    assert np.sqrt(np.mean(all3[0][0, 3000:] ** 2)) < 1e-3 * np.sqrt(np.mean(plain[0][0, 3000:] ** 2))
    # a ramp of the load (1000 Pa/s from t = 0.5 s): the rate after the notch's settling is the same;
    # the step of the rate at the ramp's start rings at 50 Hz with at most 3.5 % of the step
    load = np.where(t > 0.5, (t - 0.5) * 1000.0, 0.0)
    stress = np.zeros((1, 3, n))
    stress[0, 2] = load
    v, u = c.simulate(stress, FS)
    r0, _q0 = estimate_stress_rate(v, u, c, FS)
    r1, _q1 = estimate_stress_rate(v, u, c, FS, notch=50.0)
    dev = np.abs(r1 - r0)[0] / 1000.0
    assert dev.max() < 0.035
    assert dev[t > 1.5].max() < 1e-3
    assert np.abs(r1[0, -1] - 1000.0) < 1e-3
    # without notch the estimator is what it was
    est = StressRateEstimator(c, FS, 1)
    assert est.sos_notch is None and est.notch == ()


def test_notch_runs_in_the_streaming_sos_path():
    c = PVDFCircuit()
    rng = np.random.default_rng(0)
    v, u = rng.normal(size=(2, 3, 500)) * 1e-3
    est = StressRateEstimator(c, FS, 3, notch=(50.0, 150.0), notch_q=20.0)
    ref = estimate_stress_rate(v, u, c, FS, notch=(50.0, 150.0), notch_q=20.0)
    a = est.process(v[:, :200], u[:, :200])
    b = np.stack([np.concatenate(est.step(v[:, i], u[:, i])) for i in range(200, 500)], axis=-1)
    np.testing.assert_allclose(np.concatenate([a[0], b[:3]], axis=1), ref[0], rtol=1e-12, atol=1e-9)
    sos = notch_sos(FS, (50.0, 150.0), 20.0)
    np.testing.assert_array_equal(est.sos_notch, sos)
    b50, a50 = scipy.signal.iirnotch(50.0, 20.0, fs=FS)
    np.testing.assert_allclose(sos[0], np.concatenate([b50, a50]) / a50[0], rtol=1e-12)
    np.testing.assert_array_equal(est.sos_rate[:2], sos)


@pytest.mark.parametrize("kwargs, name", [({"notch": 600.0}, "notch"), ({"notch": 0.0}, "notch"),
                                          ({"notch": ()}, "notch"), ({"notch": "50"}, "notch"),
                                          ({"notch": 50.0, "notch_q": 0.0}, "notch_q"),
                                          # a band reaching fs/2 (or beyond): scipy's sections ran and
                                          # zeroed the whole output, or had poles on the unit circle
                                          ({"notch": FS / 4, "notch_q": 0.5}, "notch_q"),
                                          ({"notch": 50.0, "notch_q": 0.1}, "notch_q"),
                                          ({"notch": (50.0, 100.0, 50.0)}, "notch names 50 Hz twice"),
                                          ({"notch": list(range(1, 80))}, "notch: 79 notches")])
def test_bad_notch_names_the_argument(kwargs, name):
    with pytest.raises((ValueError, TypeError), match=name):
        StressRateEstimator(PVDFCircuit(), FS, 1, **kwargs)
    if "notch_q" in kwargs and kwargs["notch_q"] > 0:
        with pytest.raises(ValueError, match="notch_q"):
            notch_sos(FS, kwargs["notch"], kwargs["notch_q"])


def test_notch_just_inside_its_bound_is_stable():
    # the lowest legal Q at fs/4: its poles stay inside the unit circle
    est = StressRateEstimator(PVDFCircuit(), FS, 1, notch=FS / 4, notch_q=0.51)
    assert np.all(np.abs(np.roots(est.sos_notch[0, 3:])) < 1)
