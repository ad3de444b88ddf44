"""Sensor noise of the PVDF front end, derived from the circuit.

:class:`SensorNoise` models the noise at ``v_out`` (charge amplifier) and
``u_out`` (differentiator) of a :class:`~tactile_mirror.circuit.PVDFCircuit`:

Broadband sources (Gaussian, each independent, white at its origin)
    ``Rf``     Johnson noise of the charge amplifier's feedback resistor, a current
               ``sqrt(4 k T / Rf)`` (A/sqrt(Hz)) into the virtual-ground node.
    ``i_n1``   op-amp 1 input current noise into the same node.
    ``e_n1``   op-amp 1 input voltage noise.
    ``Rs``     Johnson noise of the differentiator's series resistor, a voltage
               ``sqrt(4 k T Rs)`` in series with its input.
    ``Rd``     Johnson noise of the differentiator's feedback resistor, a current
               ``sqrt(4 k T / Rd)`` into its virtual-ground node.
    ``i_n2``   op-amp 2 input current noise into the same node.
    ``e_n2``   op-amp 2 input voltage noise.

Noise gains (analog, from the circuit's own components; ``Zf = Rf || Cf``, ``Cp`` the
source capacitance at the charge amplifier's input: the film, plus a cable)::

    currents at node 1 -> v_out:   Zf = Rf / (1 + s Rf Cf)                       [V/A]
    e_n1 -> v_out:                 1 + Zf s Cp = (1 + s Rf (Cf + Cp)) / (1 + s Rf Cf)
    v_out -> u_out:                H_d = -s Rd Cd / (1 + s Rs Cd)                 (the differentiator)
    Rs -> u_out:                   H_d
    currents at node 2 -> u_out:   Rd                                              [V/A]
    e_n2 -> u_out:                 1 + s Rd Cd / (1 + s Rs Cd)

Every source of stage 1 reaches ``u_out`` through ``H_d`` as well, with its
``v_out`` noise (the two outputs' noise is correlated, as in the circuit).

Sampling
    The outputs are taken to be sampled at ``fs`` behind an ideal anti-alias filter
    at ``fs/2``: the broadband noise is drawn as white Gaussian sequences shaped by
    the bilinear images (``c = 2 fs``, as :meth:`PVDFCircuit.sos`) of the noise gains
    above, designed with :mod:`scipy.signal`. Its one-sided PSD (:meth:`SensorNoise.psd`)
    is the density of the source times ``|H(e^{j 2 pi f / fs})|^2`` of these sections,
    which equals the analog ``|H(j 2 pi f)|^2`` (:meth:`SensorNoise.psd_analog`) to
    within the bilinear frequency warping (0.2 dB at 100 Hz, fs = 1 kHz, defaults).
    The draws run through the filters from rest over a warm-up of at least 20 time
    constants of the slowest pole, which is dropped, so what is returned is stationary.

Mains hum
    ``hum`` V rms of ``mains`` Hz (50 or 60) at ``v_out``: pickup at the charge
    amplifier's high-impedance input, with harmonics ``k mains`` of relative amplitude
    ``harmonics[k - 1]``. It reaches ``u_out`` through the discrete differentiator
    ``H_d`` (about 3.1x at 50 Hz with the default circuit). Each channel gets its own
    random phases (pickup differs from strip to strip, so a difference of two strips
    does not cancel it). Harmonics at or above ``fs/2`` are left out.

Defaults of the op-amps: ``e_n = 15 nV/sqrt(Hz)`` and ``i_n = 2 fA/sqrt(Hz)``, typical
data-sheet densities (at 1 kHz) of general-purpose JFET-input op-amps, the class a
charge amplifier on a 1 GOhm feedback resistor is built with (TL07x-class parts: about
18 nV/sqrt(Hz) and 10 fA/sqrt(Hz); OPA14x-class precision JFET parts: about 5 nV/sqrt(Hz)
and 1 fA/sqrt(Hz)). Their 1/f noise (corners of some 10-100 Hz) is not modelled: the
densities are white. Temperature 300 K.

With the default circuit at ``fs = 1 kHz`` the broadband floor is about 44 uV rms at
``v_out`` (39 uV of it the 1 GOhm feedback resistor, 4.1 uV/sqrt(Hz) below the 72 Hz
corner; 19 uV the op-amp current noise; 2 uV its voltage noise) and about 0.34 mV rms
at ``u_out`` (see :meth:`SensorNoise.rms`). A 50 Hz line of 2 mV rms at ``v_out`` is
6.3 mV rms at ``u_out`` (its 150 Hz harmonic, 0.6 mV, becomes 6.0 mV).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from tactile_mirror.checks import channel_shape, real_array, real_number, real_sequence, sample_rate
from tactile_mirror.circuit import PVDFCircuit

__all__ = ["BOLTZMANN", "NOISE_SOURCES", "SensorNoise"]

#: Boltzmann constant, J/K.
BOLTZMANN = 1.380649e-23

#: Names of the broadband sources, in the order :meth:`SensorNoise.sources` returns them.
NOISE_SOURCES = ("Rf", "i_n1", "e_n1", "Rs", "Rd", "i_n2", "e_n2")

_OUTPUTS = ("v", "u")


@dataclass(frozen=True)
class NoiseSource:
    """One broadband source: its white density at its origin and its noise gains.

    Attributes
    ----------
    name : str
    density : float
        One-sided amplitude density at the source, V/sqrt(Hz) or A/sqrt(Hz).
    gain_v, gain_u : (z, p, k) or None
        Analog noise gain (zeros and poles in rad/s) to ``v_out`` and ``u_out``, V per
        unit of the source; None where the source does not reach that output.
    """

    name: str
    density: float
    gain_v: tuple | None
    gain_u: tuple | None


@dataclass(frozen=True)
class SensorNoise:
    """Noise of a PVDF circuit's outputs: thermal, op-amp and mains hum (see the module notes).

    Parameters
    ----------
    circuit : PVDFCircuit
        The circuit whose components set the noise gains. Default ``PVDFCircuit()``.
    temperature : float
        Of the resistors, K. Default 300.
    e_n : float
        Op-amp input voltage noise density, V/sqrt(Hz), both stages. Default 15e-9.
    i_n : float
        Op-amp input current noise density, A/sqrt(Hz), both stages. Default 2e-15.
    cable_capacitance : float
        Capacitance between the charge amplifier's input and ground besides the film's
        (cable, input pins), F. Default 0. It sets the voltage-noise gain ``1 + Cp/Cf``.
    hum : float
        Mains hum at ``v_out``, V rms of the fundamental. Default 0.
    mains : float
        Mains frequency, Hz: 50 or 60. Default 50.
    harmonics : tuple of float
        Amplitude of harmonic ``k`` relative to the fundamental at index ``k - 1``
        (the first entry must be 1). Default ``(1.0, 0.1, 0.3)``: odd harmonics
        dominate the hum of rectifier loads.

    Raises
    ------
    TypeError, ValueError
        A parameter of the wrong type or out of range (``e_n`` <= 1e-3 V/sqrt(Hz), ``i_n`` <=
        1e-6 A/sqrt(Hz), ``cable_capacitance`` <= 1e-6 F, ``hum`` <= 100 V); the message names it.

    Examples
    --------
    >>> model = SensorNoise(hum=2e-3)
    >>> nv, nu = model.draw(1000.0, 5000, channels=2, seed=1)   # V, shape (2, 5000) each
    >>> model.rms(1000.0, "v")                                   # doctest: +SKIP
    """

    circuit: PVDFCircuit = field(default_factory=PVDFCircuit)
    temperature: float = 300.0
    e_n: float = 15e-9
    i_n: float = 2e-15
    cable_capacitance: float = 0.0
    hum: float = 0.0
    mains: float = 50.0
    harmonics: tuple = (1.0, 0.1, 0.3)

    def __post_init__(self) -> None:
        if not isinstance(self.circuit, PVDFCircuit):
            raise TypeError(f"circuit must be a PVDFCircuit, got {type(self.circuit).__name__}")
        object.__setattr__(self, "temperature", real_number(self.temperature, "temperature", unit="K", positive=True))
        # Upper bounds far beyond any part or cable (1 mV/sqrt(Hz), 1 uA/sqrt(Hz), 1 uF, 100 V):
        # past them the draws overflowed or the warm-up length became infinite.
        for name, unit, top in (("e_n", "V/sqrt(Hz)", 1e-3), ("i_n", "A/sqrt(Hz)", 1e-6),
                                ("cable_capacitance", "F", 1e-6), ("hum", "V rms", 100.0)):
            v = real_number(getattr(self, name), name, unit=unit, nonnegative=True)
            if v > top:
                raise ValueError(f"{name} must be at most {top:g} {unit}, got {v!r}")
            object.__setattr__(self, name, v)
        mains = real_number(self.mains, "mains", unit="Hz", positive=True)
        if mains not in (50.0, 60.0):
            raise ValueError(f"mains must be 50 or 60 (Hz), got {self.mains!r}")
        object.__setattr__(self, "mains", mains)
        h = real_sequence(self.harmonics, "harmonics")
        if not h or h[0] != 1.0:
            raise ValueError(f"harmonics must start with 1.0 (the fundamental), got {self.harmonics!r}")
        if not all(math.isfinite(a) and a >= 0 for a in h):
            raise ValueError(f"harmonics must be finite and >= 0, got {self.harmonics!r}")
        object.__setattr__(self, "harmonics", h)

    # ------------------------------------------------------------------ sources
    @property
    def source_capacitance(self) -> float:
        """Capacitance at the charge amplifier's input, film plus cable, F."""
        return self.circuit.capacitance + self.cable_capacitance

    def sources(self) -> list[NoiseSource]:
        """The broadband sources with their densities and analog noise gains (:data:`NOISE_SOURCES` order)."""
        c = self.circuit
        kt4 = 4.0 * BOLTZMANN * self.temperature
        w1 = 1.0 / (c.Rf * c.Cf)
        wd = 1.0 / (c.Rs * c.Cd)
        # Zf = Rf / (1 + s Rf Cf) = (1/Cf) / (s + w1)
        zf = (np.array([]), np.array([-w1]), 1.0 / c.Cf)
        # 1 + s Rf (Cf + Cp) / ... = ((Cf + Cp)/Cf) (s + 1/(Rf (Cf+Cp))) / (s + w1)
        cp = self.source_capacitance
        en1 = (np.array([-1.0 / (c.Rf * (c.Cf + cp))]), np.array([-w1]), (c.Cf + cp) / c.Cf)
        # H_d = -s Rd Cd / (1 + s Rs Cd) = (-Rd/Rs) s / (s + wd)
        hd = (np.array([0.0]), np.array([-wd]), -c.Rd / c.Rs)
        # 1 + s Rd Cd / (1 + s Rs Cd) = ((Rs + Rd)/Rs) (s + 1/((Rs+Rd) Cd)) / (s + wd)
        en2 = (np.array([-1.0 / ((c.Rs + c.Rd) * c.Cd)]), np.array([-wd]), (c.Rs + c.Rd) / c.Rs)
        flat_rd = (np.array([]), np.array([]), c.Rd)

        def through_hd(g):
            return (np.concatenate([g[0], hd[0]]), np.concatenate([g[1], hd[1]]), g[2] * hd[2])

        return [
            NoiseSource("Rf", math.sqrt(kt4 / c.Rf), zf, through_hd(zf)),
            NoiseSource("i_n1", self.i_n, zf, through_hd(zf)),
            NoiseSource("e_n1", self.e_n, en1, through_hd(en1)),
            NoiseSource("Rs", math.sqrt(kt4 * c.Rs), None, hd),
            NoiseSource("Rd", math.sqrt(kt4 / c.Rd), None, flat_rd),
            NoiseSource("i_n2", self.i_n, None, flat_rd),
            NoiseSource("e_n2", self.e_n, None, en2),
        ]

    def _source(self, name):
        for s in self.sources():
            if s.name == name:
                return s
        raise ValueError(f"source must be one of {NOISE_SOURCES} or None, got {name!r}")

    def _selected(self, source):
        return self.sources() if source is None else [self._source(source)]

    # ------------------------------------------------------------------ discrete design
    def sos(self, fs: float, source: str, output: str = "v") -> np.ndarray | None:
        """Second-order sections (bilinear, ``c = 2 fs``) of one source's noise gain to
        ``output``, per unit of the source; None where it does not reach the output."""
        import scipy.signal

        fs = sample_rate(fs)
        output = _check_output(output)
        g = self._source(source).gain_v if output == "v" else self._source(source).gain_u
        if g is None:
            return None
        z, p, k = g
        zd, pd, kd = scipy.signal.bilinear_zpk(z, p, k, fs)
        return scipy.signal.zpk2sos(zd, pd, kd)

    # ------------------------------------------------------------------ spectra
    def psd(self, f: npt.ArrayLike, fs: float, output: str = "v", source: str | None = None) -> np.ndarray:
        """One-sided PSD of the sampled broadband noise at ``f`` (Hz, ``0 <= f <= fs/2``), V^2/Hz.

        Exact for what :meth:`draw` returns (hum not included: it is a set of lines,
        see :meth:`hum_lines`). ``source`` picks one of :data:`NOISE_SOURCES`; default all.
        """
        import scipy.signal

        fs = sample_rate(fs)
        f = _freqs(f, fs)
        out = np.zeros(f.shape)
        for s in self._selected(source):
            sos = self.sos(fs, s.name, output)
            if sos is None or s.density == 0:
                continue
            _, h = scipy.signal.sosfreqz(sos, worN=f, fs=fs)
            out += s.density**2 * np.abs(h) ** 2
        return out

    def psd_analog(self, f: npt.ArrayLike, output: str = "v", source: str | None = None) -> np.ndarray:
        """One-sided PSD of the analog broadband noise at ``f`` (Hz, >= 0), V^2/Hz."""
        output = _check_output(output)
        f = np.asarray(f, dtype=np.float64)
        if not np.all(np.isfinite(f)) or np.any(f < 0):
            raise ValueError("f must be finite and >= 0 (Hz)")
        out = np.zeros(f.shape)
        s = 2j * np.pi * f
        for src in self._selected(source):
            g = src.gain_v if output == "v" else src.gain_u
            if g is None:
                continue
            z, p, k = g
            h = np.full(f.shape, k, dtype=complex)
            for zz in z:
                h = h * (s - zz)
            for pp in p:
                h = h / (s - pp)
            out += src.density**2 * np.abs(h) ** 2
        return out

    def rms(self, fs: float, output: str = "v", source: str | None = None, hum: bool = True) -> float:
        """Rms of the sampled noise at ``output``, V: the broadband PSD integrated over
        ``[0, fs/2]`` (of ``source`` only if given), plus the hum lines when ``hum``
        (and no ``source`` is given)."""
        fs = sample_rate(fs)
        f = np.linspace(0.0, fs / 2, 2**15 + 1)
        var = float(np.trapezoid(self.psd(f, fs, output, source), f))
        if hum and source is None:
            var += float(np.sum(self.hum_lines(fs, output)[1] ** 2))
        return math.sqrt(var)

    def hum_lines(self, fs: float, output: str = "v") -> tuple[np.ndarray, np.ndarray]:
        """Frequencies (Hz) and rms amplitudes (V) of the hum lines at ``output``, below ``fs/2``."""
        import scipy.signal

        fs = sample_rate(fs)
        output = _check_output(output)
        k = np.arange(1, len(self.harmonics) + 1)
        f = self.mains * k
        a = self.hum * np.asarray(self.harmonics)
        keep = (f < fs / 2) & (a > 0)
        f, a = f[keep], a[keep]
        if output == "u" and f.size:
            z, p, g = self._hd()
            zd, pd, kd = scipy.signal.bilinear_zpk(z, p, g, fs)
            _, h = scipy.signal.freqz_zpk(zd, pd, kd, worN=f, fs=fs)
            a = a * np.abs(h)
        return f, a

    def _hd(self):
        c = self.circuit
        return np.array([0.0]), np.array([-1.0 / (c.Rs * c.Cd)]), -c.Rd / c.Rs

    # ------------------------------------------------------------------ drawing
    def draw(self, fs: float, n: int, channels: int | tuple[int, ...] = 1,
             seed: int | Sequence[int] | np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Draw noise of ``v_out`` and ``u_out``.

        Parameters
        ----------
        fs : float
            Sample rate, Hz.
        n : int
            Samples per channel, >= 0.
        channels : int or tuple of int
            Number of strips or the shape of the strip axes.
        seed : int, sequence of int or numpy.random.Generator, optional
            Same seed, same noise (what ``numpy.random.default_rng`` takes); a
            Generator is used as it is.

        Returns
        -------
        noise_v, noise_u : ndarray, shape (*channels, n)
            V; stationary, with the PSD of :meth:`psd` and the hum of :meth:`hum_lines`.
        """
        import scipy.signal

        fs = sample_rate(fs)
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"n must be a non-negative integer (samples), got {n!r}")
        shape = channel_shape(channels)
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")  # (numpy's words named nothing)
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        m = int(np.prod(shape, dtype=np.int64))
        v = np.zeros((m, int(n)))
        u = np.zeros((m, int(n)))
        if m and n:
            warm = self._warmup(fs)
            for s in self.sources():
                if s.density == 0:
                    continue
                # white sequence of one-sided density s.density: variance density^2 fs / 2
                w = rng.standard_normal((m, warm + int(n))) * (s.density * math.sqrt(fs / 2))
                for sos, acc in ((self.sos(fs, s.name, "v"), v), (self.sos(fs, s.name, "u"), u)):
                    if sos is not None:
                        acc += scipy.signal.sosfilt(sos, w, axis=-1)[:, warm:]
            f_v, a_v = self.hum_lines(fs, "v")
            if f_v.size:
                t = np.arange(int(n)) / fs
                phase = rng.uniform(0.0, 2 * np.pi, (m, f_v.size))
                z, p, g = self._hd()
                zd, pd, kd = scipy.signal.bilinear_zpk(z, p, g, fs)
                _, hd = scipy.signal.freqz_zpk(zd, pd, kd, worN=f_v, fs=fs)
                for j in range(f_v.size):
                    arg = 2 * np.pi * f_v[j] * t[None, :] + phase[:, j:j + 1]
                    v += math.sqrt(2) * a_v[j] * np.cos(arg)
                    u += math.sqrt(2) * a_v[j] * np.abs(hd[j]) * np.cos(arg + np.angle(hd[j]))
        return v.reshape(*shape, int(n)), u.reshape(*shape, int(n))

    def apply(self, v_out: npt.ArrayLike, u_out: npt.ArrayLike, fs: float,
              seed: int | Sequence[int] | np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``v_out``, ``u_out`` (V, time last, same shape) with drawn noise added."""
        v, u = real_array(v_out, "v_out"), real_array(u_out, "u_out")
        if v.ndim < 1 or u.shape != v.shape:
            raise ValueError(f"u_out must have the shape of v_out {v.shape}, got {u.shape}")
        nv, nu = self.draw(fs, v.shape[-1], v.shape[:-1], seed)
        return v + nv, u + nu

    def _warmup(self, fs: float) -> int:
        c = self.circuit
        slowest = max(c.Rf * c.Cf, c.Rs * c.Cd, c.Rf * (c.Cf + self.source_capacitance),
                      (c.Rs + c.Rd) * c.Cd)
        return math.ceil(20 * slowest * fs) + 1


def _check_output(output) -> str:
    if output not in _OUTPUTS:
        raise ValueError(f"output must be 'v' or 'u', got {output!r}")
    return output


def _freqs(f, fs) -> np.ndarray:
    f = np.asarray(f, dtype=np.float64)
    if not np.all(np.isfinite(f)) or np.any(f < 0) or np.any(f > fs / 2):
        raise ValueError(f"f must lie in [0, fs/2] = [0, {fs / 2}] Hz")
    return f
