"""tactile_mirror.sosfilt / SosFilter against scipy.signal.sosfilt."""
import warnings

import numpy as np
import pytest
import scipy.signal as ss
import tactile_mirror as tm
from hypothesis import assume, example, given
from hypothesis import strategies as st
from tactile_mirror.filters import POLE_TOLERANCE, SosFilter, UnstableFilterWarning, roundoff_bound

DBL_MAX = float(np.finfo(np.float64).max)
F64_RTOL = 1e-12  # relative to the signal scale
F32_BOUND_FACTOR = 8.0  # x roundoff_bound(); measured worst 1.6x


# ---------------------------------------------------------------- strategies
@st.composite
def stable_sos(draw, max_sections=12, rmax=0.999):
    n = draw(st.integers(1, max_sections))
    rows = []
    for _ in range(n):
        if draw(st.booleans()):
            r = draw(st.floats(0.0, rmax))
            th = draw(st.floats(0.0, np.pi))
            a1, a2 = -2 * r * np.cos(th), r * r
        else:
            p1 = draw(st.floats(-rmax, rmax))
            p2 = draw(st.floats(-rmax, rmax))
            a1, a2 = -(p1 + p2), p1 * p2
        zr = draw(st.floats(0.0, 1.5))
        zt = draw(st.floats(0.0, np.pi))
        g = draw(st.floats(0.1, 2.0))
        rows.append([g, -2 * g * zr * np.cos(zt), g * zr * zr, 1.0, a1, a2])
    return np.array(rows)


def signal(seed, shape):
    return np.random.default_rng(seed).standard_normal(shape)


def scale(ref):
    return max(1.0, float(np.max(np.abs(ref)))) if ref.size else 1.0


def f64_tolerance(sos, x):
    """Round-off: 1e-12 of the largest signal in the cascade, plus what poles near
    the unit circle amplify it to (the first-order bound; scipy's own error is of
    that size, and both implementations' errors add)."""
    rows = np.atleast_2d(x)
    bound = max(roundoff_bound(sos, row, np.float64) for row in rows)
    return F64_RTOL * cascade_scale(sos, rows) + 4 * bound


def cascade_scale(sos, x):
    """Largest magnitude anywhere in the cascade: the scale round-off acts on."""
    peak, u = float(np.max(np.abs(x), initial=1.0)), x
    for s in range(sos.shape[0]):
        u = ss.sosfilt(sos[s:s + 1], u)
        peak = max(peak, float(np.max(np.abs(u), initial=0.0)))
    return peak


# ---------------------------------------------------------------- float64 parity
@given(sos=stable_sos(), n=st.integers(0, 5000), seed=st.integers(0, 2**31))
def test_sosfilt_f64_matches_scipy_1d(sos, n, seed):
    x = signal(seed, n)
    ref = ss.sosfilt(sos, x) if n else np.zeros(0)
    y = tm.sosfilt(sos, x)
    assert y.dtype == np.float64 and y.shape == x.shape
    tol = f64_tolerance(sos, x) if n else 0.0
    np.testing.assert_allclose(y, ref, rtol=0, atol=tol)


@given(sos=stable_sos(max_sections=6), shape=st.lists(st.integers(1, 7), min_size=1, max_size=3),
       n=st.integers(1, 400), data=st.data(), seed=st.integers(0, 2**31))
def test_sosfilt_any_axis_with_zi(sos, shape, n, data, seed):
    full = list(shape)
    axis = data.draw(st.integers(-len(full) - 1, len(full)))
    ax = axis % (len(full) + 1)
    full.insert(ax, n)
    x = signal(seed, full)
    zshape = list(x.shape)
    zshape[ax] = 2
    zi = signal(seed + 1, [sos.shape[0], *zshape])
    ref, zref = ss.sosfilt(sos, x, axis=axis, zi=zi)
    y, zf = tm.sosfilt(sos, x, axis=axis, zi=zi)
    tol = F64_RTOL * max(scale(ref), scale(zref))
    np.testing.assert_allclose(y, ref, rtol=0, atol=tol)
    np.testing.assert_allclose(zf, zref, rtol=0, atol=tol)
    assert zf.shape == zref.shape


def test_non_contiguous_and_strided_input():
    sos = ss.butter(6, 0.2, output="sos")
    big = signal(0, (9, 3000))
    x = big[::2, ::3]  # both axes strided
    np.testing.assert_allclose(tm.sosfilt(sos, x), ss.sosfilt(sos, x), rtol=0, atol=1e-12 * 10)
    xt = signal(1, (500, 5)).T  # Fortran order
    np.testing.assert_allclose(tm.sosfilt(sos, xt), ss.sosfilt(sos, xt), rtol=0, atol=1e-11)


