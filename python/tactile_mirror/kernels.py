"""The compiled kernels seen from Python: which code path each runs, and the hooks that
benchmarks, the lab and cluster workers use to time, compare or pin them.

Every kernel is compiled for the x86-64 baseline and, where the CPU has them, AVX2+FMA
clones chosen at run time (``-DTM_NATIVE=ON`` builds for the host only). Two paths may
round differently, so a result that must be bit-identical across machines records
:func:`simd_paths` beside it, or is computed on the baseline everywhere:
:func:`use_baseline` holds every kernel of the process to the baseline, and the
environment variable :data:`SIMD_VARIABLE` (``TM_SIMD=baseline``, read when the compiled
core is imported) starts a process that way (a cluster worker, say).
"""
from __future__ import annotations

import numpy as np
import numpy.typing as npt

from tactile_mirror import _core

__all__ = ["SIMD_VARIABLE", "baseline_in_use", "contact_simd_path", "detector_has_avx2_fma", "detector_sigmoid",
           "jordan_loss_grad", "simd_paths", "use_baseline"]

#: The environment variable read when the compiled core is imported: ``"baseline"`` starts
#: the process with :func:`use_baseline` on; unset, empty or ``"auto"`` leaves each kernel
#: on the CPU's best path; any other value makes the import fail with a message naming it.
SIMD_VARIABLE = "TM_SIMD"


def simd_paths() -> dict[str, str]:
    """The code path each kernel family runs now: ``{"filters", "detector", "contact"}``
    -> ``"avx2+fma"``, ``"sse2"`` (the x86-64 baseline), ``"native"`` (a ``-DTM_NATIVE=ON``
    build) or ``"generic"`` (the baseline elsewhere). "Now": for the filters and the
    detector, the path of the objects built from now on; the contact solver follows
    :func:`use_baseline` at every solve. The filters' and pipeline's path is also
    :func:`tactile_mirror.simd_path`."""
    path = _core.simd_path()
    return {"filters": path, "detector": path, "contact": _core._contact_simd_path()}


def baseline_in_use() -> bool:
    """Whether the kernels are held to the baseline path now (:func:`use_baseline`, or the
    process started with ``TM_SIMD=baseline``)."""
    return bool(_core._baseline_forced())


def use_baseline(on: bool) -> None:
    """Hold every compiled kernel of this process to the baseline path (``on=True``: SSE2 on
    x86-64, no AVX2 nor FMA), or return to the CPU's best (``on=False``).

    Process-wide, for all threads. Filters, detector nets and pipelines built after the
    call run the path it sets (those built before keep theirs); the contact solver and the
    detector's training gradient follow it at every call. A machine with AVX2+FMA and one
    without give the same bits on the baseline: the portable mode of
    :func:`tactile_mirror.engine.run_tasks` turns it on in every task. Switch between runs,
    not while another thread is inside a kernel. A ``-DTM_NATIVE=ON`` build has a single
    path, which this leaves as it is.
    """
    if not isinstance(on, (bool, np.bool_)):
        raise TypeError(f"on must be a bool, got {type(on).__name__}")
    _core._set_baseline(bool(on))


def detector_has_avx2_fma() -> bool:
    """Whether the detector kernels' AVX2+FMA variant can run now: this CPU and build have
    one, and the kernels are not held to the baseline (:func:`use_baseline`)."""
    return bool(_core.detector_cpu_has_avx2_fma())


def contact_simd_path() -> str:
    """The path the contact solver's kernels run now: ``"avx2+fma"`` or the baseline's name."""
    return _core._contact_simd_path()


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
