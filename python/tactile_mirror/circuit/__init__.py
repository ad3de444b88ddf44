"""The PVDF circuit: charge generation, charge amplifier and differentiator (paper Fig. 4).

- :mod:`~tactile_mirror.circuit.pvdf`: :class:`PVDFCircuit`, the components, transfer
  functions, gain curves, second-order sections at any rate, whole-record simulation;
- :mod:`~tactile_mirror.circuit.stream`: :class:`CircuitStream`, the same simulation sample
  by sample or block by block, with sensor noise;
- :mod:`~tactile_mirror.circuit.fit`: :func:`fit_circuit`, the components from a measured
  gain curve;
- :mod:`~tactile_mirror.circuit.checks`: the input checks the three share.
"""
from __future__ import annotations

from tactile_mirror.circuit.fit import fit_circuit
from tactile_mirror.circuit.pvdf import EPSILON_0, SLOPE_BAND, PVDFCircuit
from tactile_mirror.circuit.stream import CircuitStream

__all__ = ["EPSILON_0", "SLOPE_BAND", "CircuitStream", "PVDFCircuit", "fit_circuit"]