@pytest.mark.parametrize("shape,axis", [((0,), -1), ((3, 0), -1), ((0, 5), 1), ((4, 0, 2), 1)])
def test_empty_input(shape, axis):
    sos = ss.butter(2, 0.3, output="sos")
    x = np.zeros(shape)
    y = tm.sosfilt(sos, x, axis=axis)
    assert y.shape == x.shape and y.dtype == np.float64
    zshape = list(shape)
    zshape[axis] = 2
    zi = np.ones((1, *zshape))
    y, zf = tm.sosfilt(sos, x, axis=axis, zi=zi)
    np.testing.assert_array_equal(zf, zi)


# ---------------------------------------------------------------- dtype rules
@pytest.mark.parametrize(
    "sos_dt,x_dt,want",
    [(np.float64, np.float64, np.float64), (np.float32, np.float32, np.float32),
     (np.float64, np.float32, np.float64), (np.float32, np.float64, np.float64),
     (np.float64, np.int32, np.float64), (np.float32, np.int16, np.float32),
     (np.float32, np.int64, np.float64)],
)
def test_dtype_rules_match_scipy(sos_dt, x_dt, want):
    sos = ss.butter(4, 0.1, output="sos").astype(sos_dt)
    x = (signal(3, 200) * 100).astype(x_dt)
    y = tm.sosfilt(sos, x)
    assert y.dtype == ss.sosfilt(sos, x).dtype == want


def test_complex_input_is_passed_to_scipy():
    sos = ss.butter(4, 0.1, output="sos")
    x = signal(0, 100) + 1j * signal(1, 100)
    np.testing.assert_array_equal(tm.sosfilt(sos, x), ss.sosfilt(sos, x))


# ---------------------------------------------------------------- float32
@given(sos=stable_sos(), n=st.integers(1, 3000), seed=st.integers(0, 2**31),
       structure=st.sampled_from(["auto", "tdf2"]))
def test_float32_within_roundoff_bound(sos, n, seed, structure):
    s32 = sos.astype(np.float32)
    x = signal(seed, n).astype(np.float32)
    ref = ss.sosfilt(s32.astype(np.float64), x.astype(np.float64))
    y = tm.sosfilt(s32, x, structure=structure)
    assert y.dtype == np.float32
    bound = roundoff_bound(s32, x)
    assume(np.isfinite(bound))
    assert np.max(np.abs(y - ref)) <= F32_BOUND_FACTOR * bound + 1e-30


def test_float32_highpass_near_z1_meets_1e_4_of_peak():
    fs = 10_000.0
    sos = ss.butter(4, 0.5, "highpass", fs=fs, output="sos")
    x = signal(7, (12, 100_000))
    ref = ss.sosfilt(sos, x)
    peak = np.max(np.abs(ref))
    f = tm.SosFilter(sos, channels=12, dtype=np.float32)
    assert f.structure == ("delta",) * len(sos)
    err = np.max(np.abs(f.process(x.astype(np.float32)) - ref)) / peak
    assert err <= 1e-4
    # the plain float32 structure (scipy's) is what fails here
    tdf2 = tm.SosFilter(sos, channels=12, dtype=np.float32, structure="tdf2")
    err_tdf2 = np.max(np.abs(tdf2.process(x.astype(np.float32)) - ref)) / peak
    assert err_tdf2 > 10 * err


@pytest.mark.parametrize("structure", ["tdf2", "delta"])
def test_structures_agree_in_float64(structure):
    sos = ss.ellip(8, 0.5, 60, [0.05, 0.2], "bandpass", output="sos")
    x = signal(2, (3, 4000))
    np.testing.assert_allclose(tm.sosfilt(sos, x, structure=structure), ss.sosfilt(sos, x),
                               rtol=0, atol=1e-11 * scale(ss.sosfilt(sos, x)))


# ---------------------------------------------------------------- streaming
@given(sos=stable_sos(max_sections=6), channels=st.integers(1, 20), n=st.integers(1, 600),
       cuts=st.lists(st.integers(0, 600), max_size=8), dtype=st.sampled_from([np.float64, np.float32]),
       seed=st.integers(0, 2**31))
