"""The PVDF circuit in streaming form: :class:`CircuitStream`, strip stresses in,
``v_out`` and ``u_out`` out, sample by sample or block by block, with sensor noise.

It runs the sections of :meth:`PVDFCircuit.sos <tactile_mirror.circuit.PVDFCircuit.sos>`
on the C++ filter engine. Made with :meth:`PVDFCircuit.stream
<tactile_mirror.circuit.PVDFCircuit.stream>` or directly.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from tactile_mirror.checks import channel_shape, sample_rate
from tactile_mirror.circuit.checks import check_noise, finite_array, stress_array
from tactile_mirror.filters import SosFilter

if TYPE_CHECKING:
    from tactile_mirror.circuit.pvdf import PVDFCircuit

__all__ = ["CircuitStream"]


class CircuitStream:
    """The circuit in streaming form: strip stresses in, ``v_out`` and ``u_out`` out,
    sample by sample (:meth:`step`) or block by block (:meth:`process`).

    Runs the sections of :meth:`PVDFCircuit.sos` on the C++ filter engine
    (:class:`~tactile_mirror.filters.SosFilter`, float64), one channel per strip. Any
    chunking of a record, down to single samples, gives the one-shot result of
    :meth:`PVDFCircuit.simulate` bit for bit (noise included, for the same ``seed``
    and the same chunking of noise draws: each call draws the ``v_out`` noise of
    its samples, then the ``u_out`` noise).

    Parameters
    ----------
    circuit : PVDFCircuit
    fs : float
        Sample rate, Hz.
    channels : int or tuple of int
        Number of strips, or the shape of the strip axes (e.g. ``(n_ridges, 2)``):
        the leading shape of every input, fixed at construction.
    noise : float or (float, float)
        Sensor noise, V rms, white and Gaussian, added to ``v_out`` and ``u_out``
        (one value for both, or one each). Default 0.
    seed : int or numpy.random.Generator, optional
        Seed of the noise; a Generator is used as it is (shared with the caller).
    method, prewarp
        Discretisation, as in :meth:`PVDFCircuit.sos`.

    Notes
    -----
    Inputs come either as stresses (:meth:`step`, :meth:`process`: ``s1, s2, s3``
    on the axis before time, Pa) or as equivalent loads (:meth:`step_load`,
    :meth:`process_load`: :meth:`PVDFCircuit.equivalent_load`, Pa). Stresses are
    checked (finite, real) and raise ``ValueError`` naming ``stress``; equivalent
    loads in :meth:`step_load` are not checked (a NaN is rejected by the filter,
    which holds its previous output, see :meth:`SosFilter.step`).
    """

    def __init__(self, circuit: PVDFCircuit, fs: float, channels: int | tuple[int, ...] = 1,
                 noise: float | tuple[float, float] = 0.0, seed: int | np.random.Generator | None = None,
                 method: str = "bilinear", prewarp: float | None = None) -> None:
        if not (callable(getattr(circuit, "sos", None)) and callable(getattr(circuit, "equivalent_load", None))):
            raise TypeError(f"circuit must be a PVDFCircuit (sos and equivalent_load), got {type(circuit).__name__}")
        self.circuit = circuit
        self.fs = sample_rate(fs)
        self.shape = channel_shape(channels)
        self.noise = check_noise(noise)
        self.n_channels = int(np.prod(self.shape, dtype=np.int64))
        sos_v = circuit.sos(self.fs, "v", method, prewarp)
        sos_u = circuit.sos(self.fs, "u", method, prewarp)
        # no filter for zero channels (an empty record passes through)
        self._v = SosFilter(sos_v, self.n_channels) if self.n_channels else None
        self._u = SosFilter(sos_u, self.n_channels) if self.n_channels else None
        self._rng = np.random.default_rng(seed) if any(self.noise) else None

    def reset(self) -> None:
        """Back to rest (the noise generator goes on)."""
        if self._v is not None and self._u is not None:
            self._v.reset()
            self._u.reset()

    # ------------------------------------------------------------------ one sample
    def step(self, stress: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """One sample of strip stresses, shape ``(*channels, 3)``, Pa -> ``v_out``,
        ``u_out``, each shape ``channels``, V."""
        s = stress_array(np.asarray(stress)[..., None])
        if s.shape[:-2] != self.shape:
            raise ValueError(f"stress must have shape {(*self.shape, 3)}, got {np.shape(stress)}")
        v, u = self.step_load(self.circuit.equivalent_load(s)[..., 0])
        return v.reshape(self.shape), u.reshape(self.shape)

    def step_load(self, load: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """One sample of equivalent loads, shape ``channels`` (or flat), Pa -> ``v_out``,
        ``u_out``, flat ``(n_channels,)``, V."""
        x = np.asarray(load, dtype=np.float64).reshape(-1)
        if x.size != self.n_channels:
            raise ValueError(f"load must have {self.n_channels} values (channels {self.shape}), got {x.size}")
        if self._v is None or self._u is None:
            return x.copy(), x.copy()
        v = self._v.step(x)
        u = self._u.step(x)
        return self._add_noise(v, u)

    # ------------------------------------------------------------------ blocks
    def process(self, stress: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """A block of strip stresses, shape ``(*channels, 3, n)``, Pa -> ``v_out``,
        ``u_out``, each ``(*channels, n)``, V. The state carries over to the next call."""
        s = stress_array(stress)
        if s.shape[:-2] != self.shape:
            raise ValueError(f"stress must have shape {(*self.shape, 3, 'n')}, got {s.shape}")
        return self.process_load(self.circuit.equivalent_load(s))

    def process_load(self, load: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """A block of equivalent loads, shape ``(*channels, n)``, Pa -> ``v_out``,
        ``u_out``, same shape, V."""
        lo = finite_array(load, "load")
        if lo.shape[:-1] != self.shape:
            raise ValueError(f"load must have shape {(*self.shape, 'n')}, got {lo.shape}")
        n = lo.shape[-1]
        if self._v is None or self._u is None or n == 0:
            v, u = lo.copy(), lo.copy()
        else:
            x = lo.reshape(self.n_channels, n)
            v = self._v.process(x).reshape(lo.shape)
            u = self._u.process(x).reshape(lo.shape)
        return self._add_noise(v, u)

    def _add_noise(self, v: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``v``, ``u`` with this call's noise draws (``v_out``'s first)."""
        noise_v, noise_u = self.noise
        if self._rng is not None:
            if noise_v:
                v = v + self._rng.normal(0.0, noise_v, v.shape)
            if noise_u:
                u = u + self._rng.normal(0.0, noise_u, u.shape)
        return v, u
