"""tactile_mirror: closed-loop tactile displays that render static friction.

Data flow (one module or package per stage):

    scene -> contact/ (ridge FEM, Coulomb friction) -> circuit (PVDF charge amp and
    differentiator) -> estimator (stress rate from v_out, u_out) -> detector (Jordan MLP)
    -> loop (controller, stage)

Filtering follows scipy.signal conventions (``sos``, ``zi``, ``axis``); everything is SI
(m, s, Pa, N, V) with time on the last axis.
"""
from __future__ import annotations

from .filters import SosFilter, simd_path, sosfilt

__version__ = "0.1.0"

__all__ = [
    "SosFilter",
    "__version__",
    "simd_path",
    "sosfilt",
]
