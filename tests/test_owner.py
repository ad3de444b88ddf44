"""Objects holding a running compiled state (tactile_mirror._owner.NotCopyable): copies
and pickles are refused, naming the class and how to make another."""
from __future__ import annotations

import copy
import pickle

import pytest
import tactile_mirror as tm
from scipy import signal
from tactile_mirror.contact import ContactSolver, Pad, ridge_model
from tactile_mirror.geometry import RidgeGeometry


@pytest.mark.parametrize("make", [
    lambda: tm.SosFilter(signal.butter(2, 0.1, output="sos")),
    lambda: tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 2),
    lambda: tm.MirrorPipeline(tm.SlipDetector.default(), 1000.0, 1,
                              estimator=tm.StressRateEstimator(tm.PVDFCircuit(), 1000.0, 2)),
    lambda: tm.SlipDetector.default(),
    lambda: ContactSolver(ridge_model(RidgeGeometry()), 0.5),
    lambda: Pad(ridge_model(RidgeGeometry()), 0.5, n_ridges=2),
])
def test_objects_with_a_running_state_refuse_copies_naming_their_class(make):
    """copy.copy shared the C++ state (two filters stepping one state); deepcopy and
    pickle named a private class."""
    obj = make()
    name = type(obj).__name__
    for do in (copy.copy, copy.deepcopy, pickle.dumps):
        with pytest.raises(TypeError, match=f"a {name} cannot be"):
            do(obj)
    # what the hint says works
    if isinstance(obj, tm.SlipDetector):
        assert pickle.loads(pickle.dumps(obj.weights)).params.w1.shape == obj.weights.params.w1.shape
