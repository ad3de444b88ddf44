"""Test configuration shared by the whole suite, and the pipeline on a random net that the
pipeline, C ABI, argument-check and loop-experiment tests build."""
import os
import sys

import pytest

# Small problems: BLAS/OpenMP threading only adds overhead on 2-core machines.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np
from hypothesis import HealthCheck, settings
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.pipeline import MirrorPipeline

settings.register_profile(
    "ci", max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile("dev", max_examples=25, deadline=None)
settings.register_profile("thorough", max_examples=1000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: long-running test (deselect with -m 'not slow')")
    config.addinivalue_line(
        "markers", "native_build(spec): the test runs a native build (tests/_native_build.py Spec), started "
        "ahead of the tests")


def pytest_collection_finish(session):
    """Start the native builds the selected tests need (the sanitizer builds: minutes
    of compiling) in a background thread of each test process, costliest first, so
    that they overlap the other tests instead of holding up the tests that run them.
    The processes share the builds (tests/_native_build.py): each build is made once,
    by whichever process gets to it first. TM_NATIVE_TEST_PREBUILD=0 turns this off
    (each build is then made when its first test needs it)."""
    if session.config.option.collectonly or os.environ.get("TM_NATIVE_TEST_PREBUILD", "1") == "0":
        return
    specs = [m.args[0] for item in session.items if not _skipped(item) for m in item.iter_markers("native_build")]
    if specs:
        import _native_build

        _native_build.start_background(specs)


def _skipped(item):
    return any(m.name == "skip" or (m.name == "skipif" and m.args and m.args[0] is True)
               for m in item.iter_markers())


def pytest_sessionfinish(session, exitstatus):
    # A background build under way is finished (the other test process may be waiting
    # for it) unless the run was interrupted or stopped early (-x, --maxfail).
    nb = sys.modules.get("_native_build")
    if nb is not None:
        stopped = bool(session.shouldstop or session.shouldfail) or exitstatus == pytest.ExitCode.INTERRUPTED
        nb.finish_background(kill=stopped)

# -- a pipeline on a random net ---------------------------------------------------------------

_FS = 1000.0


def _random_net(h=8, seed=3):
    rng = np.random.default_rng(seed)
    return {"w1": rng.normal(size=(h, 5)), "b1": rng.normal(size=h), "w2": 2 * rng.normal(size=(2, h)),
            "b2": rng.normal(size=2), "input_mean": np.zeros(4),
            "input_gain": np.array([3e-3, 3e-3, 3e-5, 3e-5]), "fs": _FS}


def _fast_pipeline(controller=None, n_ridges=6, activation="fast", detector=None, **kw):
    est = StressRateEstimator(PVDFCircuit(), _FS, 2 * n_ridges, use_u=True)
    return MirrorPipeline(_random_net() if detector is None else detector, _FS, n_ridges, estimator=est,
                          controller=controller, activation=activation, **kw)


def _wave_signals(n, ni, seed=2):
    rng = np.random.default_rng(seed)
    waves = 0.05 * np.sin(np.arange(n)[:, None] * 0.01 * np.arange(1, ni + 1))
    return waves + 0.02 * rng.normal(size=(n, ni))


@pytest.fixture
def random_net():
    """The weights of a random 8-unit net for stress-rate features at 1 kHz (a new dict)."""
    return _random_net()


@pytest.fixture
def fast_pipeline():
    """Makes a MirrorPipeline at 1 kHz on :func:`random_net` (or ``detector``): 6 ridges with
    v and u inputs, the fast sigmoid, the default limits; other keywords go to MirrorPipeline."""
    return _fast_pipeline


@pytest.fixture
def wave_signals():
    """Makes ``n`` ticks of ``ni`` inputs: sines of rising frequency plus seeded noise."""
    return _wave_signals