def test_any_chunking_equals_one_shot_exactly(sos, channels, n, cuts, dtype, seed):
    x = signal(seed, (channels, n)).astype(dtype)
    one = tm.SosFilter(sos, channels, dtype).process(x)
    f = tm.SosFilter(sos, channels, dtype)
    edges = sorted({0, n, *[c for c in cuts if c <= n]})
    parts = [f.process(x[:, a:b]) for a, b in zip(edges[:-1], edges[1:])]
    np.testing.assert_array_equal(np.concatenate(parts, axis=1), one)
    # and sample by sample through step()
    f.reset()
    steps = np.stack([f.step(x[:, i]) for i in range(min(n, 60))], axis=1)
    np.testing.assert_array_equal(steps, one[:, :steps.shape[1]])


def test_zi_roundtrip_in_scipy_layout_both_structures():
    sos = ss.butter(8, 0.01, output="sos")
    x = signal(4, (5, 800))
    for dtype in (np.float64, np.float32):
        f = tm.SosFilter(sos, 5, dtype)
        f.process(x[:, :300].astype(dtype))
        zi = f.zi
        assert zi.shape == (4, 5, 2)
        rest_ref = ss.sosfilt(sos, x[:, 300:], zi=zi.astype(np.float64))[0]
        g = tm.SosFilter(sos, 5, dtype)
        g.reset(zi)
        tol = 1e-12 if dtype == np.float64 else 1e-4
        np.testing.assert_allclose(g.process(x[:, 300:].astype(dtype)), rest_ref, rtol=0,
                                   atol=tol * scale(rest_ref))


def test_zi_matches_scipy_after_block():
    sos = ss.cheby1(6, 1, 0.2, output="sos")
    x = signal(5, (3, 1000))
    f = tm.SosFilter(sos, 3)
    f.process(x)
    _, zf = ss.sosfilt(sos, x, zi=np.zeros((3, 3, 2)))
    np.testing.assert_allclose(f.zi, zf, rtol=0, atol=1e-12 * scale(zf))


def test_one_channel_accepts_1d_blocks():
    sos = ss.butter(2, 0.2, output="sos")
    x = signal(0, 50)
    y = tm.SosFilter(sos, 1).process(x)
    assert y.shape == (50,)
    np.testing.assert_allclose(y, ss.sosfilt(sos, x), atol=1e-13)


# ---------------------------------------------------------------- stability, subnormals
def test_poles_at_radius_one_minus_1e6_stay_accurate():
    r, th = 1 - 1e-6, 2 * np.pi * 1e-4
    sos = np.array([[1e-6, 0, 0, 1, -2 * r * np.cos(th), r * r]])
    x = signal(9, 200_000)
    ref = ss.sosfilt(sos.astype(np.longdouble), x.astype(np.longdouble)).astype(np.float64)
    y = tm.sosfilt(sos, x)
    assert np.all(np.isfinite(y))
    assert np.max(np.abs(y - ref)) <= 1e-9 * np.max(np.abs(ref))
    y32 = tm.SosFilter(sos, 1, np.float32).process(x.astype(np.float32))
    assert np.max(np.abs(y32 - ref)) <= 1e-3 * np.max(np.abs(ref))


def test_decay_through_subnormal_range_is_flushed_to_zero():
    sos = ss.butter(2, 0.2, output="sos")
    x = np.zeros((4, 20_000))
    x[:, 0] = 1.0
    y = tm.SosFilter(sos, 4).process(x)
    tiny = np.finfo(np.float64).tiny
    nz = np.abs(y[np.abs(y) > 0])
    assert np.all(nz >= tiny)  # no subnormal output: FTZ was active
    assert np.all(y[:, -100:] == 0)


# ---------------------------------------------------------------- bad input
def test_bad_sos_shapes_and_values():
    x = np.zeros(10)
    with pytest.raises(ValueError, match="sos"):
        tm.sosfilt(np.ones((2, 5)), x)
    with pytest.raises(ValueError, match="sos"):
        tm.sosfilt(np.ones((0, 6)), x)
    with pytest.raises(ValueError, match="a0"):
        tm.sosfilt([[1, 0, 0, 0, 0, 0]], x)
    with pytest.raises(ValueError, match="non-finite"):
        tm.sosfilt([[1, np.nan, 0, 1, 0, 0]], x)
    # an a0 so small that the normalised section overflows (it came back as inf, or as
    # numpy's LinAlgError from the pole check)
    for sos in ([[1, 0, 0, 1e-320, 0, 0]], [[1, 0, 0, 1e-300, 1e300, 0]]):
        with pytest.raises(ValueError, match=r"sos\[0\] divided by its a0"):
            tm.validate_sos(sos, allow_unstable=True)
    for axis in (1.0, None, True):
        with pytest.raises(TypeError, match="axis must be an integer"):
            tm.sosfilt([[1, 0, 0, 1, 0, 0]], x, axis=axis)
    with pytest.raises(ValueError, match="unit circle"):
        tm.SosFilter([[1, 0, 0, 1, 0, 1.2]], 1)
    with pytest.raises(TypeError, match="sos"):
        tm.SosFilter(np.ones((1, 6), dtype=complex), 1)
    # explicitly allowed: a pole outside the circle
    y = tm.SosFilter([[1, 0, 0, 1, 0, 1.2]], 1, allow_unstable=True).process(np.ones(5))
    np.testing.assert_array_equal(y, ss.sosfilt([[1, 0, 0, 1, 0, 1.2]], np.ones(5)))


