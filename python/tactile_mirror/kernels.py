"""The compiled kernels seen from Python: which code path each runs, and the hooks that
benchmarks, the lab and cluster workers use to time, compare or pin them.

Every kernel is compiled for the x86-64 baseline and, where the CPU has them, AVX2+FMA
clones chosen once at start-up (``-DTM_NATIVE=ON`` builds for the host only). Two paths
may round differently, so a result that must be bit-identical across machines records
:func:`simd_paths` beside it.
"""
from __future__ import annotations

import numpy as np
import numpy.typing as npt

from tactile_mirror import _core

__all__ = ["contact_simd_path", "detector_has_avx2_fma", "detector_sigmoid", "jordan_loss_grad", "simd_paths",
           "use_contact_baseline"]


def simd_paths() -> dict[str, str]:
    """The code path each kernel family runs on this CPU: ``{"filters", "detector", "contact"}``
    -> ``"avx2+fma"``, ``"sse2"``, ``"native"`` or ``"generic"`` (the filters' and pipeline's
    path is :func:`tactile_mirror.simd_path`)."""
    return {"filters": _core.simd_path(),
            "detector": "avx2+fma" if _core.detector_cpu_has_avx2_fma() else "generic",
            "contact": _core._contact_simd_path()}


def detector_has_avx2_fma() -> bool:
    """Whether the detector kernels' AVX2+FMA variant can run here (and this build has one)."""
    return bool(_core.detector_cpu_has_avx2_fma())


def contact_simd_path() -> str:
    """The path the contact solver's kernels run now: ``"avx2+fma"`` or the baseline's name."""
    return _core._contact_simd_path()


def use_contact_baseline(on: bool) -> None:
    """Run the contact solver's baseline (SSE2) kernels even on AVX2 hardware (``on=True``),
    or go back to the path chosen at start-up (``on=False``). Process-wide; for benchmarks
    and for machines that must round alike."""
    if not isinstance(on, (bool, np.bool_)):
        raise TypeError(f"on must be a bool, got {type(on).__name__}")
    _core._contact_set_baseline(bool(on))


def detector_sigmoid(a: npt.NDArray[np.floating], activation: str = "fast", path: str = "avx2+fma") -> np.ndarray:
    """The detector kernel's sigmoid (with its clamp) on a flat copy of ``a`` (float32 or
    float64, kept): ``activation`` ``"fast"`` or ``"exact"``, ``path`` ``"avx2+fma"`` or
    ``"generic"``. For measuring the fast sigmoid's error."""
    return _core.detector_sigmoid(a, activation, path)  # type: ignore[call-overload]


def jordan_loss_grad(theta, xn, t_slip, t_pred, w_slip, w_pred, length, n_hidden: int, n_threads: int = 1
                     ) -> tuple[float, np.ndarray]:
    """The Jordan net's weighted cross-entropy loss and its exact BPTT gradient in C++ (float64).

    ``theta`` is the flat parameter vector of :class:`tactile_mirror.detector.Params`;
    ``xn`` (n_seq, n_inputs, n) the normalised inputs, ``t_slip``/``t_pred`` the targets and
    ``w_slip``/``w_pred`` their weights, (n_seq, n); ``length`` (n_seq,) each sequence's real
    samples; ``n_threads`` 1 or more. Checked against
    :func:`tactile_mirror.detector.loss_and_grad` (the numpy specification) to 1e-12.
    """
    return _core.jordan_loss_grad(theta, xn, t_slip, t_pred, w_slip, w_pred, length, n_hidden, n_threads)
