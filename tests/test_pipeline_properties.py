"""Properties of the pipeline tick under random chunking and random bad samples."""
from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.pipeline import MirrorPipeline, VelocityController

FS = 1000.0
_RNG = np.random.default_rng(11)
_W = {"w1": _RNG.normal(size=(6, 5)), "b1": _RNG.normal(size=6), "w2": 2 * _RNG.normal(size=(2, 6)),
      "b2": _RNG.normal(size=2), "input_mean": np.zeros(4), "input_gain": np.array([3e-3, 3e-3, 3e-5, 3e-5]),
      "fs": FS}
_PIPES = {}


def pipe(n_ridges, use_u):
    key = (n_ridges, use_u)
    if key not in _PIPES:
        est = StressRateEstimator(PVDFCircuit(), FS, 2 * n_ridges, use_u=use_u)
        _PIPES[key] = MirrorPipeline(_W, FS, n_ridges, estimator=est, v_limit=1.0, u_limit=1.0,
                                     controller=VelocityController(threshold=0.2, y_full=0.6, shear_gain=1e-4),
                                     max_hold_ticks=5)
    p = _PIPES[key]
    p.reset()
    return p


@given(n_ridges=st.integers(1, 6), use_u=st.booleans(), n=st.integers(1, 120),
       cuts=st.lists(st.integers(0, 120), max_size=5),
       bad=st.lists(st.tuples(st.integers(0, 119), st.integers(0, 23),
                              st.sampled_from([np.nan, np.inf, -np.inf, 3.0, -1.5])), max_size=6),
       seed=st.integers(0, 2**16))
def test_chunking_and_bad_samples(n_ridges, use_u, n, cuts, bad, seed):
    p = pipe(n_ridges, use_u)
    rng = np.random.default_rng(seed)
    x = 0.1 * rng.standard_normal((n, p.n_inputs))
    bad_rows = set()
    for t, c, v in bad:
        if t < n:
            x[t, c % p.n_inputs] = v
            bad_rows.add(t)
    whole, acc = p.process_block(x, accepted=True)
    assert set(np.flatnonzero(~acc)) == bad_rows
    assert p.status["rejected"] == len(bad_rows)
    assert np.all(np.isfinite(whole))
    assert np.all((whole[:, 2:] >= 0) & (whole[:, 2:] <= 1))
    p.reset()
    parts = [p.process_block(c)[0] for c in np.split(x, sorted({min(k, n) for k in cuts}))]
    assert np.array_equal(np.concatenate(parts), whole)
    # a rejected tick holds the detector outputs of the tick before it
    for t in bad_rows:
        if t > 0:
            np.testing.assert_array_equal(whole[t, 2:], whole[t - 1, 2:])


_DBL_MAX = float(np.finfo(np.float64).max)
_OPEN = {}


def open_pipe(n_ridges, use_u, limit):
    """Detection only (no controller), so that a rejected tick changes nothing but counters."""
    key = (n_ridges, use_u, limit)
    if key not in _OPEN:
        est = StressRateEstimator(PVDFCircuit(), FS, 2 * n_ridges, use_u=use_u)
        _OPEN[key] = [MirrorPipeline(_W, FS, n_ridges, estimator=est, v_limit=limit, u_limit=limit,
                                     max_hold_ticks=5) for _ in range(2)]
    a, b = _OPEN[key]
    a.reset()
    b.reset()
    return a, b


def assert_no_trace(a, b, n, bad, seed):
    """Feed ``a`` noise with ``bad`` samples and ``b`` only the ticks ``a`` accepted:
    every output of ``a`` is finite, its counts are exact, and its outputs on the
    accepted ticks and on a clean tail are bit for bit those of ``b``."""
    rng = np.random.default_rng(seed)
    x = 0.1 * rng.standard_normal((n, a.n_inputs))
    for t, c, v in bad:
        if t < n:
            x[t, c % a.n_inputs] = v
    out, acc = a.process_block(x, accepted=True)
    assert np.all(np.isfinite(out))
    s = a.status
    assert s["rejected"] == np.count_nonzero(~acc)
    assert s["nonfinite"] + s["out_of_range"] + s["overflow"] == s["rejected"]
    ref = b.process_block(x[acc])[0]
    np.testing.assert_array_equal(out[acc], ref)
    tail = 0.1 * rng.standard_normal((20, a.n_inputs))
    np.testing.assert_array_equal(a.process_block(tail)[0], b.process_block(tail)[0])


@given(n_ridges=st.integers(1, 3), use_u=st.booleans(), n=st.integers(1, 80),
       limit=st.sampled_from([1.0, _DBL_MAX]),
       bad=st.lists(st.tuples(st.integers(0, 79), st.integers(0, 11),
                              st.sampled_from([np.nan, np.inf, -np.inf, 3.0, 1e99, -1e99, 1e300, -1e306, _DBL_MAX,
                                               -_DBL_MAX])), max_size=8),
       seed=st.integers(0, 2**16))
def test_rejected_ticks_leave_no_trace(n_ridges, use_u, n, limit, bad, seed):
    """NaN, Inf, out-of-range and huge samples at random places: every output is
    finite, and the pipeline's state afterwards is that of a run that never saw the
    rejected ticks (its outputs on the accepted ticks, and on a clean tail, are
    bit for bit those of a pipeline fed only the accepted ticks)."""
    a, b = open_pipe(n_ridges, use_u, limit)
    assert_no_trace(a, b, n, bad, seed)
    np.testing.assert_array_equal(a.features, b.features)


_LOW = {}


@given(n_ridges=st.integers(1, 3), use_u=st.booleans(), n=st.integers(1, 80),
       dtypes=st.sampled_from([("float32", "float32"), ("float64", "float32")]),
       limit=st.sampled_from([1.0, 1e20, _DBL_MAX]),
       bad=st.lists(st.tuples(st.integers(0, 79), st.integers(0, 11),
                              st.sampled_from([np.nan, np.inf, 3.0, 1e19, -1e19, 9e19, 1e30, -1e38, 1e300])),
                    max_size=8),
       seed=st.integers(0, 2**16))
def test_rejected_ticks_leave_no_trace_in_float32(n_ridges, use_u, n, dtypes, limit, bad, seed):
    """The same with float32 filters or detector, whose ticks skip the undo only while
    the sample limits and the sections' growth bound keep every value below the float
    range: huge samples within the limit (1e19-9e19 with a 1e20 limit) are accepted or
    rejected, never a non-finite output, and the state is that of a run without them."""
    key = (n_ridges, use_u, dtypes, limit)
    if key not in _LOW:
        est = StressRateEstimator(PVDFCircuit(), FS, 2 * n_ridges, use_u=use_u)
        _LOW[key] = [MirrorPipeline(_W, FS, n_ridges, estimator=est, v_limit=limit, u_limit=limit, max_hold_ticks=5,
                                    dtype=dtypes[0], detector_dtype=dtypes[1]) for _ in range(2)]
    a, b = _LOW[key]
    a.reset()
    b.reset()
    assert_no_trace(a, b, n, bad, seed)