# Sections with poles on the unit circle: what scipy runs, the library runs.
MARGINAL = {
    "integrator": [[1, 0, 0, 1, -1, 0]],  # stress rate -> stress
    "double integrator": [[1, 0, 0, 1, -2, 1]],
    "dc-marginal": [[0.5, -0.5, 0, 1, -1, 0]],
    "undamped resonator": [[1, 0, 0, 1, -2 * np.cos(0.3), 1]],
    "poles at +-1": [[1, 0, 0, 1, 0, -1]],
    "integrator after a lowpass": np.vstack([ss.butter(2, 0.1, output="sos"), [[1, 0, 0, 1, -1, 0]]]),
}


@pytest.mark.parametrize("name", sorted(MARGINAL))
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_poles_on_the_unit_circle_run_like_scipy(name, dtype):
    sos = np.asarray(MARGINAL[name], dtype=dtype)
    x = signal(3, 2000).astype(dtype)
    ref = ss.sosfilt(sos, x)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning for a pole on the circle
        y = tm.sosfilt(sos, x)
    assert y.dtype == ref.dtype
    tol = 1e-12 if dtype == np.float64 else 2e-4
    np.testing.assert_allclose(y, ref, rtol=0, atol=tol * np.max(np.abs(ref)))
    # the streaming object runs them too, in chunks, and agrees with the block function
    f = tm.SosFilter(sos, 1, dtype)
    parts = [f.process(x[:700]), *(f.step(np.array([v]))[0:1] for v in x[700:710]), f.process(x[710:])]
    np.testing.assert_array_equal(np.concatenate(parts), y if dtype == np.float64 else tm.sosfilt(sos, x))


def test_integrator_integrates_exactly():
    y = tm.sosfilt([[1, 0, 0, 1, -1, 0]], np.ones(5))
    np.testing.assert_array_equal(y, [1, 2, 3, 4, 5])
    np.testing.assert_array_equal(tm.SosFilter([[1, 0, 0, 1, -1, 0]], 1).process(np.ones(5)), [1, 2, 3, 4, 5])


