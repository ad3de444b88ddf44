"""Test configuration shared by the whole suite."""
import os
import sys

import pytest

# Small problems: BLAS/OpenMP threading only adds overhead on 2-core machines.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from hypothesis import HealthCheck, settings

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
