"""The argument checks every constructor shares (tactile_mirror.checks): one wording and one
behaviour for numbers and sequences of numbers across the library."""
from __future__ import annotations

import numpy as np
import pytest
from tactile_mirror.circuit import PVDFCircuit
from tactile_mirror.estimator import StressRateEstimator
from tactile_mirror.pipeline import PaperController

FS = 1000.0


def _numeric_constructors(make):
    from tactile_mirror.estimator import notch_sos
    from tactile_mirror.loop import SimulatedStage, StageLimits
    from tactile_mirror.loop.design import design_loop
    from tactile_mirror.noise import SensorNoise

    limits = StageLimits(-0.02, 0.02, 0.03, 1.0)
    return [
        ("Cf", 2.2e-12, lambda v: PVDFCircuit(Cf=v)),
        ("fs", FS, lambda v: StressRateEstimator(PVDFCircuit(), v, 2)),
        ("notch_q", 30.0, lambda v: notch_sos(FS, 50.0, notch_q=v)),
        ("temperature", 300.0, lambda v: SensorNoise(temperature=v)),
        ("v_max", 0.03, lambda v: StageLimits(-0.02, 0.02, v, 1.0)),
        ("lag", 0.002, lambda v: SimulatedStage(limits, lag=v)),
        ("fs", FS, lambda v: design_loop(limits, (1.0, 1e7), v, stage_delay=0.001, stage_lag=0.002)),
        ("slip_threshold", 0.8, lambda v: make(slip_threshold=v)),
        ("gain", 1.0, lambda v: PaperController(gain=v)),
    ]


@pytest.mark.parametrize("case", range(9))
def test_numeric_arguments_are_checked_alike(case, fast_pipeline):
    # Every constructor takes its numbers through one check (tactile_mirror.checks): a
    # non-number is a TypeError, a NaN / Inf or out-of-range number a ValueError, and both
    # name the argument; the same arguments pass with a good value.
    name, good, build = _numeric_constructors(fast_pipeline)[case]
    build(good)
    for bad in ("1.0", None, True, [1.0]):
        with pytest.raises(TypeError, match=f"^{name} must be a real number"):
            build(bad)
    for bad in (float("nan"), float("inf"), -float("inf")):
        with pytest.raises(ValueError, match=f"^{name} must be .*finite"):
            build(bad)


@pytest.mark.parametrize("make, exc, match", [
    # a string was iterated character by character; a complex load lost its imaginary part
    (lambda tm: tm.PVDFCircuit(load="123"), TypeError, "load must be a sequence of real numbers"),
    (lambda tm: tm.PVDFCircuit(load=np.array([0.0, 0.0, 1 + 1j])), TypeError, "load"),
    (lambda tm: tm.SensorNoise(harmonics="10"), TypeError, "harmonics"),
    (lambda tm: tm.SensorNoise().apply(np.zeros(8) + 0j, np.zeros(8), 1e3), TypeError, "v_out"),
    (lambda tm: tm.SensorNoise().apply(np.zeros(8), np.zeros(8, dtype=bool), 1e3), TypeError, "u_out"),
])
def test_strings_complex_and_bools_are_not_real_sequences(make, exc, match):
    import tactile_mirror as tm

    with pytest.raises(exc, match=match):
        make(tm)