def test_pole_outside_the_circle_warns_in_sosfilt_and_is_refused_by_sosfilter():
    sos = [[1, 0, 0, 1, -1.0, -0.1]]  # poles 1.092, -0.092
    x = signal(4, 300)
    with pytest.warns(UnstableFilterWarning, match=r"section 0 .*magnitude 1\.09"):
        y = tm.sosfilt(sos, x)
    np.testing.assert_allclose(y, ss.sosfilt(sos, x), rtol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tm.sosfilt(sos, x, allow_unstable=True)
    with pytest.raises(ValueError, match="outside the unit circle"):
        tm.SosFilter(sos, 1)
    # the tolerance for "on the circle" is rounding, not a margin
    with pytest.raises(ValueError, match="outside the unit circle"):
        tm.SosFilter([[1, 0, 0, 1, 0, 1 + 1e-9]], 1)
    tm.SosFilter([[1, 0, 0, 1, 0, 1 + POLE_TOLERANCE / 2]], 1)


def test_roundoff_bound_needs_poles_inside_the_circle():
    with pytest.raises(ValueError, match="on the unit circle"):
        roundoff_bound([[1, 0, 0, 1, -1, 0]], np.ones(10))


def test_roundoff_bound_refuses_signals_it_cannot_bound():
    sos = np.array([[1.0, 0, 0, 1, -0.9, 0]])
    for x, kw, exc in (([1.0, np.nan], {}, ValueError), ([1.0, np.inf], {}, ValueError),
                       (np.ones(3) + 1j, {}, TypeError), ("abc", {}, TypeError),
                       (np.ones(3), {"impulse_length": 0}, ValueError), (np.ones(3), {"impulse_length": 1.5}, ValueError),
                       (np.ones(3), {"impulse_length": True}, ValueError)):
        with pytest.raises(exc, match="impulse_length" if kw else "x must"):
            tm.roundoff_bound(sos, x, **kw)


def test_a0_is_normalised():
    sos = ss.butter(4, 0.2, output="sos")
    x = signal(0, 300)
    np.testing.assert_allclose(tm.sosfilt(sos * 3.0, x), ss.sosfilt(sos, x), atol=1e-13)


def test_bad_constructor_arguments():
    sos = ss.butter(2, 0.2, output="sos")
    with pytest.raises(ValueError, match="channels"):
        tm.SosFilter(sos, 0)
    with pytest.raises(TypeError, match="channels"):
        tm.SosFilter(sos, 2.5)
    with pytest.raises(TypeError, match="dtype"):
        tm.SosFilter(sos, 2, np.int32)
    with pytest.raises(ValueError, match="structure"):
        tm.SosFilter(sos, 2, structure="lattice")


def test_bad_block_and_sample():
    f = tm.SosFilter(ss.butter(2, 0.2, output="sos"), 3)
    with pytest.raises(ValueError, match="block"):
        f.process(np.zeros((2, 10)))
    with pytest.raises(TypeError, match="block"):
        f.process(np.zeros((3, 10), dtype=complex))
    with pytest.raises(ValueError, match="sample"):
        f.step(np.zeros(4))
    with pytest.raises(TypeError, match="sample"):
        f.step(np.zeros(3, dtype=complex))
    with pytest.raises(TypeError, match="sample"):
        f.step(np.array(["a", "b", "c"]))
    with pytest.raises(ValueError, match="zi"):
        f.zi = np.zeros((1, 2, 2))
    with pytest.raises(ValueError, match="zi"):
        f.zi = np.full((1, 3, 2), np.inf)
    with pytest.raises(ValueError, match="zi"):
        tm.sosfilt(f.sos, np.zeros((3, 10)), zi=np.zeros((1, 3, 3)))
    with pytest.raises(ValueError, match="axis"):
        tm.sosfilt(f.sos, np.zeros((3, 10)), axis=2)
    with pytest.raises(TypeError, match="x"):
        tm.sosfilt(f.sos, np.array(["a"]))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_block_raises_with_index_and_keeps_state(dtype, bad):
    sos = ss.butter(4, 0.1, output="sos")
    f = tm.SosFilter(sos, 13, dtype)
    f.process(signal(0, (13, 100)).astype(dtype))
    before = f.zi
    x = signal(1, (13, 1000)).astype(dtype)
    x[11, 700] = bad
    x[4, 650] = bad  # the first in time
    with pytest.raises(ValueError, match=r"channel 4, sample 650"):
        f.process(x)
    np.testing.assert_array_equal(f.zi, before)
    x[4, 650] = 0.0
    x[11, 700] = 0.0
    g = tm.SosFilter(sos, 13, dtype)
    g.process(signal(0, (13, 100)).astype(dtype))
    np.testing.assert_array_equal(f.process(x), g.process(x))


def test_nonfinite_in_sosfilt_names_nd_index():
    x = signal(0, (3, 4, 50))
    x[2, 1, 30] = np.nan
    with pytest.raises(ValueError, match=r"\(2, 1, 30\)"):
        tm.sosfilt(ss.butter(2, 0.2, output="sos"), x, axis=-1)
    with pytest.raises(ValueError, match=r"\(2, 1, 30\)"):
        tm.sosfilt(ss.butter(2, 0.2, output="sos"), x, axis=1)


def test_step_rejects_nonfinite_sample_counts_and_holds():
    sos = ss.butter(2, 0.2, output="sos")
    f = tm.SosFilter(sos, 3)
    y1 = f.step([1.0, 2.0, 3.0])
    z = f.zi
    held = f.step([0.0, np.nan, 0.0])
    np.testing.assert_array_equal(held, y1)
    np.testing.assert_array_equal(f.zi, z)
    assert f.rejected == 1
    f.step([np.inf, 0.0, 0.0])
    assert f.rejected == 2
    f.reset()
    assert f.rejected == 0 and not np.any(f.zi)


def test_sos_filter_rejects_an_overflowing_sample():
    f = SosFilter([[1.0, 0.0, 0.0, 1.0, -0.5, 0.0]], channels=2)  # y = x + 0.5 y(t-1)
    f.step([1.0, 2.0])
    y0 = f.step([DBL_MAX, -DBL_MAX])      # y still finite: accepted
    assert np.all(np.isfinite(y0)) and f.rejected == 0
    z0 = f.zi
    y = f.step([DBL_MAX, -DBL_MAX])       # y = max + max / 2 overflows: rejected
    np.testing.assert_array_equal(y, y0)  # the previous output is held
    np.testing.assert_array_equal(f.zi, z0)
    assert f.rejected == 1
    y = f.step([np.nan, 0.0])             # a later NaN holds the last accepted output too
    np.testing.assert_array_equal(y, y0)
    assert f.rejected == 2
    g = SosFilter([[1.0, 0.0, 0.0, 1.0, -0.5, 0.0]], channels=1)
    g.process(np.ones(3))
    zg = g.zi
    with pytest.raises(ValueError, match="overflow"):
        g.process(np.array([1.0, DBL_MAX, DBL_MAX, 1.0]))
    np.testing.assert_array_equal(g.zi, zg)


def test_a_refused_block_keeps_the_held_output_step_returns():
    f = tm.SosFilter(ss.butter(2, 0.2, "highpass", output="sos"))
    held = f.process(np.ones((1, 5)))[0, -1]
    with pytest.raises(ValueError, match="unchanged"):
        f.process(np.array([[1.7e308, -1.7e308, 1.7e308]]))
    assert f.step(np.array([np.nan]))[0] == held
    # after a step refused for overflow, an accepted block's last output is the held one
    f.step(np.array([1.7e308]))
    y = f.process(np.array([[0.5, 0.25]]))
    assert f.step(np.array([np.nan]))[0] == y[0, -1]


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_step_converts_any_real_sample(dtype):
    sos = ss.butter(4, 0.1, output="sos")
    x = signal(0, (12, 40))
    f, g = tm.SosFilter(sos, 12, dtype), tm.SosFilter(sos, 12, dtype)
    for i in range(40):  # strided float64 column, a list, int and float32 inputs
        col = x[:, i]
        np.testing.assert_array_equal(f.step(col), g.step(np.ascontiguousarray(col, dtype=dtype)))
    np.testing.assert_array_equal(f.step(list(x[:, 0])), g.step(x[:, 0].astype(dtype)))
    np.testing.assert_array_equal(f.step(np.arange(12)), g.step(np.arange(12).astype(dtype)))
    np.testing.assert_array_equal(f.step(x[:, 1].astype(np.float32)), g.step(x[:, 1].astype(np.float32).astype(dtype)))
    assert f.step(x[:, 2]).dtype == dtype


@given(sos=stable_sos(max_sections=6), channels=st.integers(1, 20), n=st.integers(1, 300),
       dtype=st.sampled_from([np.float64, np.float32]), seed=st.integers(0, 2**31))
@example(sos=np.array([[1.0, 0, 0, 1, 1.983375, 0.98339062], [1, 0, 0, 1, 0, 0]]), channels=1, n=132,
         dtype=np.float32, seed=0)  # poles at radius 0.992: float32 error 0.046, 1e-4 of the scale 0.042
def test_baseline_kernels_match_dispatched(sos, channels, n, dtype, seed):
    """The portable (SSE2/generic) clone computes what the dispatched one does."""
    x = signal(seed, (channels, n)).astype(dtype)
    f, base = tm.SosFilter(sos, channels, dtype), tm.SosFilter(sos, channels, dtype)
    base._core.use_baseline_isa()
    y, yb = f.process(x), base.process(x)
    ref = ss.sosfilt(sos, x.astype(np.float64))
    x64 = x.astype(np.float64)
    # float32: 1e-4 of the cascade's largest signal, or twice the first-order bound where poles
    # near the unit circle amplify round-off beyond that (measured errors stay below 1.6x it)
    tol = f64_tolerance(sos, x64) if dtype == np.float64 else max(
        1e-4 * cascade_scale(sos, x64), 2 * max(roundoff_bound(sos, row, np.float32) for row in x64))
    np.testing.assert_allclose(yb, ref, rtol=0, atol=tol)
    np.testing.assert_allclose(yb, y, rtol=0, atol=tol)
    base.reset()
    steps = np.stack([base.step(x[:, i]) for i in range(min(n, 30))], axis=1)
    np.testing.assert_array_equal(steps, yb[:, :steps.shape[1]])


def test_simd_path_is_reported():
    assert tm.simd_path() in {"avx2+fma", "sse2", "native", "generic"}
