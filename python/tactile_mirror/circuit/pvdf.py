"""PVDF circuit model: charge generation, charge amplifier and differentiator.

A PVDF strip turns the stress it carries into charge; an inverting
transimpedance (charge) amplifier turns the charge into ``v_out``; an inverting
differentiator turns ``v_out`` into ``u_out`` (paper Fig. 4). This module holds
the circuit's physical parameters (:class:`PVDFCircuit`), its analog transfer
functions and gain curves (paper Eq. 1), its discretisation to second-order
sections at any sample rate, a simulator that runs those sections on the C++
filter engine (:meth:`PVDFCircuit.simulate` for whole records; its streaming form
:class:`~tactile_mirror.circuit.stream.CircuitStream` for sample-by-sample and block-by-block
use is in :mod:`tactile_mirror.circuit.stream`, and
:func:`~tactile_mirror.circuit.fit.fit_circuit`, which identifies the components from a
measured gain curve, in :mod:`tactile_mirror.circuit.fit`).

Circuit
-------
Charge, from the strip-averaged normal stresses ``s1`` (along the strip length),
``s2`` (along the strip width) and ``s3`` (through the film thickness)::

    Q = A (d31 s1 + d32 s2 + d33 s3),            A = length * width

Charge amplifier, feedback ``Rf || Cf`` from output to the virtual-ground input
(the film's own capacitance sits at virtual ground and drops out)::

    v_out / Q = -s Rf / (1 + s Rf Cf)

a differentiator (``v_out = -Rf dQ/dt``: the stress rate) below the corner
``fc = 1 / (2 pi Rf Cf)`` and a charge amplifier (``-Q / Cf``) above it.

Differentiator, input capacitor ``Cd`` in series with ``Rs``, feedback ``Rd``::

    u_out / v_out = -s Rd Cd / (1 + s Rs Cd)

a differentiator with time constant ``tau_d = Rd Cd`` below its roll-off corner
``fd = 1 / (2 pi Rs Cd)``, which limits its noise gain.

The load
--------
The paper's Eq. (1) divides an output by "the applied load" ``lo``. Here the
load is a stress: one pascal of load is the stress pattern ``load = (l1, l2,
l3)`` (weights of ``s1, s2, s3``; default ``(0, 0, 1)``, a uniform normal stress
through the film thickness). One pascal of load makes the charge
``q = A (d31 l1 + d32 l2 + d33 l3)`` (:attr:`PVDFCircuit.charge_sensitivity`,
C/Pa), so::

    v_out / lo = -q s Rf / (1 + s Rf Cf)                       [V/Pa]
    u_out / lo = (v_out / lo) (-s Rd Cd / (1 + s Rs Cd))       [V/Pa]

Any stress state acts through its charge only: it is equivalent to the load
``Q / q`` (:meth:`PVDFCircuit.equivalent_load`), and that is the stress whose
rate the estimator (:mod:`tactile_mirror.estimator`) recovers.

Defaults and the paper's slopes
-------------------------------
The paper measured gain slopes of 18.5 dB/dec for ``v_out`` and 38.5 dB/dec for
``u_out``. A first-order high-pass has the local slope ``20 / (1 + (f/fc)^2)``
dB/dec, so a slope below 20 means the charge-amplifier corner lies at or just
above the band measured. The slope of a band is taken here as the least-squares
line through the gain in dB against ``log10 f`` at log-spaced frequencies
(:meth:`PVDFCircuit.slope`). Over the band ``SLOPE_BAND = (1, 100)`` Hz (slow
loading of about 1 s up to slip transients of about 10 ms) the defaults

    Rf = 1 GOhm, Cf = 2.2 pF    ->  fc = 72.3 Hz
    Rd = 100 kOhm, Cd = 100 nF  ->  tau_d = 10 ms
    Rs = 2.2 kOhm               ->  fd = 723 Hz

give 18.52 dB/dec (v_out) and 38.50 dB/dec (u_out). The charge-amplifier corner
thus lies inside the band of the slip transients: :mod:`~tactile_mirror.estimator`
equalises it. The differentiator's roll-off lies a decade above the band (it
costs 0.02 dB/dec of slope there).

Discretisation
--------------
:meth:`PVDFCircuit.sos` maps the analog circuit to second-order sections.

``"bilinear"``
    Bilinear transform ``s = c (z - 1) / (z + 1)``. ``prewarp=None`` (default)
    uses ``c = 2 fs``, which keeps the low-frequency asymptote exact: the
    stress-rate sensitivity at slow loading is the analog one. ``prewarp=f0``
    uses ``c = 2 pi f0 / tan(pi f0 / fs)``: exact response at ``f0``, all other
    frequencies scaled (the low-frequency gain of ``v_out`` is off by the
    factor ``(pi f0 / fs) / tan(pi f0 / fs)``, squared for ``u_out``).
``"matched"``
    Matched z-transform: poles and zeros mapped by ``z = exp(s / fs)``, the gain
    matched to the analog low-frequency asymptote. For ``v_out`` this equals the
    first-order-hold discretisation (what :func:`scipy.signal.lsim` computes).

Error of the discrete frequency response against the analog one over
``SLOPE_BAND`` at ``fs = 1 kHz`` (defaults; |dB| max, phase max)::

    method                     v_out            u_out
    bilinear                   0.10 dB, 0.9 deg  0.39 dB, 1.2 deg
    bilinear, prewarp=fc       0.15 dB, 0.4 deg  0.30 dB, 0.6 deg
    matched                    0.002 dB, 1.4 deg 0.08 dB, 11.9 deg

Matched-z fits the magnitude best, but its phase lags (for ``u_out`` the
differentiator's roll-off lies above Nyquist at 1 kHz and the matched section
acts as a backward difference, half a sample late). The bilinear default keeps
the phase within about a degree and the slow-loading sensitivity exact; it is
what :meth:`PVDFCircuit.simulate` uses. At ``fs = 10 kHz`` all errors are below
0.01 dB and 0.2 deg.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from tactile_mirror.checks import real_number, real_sequence, sample_rate
from tactile_mirror.circuit.checks import check_noise, finite_array, stress_array
from tactile_mirror.circuit.stream import CircuitStream

if TYPE_CHECKING:
    import scipy.signal

__all__ = ["EPSILON_0", "SLOPE_BAND", "PVDFCircuit"]

#: Band over which the default circuit reproduces the paper's slopes, Hz.
SLOPE_BAND: tuple[float, float] = (1.0, 100.0)

#: Vacuum permittivity, F/m.
EPSILON_0 = 8.8541878128e-12

_OUTPUTS = ("v", "u")
_METHODS = ("bilinear", "matched")
_POSITIVE_FIELDS = ("length", "width", "thickness", "eps_r", "Rf", "Cf", "Rd", "Cd", "Rs")
_FINITE_FIELDS = ("d31", "d32", "d33")


def _check_output(output) -> str:
    if output not in _OUTPUTS:
        raise ValueError(f"output must be 'v' or 'u', got {output!r}")
    return output


def _low_frequency_gain_analog(z, p, k) -> float:
    """lim_{s->0} H(s) / s^m for an analog zpk with m zeros at the origin."""
    nz = z[z != 0]
    return float(np.real(k * np.prod(-nz) / np.prod(-p)))


def _band_freqs(band, num) -> np.ndarray:
    try:
        lo, hi = (float(b) for b in band)
    except (TypeError, ValueError):
        raise TypeError(f"band must be a pair (f_low, f_high) in Hz, got {band!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise ValueError(f"band must satisfy 0 < f_low < f_high (Hz), got {band!r}")
    if int(num) < 2:
        raise ValueError(f"num must be >= 2, got {num}")
    return np.logspace(math.log10(lo), math.log10(hi), int(num))


@dataclass(frozen=True)
class PVDFCircuit:
    """A PVDF strip with its charge amplifier and differentiator (paper Fig. 4).

    All parameters are SI. The defaults reproduce the paper's gain slopes (18.5
    and 38.5 dB/dec) over :data:`SLOPE_BAND`; see the module notes.

    Parameters
    ----------
    length, width, thickness : float
        Strip size, m. Defaults 10 mm, 1 mm, 80 um (KF Piezofilm 80 um cut 1 x 10 mm).
    d31, d32, d33 : float
        Piezoelectric charge coefficients, C/N, for stress along the length (1),
        the width (2) and through the thickness (3). Defaults 23e-12, 3e-12, -33e-12.
    eps_r : float
        Relative permittivity of the film. Default 12.5.
    Rf, Cf : float
        Charge-amplifier feedback, ohm and F. Defaults 1 GOhm and 2.2 pF
        (corner ``fc = 72.3 Hz``).
    Rd, Cd : float
        Differentiator feedback resistor and input capacitor, ohm and F. Defaults
        100 kOhm and 100 nF (``tau_d = Rd Cd = 10 ms``).
    Rs : float
        Differentiator series (roll-off) resistor, ohm. Default 2.2 kOhm (roll-off
        ``fd = 723 Hz``).
    load : tuple of 3 floats
        Stress pattern of one pascal of load: weights of ``(s1, s2, s3)``. Default
        ``(0, 0, 1)``: uniform normal stress through the film. Gains are per pascal
        of this load and the estimator reports rates of it.

    Raises
    ------
    ValueError
        A non-positive or non-finite size, permittivity or component, a non-finite
        coefficient, a load that makes no charge, time constants ``Rf Cf``, ``Rd Cd``,
        ``Rs Cd`` outside [1e-12, 1e9] s or a charge per pascal outside [1e-30, 1] C/Pa in
        size; the message names the field.
    """

    length: float = 10e-3
    width: float = 1e-3
    thickness: float = 80e-6
    d31: float = 23e-12
    d32: float = 3e-12
    d33: float = -33e-12
    eps_r: float = 12.5
    Rf: float = 1e9
    Cf: float = 2.2e-12
    Rd: float = 100e3
    Cd: float = 100e-9
    Rs: float = 2.2e3
    load: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        for name in _POSITIVE_FIELDS + _FINITE_FIELDS:
            value = real_number(getattr(self, name), name, positive=name in _POSITIVE_FIELDS)
            object.__setattr__(self, name, value)
        load = real_sequence(self.load, "load")
        if len(load) != 3:
            raise ValueError(f"load must have 3 entries (s1, s2, s3), got {len(load)}")
        if not all(math.isfinite(v) for v in load):
            raise ValueError(f"load must be finite, got {load}")
        object.__setattr__(self, "load", load)
        if self.charge_sensitivity == 0.0:
            raise ValueError("load makes no charge: d31*l1 + d32*l2 + d33*l3 == 0")
        # What the filters can represent: time constants from a ps to 30 years, a charge
        # sensitivity between 1e-30 and 1 C/Pa (past these the filter design broke inside
        # scipy, with an AssertionError or non-finite sections that named no field).
        for name, tau in (("Rf * Cf", self.Rf * self.Cf), ("Rd * Cd", self.Rd * self.Cd),
                          ("Rs * Cd", self.Rs * self.Cd)):
            if not 1e-12 <= tau <= 1e9:
                raise ValueError(f"{name} = {tau:g} s must lie in [1e-12, 1e9] s")
        if not 1e-30 <= abs(self.charge_sensitivity) <= 1.0:
            raise ValueError(f"the load's charge per pascal, A (d31 l1 + d32 l2 + d33 l3) = "
                             f"{self.charge_sensitivity:g} C/Pa, must lie within 1e-30 and 1 in size")

    # ------------------------------------------------------------------ derived
    @property
    def area(self) -> float:
        """Electrode area ``length * width``, m^2."""
        return self.length * self.width

    @property
    def capacitance(self) -> float:
        """Film capacitance ``eps0 eps_r A / thickness``, F (about 13.8 pF by default)."""
        return EPSILON_0 * self.eps_r * self.area / self.thickness

    @property
    def charge_sensitivity(self) -> float:
        """Charge per pascal of load, ``q = A (d31 l1 + d32 l2 + d33 l3)``, C/Pa."""
        l1, l2, l3 = self.load
        return self.area * (self.d31 * l1 + self.d32 * l2 + self.d33 * l3)

    @property
    def fc(self) -> float:
        """Charge-amplifier corner ``1 / (2 pi Rf Cf)``, Hz."""
        return 1.0 / (2 * math.pi * self.Rf * self.Cf)

    @property
    def fd(self) -> float:
        """Differentiator roll-off corner ``1 / (2 pi Rs Cd)``, Hz."""
        return 1.0 / (2 * math.pi * self.Rs * self.Cd)

    @property
    def tau_d(self) -> float:
        """Differentiator time constant ``Rd Cd``, s."""
        return self.Rd * self.Cd

    @property
    def rate_gain(self) -> float:
        """Low-frequency sensitivity of ``v_out`` to the load rate, ``-q Rf``, V/(Pa/s)."""
        return -self.charge_sensitivity * self.Rf

    @property
    def rate2_gain(self) -> float:
        """Low-frequency sensitivity of ``u_out`` to the 2nd-order load rate,
        ``q Rf Rd Cd``, V/(Pa/s^2)."""
        return -self.rate_gain * self.tau_d

    # ------------------------------------------------------------------ charge
    def charge(self, stress: npt.ArrayLike) -> np.ndarray:
        """Charge on the strip from its strip-averaged normal stresses.

        Parameters
        ----------
        stress : array_like, shape (..., 3, n)
            ``s1`` (along the length), ``s2`` (along the width), ``s3`` (through the
            thickness), Pa, time on the last axis.

        Returns
        -------
        ndarray, shape (..., n)
            ``Q = A (d31 s1 + d32 s2 + d33 s3)``, C.
        """
        s = stress_array(stress)
        d = np.array([self.d31, self.d32, self.d33])
        return self.area * np.einsum("...kn,k->...n", s, d)

    def equivalent_load(self, stress: npt.ArrayLike) -> np.ndarray:
        """The load (Pa) that makes the same charge as ``stress``: ``Q / q``.

        ``stress`` as in :meth:`charge`; returns shape (..., n).
        """
        return self.charge(stress) / self.charge_sensitivity


    # ------------------------------------------------------------------ analog
    def zpk(self, output: str = "v") -> tuple[np.ndarray, np.ndarray, float]:
        """Analog zeros, poles (rad/s) and gain from the load (Pa) to an output (V).

        Parameters
        ----------
        output : {"v", "u"}
            ``"v"``: ``v_out``; ``"u"``: ``u_out``.

        Returns
        -------
        z, p : ndarray
        k : float
        """
        _check_output(output)
        q = self.charge_sensitivity
        w1 = 1.0 / (self.Rf * self.Cf)
        # v/lo = -q Rf s / (1 + s Rf Cf) = (-q / Cf) s / (s + w1)
        z = [0.0]
        p = [-w1]
        k = -q / self.Cf
        if output == "u":
            wd = 1.0 / (self.Rs * self.Cd)
            # u/v = -Rd Cd s / (1 + s Rs Cd) = (-Rd / Rs) s / (s + wd)
            z.append(0.0)
            p.append(-wd)
            k *= -self.Rd / self.Rs
        return np.array(z), np.array(p), float(k)

    def lti(self, output: str = "v") -> scipy.signal.ZerosPolesGain:
        """Analog transfer function load (Pa) -> ``v_out`` or ``u_out`` (V) as a
        :class:`scipy.signal.ZerosPolesGain`."""
        import scipy.signal

        return scipy.signal.ZerosPolesGain(*self.zpk(output))

    def response(self, f: npt.ArrayLike, output: str = "v") -> np.ndarray:
        """Complex analog frequency response at ``f`` (Hz, >= 0), V/Pa."""
        f = finite_array(f, "f")
        if np.any(f < 0):
            raise ValueError("f must be non-negative (Hz)")
        z, p, k = self.zpk(output)
        s = 2j * np.pi * f
        h = np.full(f.shape, k, dtype=complex)
        for zz in z:
            h = h * (s - zz)
        for pp in p:
            h = h / (s - pp)
        return h

    def gain(self, f: npt.ArrayLike, output: str = "v") -> np.ndarray:
        """Gain per the paper's Eq. (1): ``20 log10 |out / lo|``, dB re 1 V/Pa.

        Parameters
        ----------
        f : array_like
            Frequencies, Hz, >= 0 (the gain is -inf at 0).
        output : {"v", "u"}

        Returns
        -------
        ndarray, same shape as ``f``, dB.
        """
        with np.errstate(divide="ignore"):
            return 20.0 * np.log10(np.abs(self.response(f, output)))

    def slope(self, output: str = "v", band: tuple[float, float] = SLOPE_BAND, num: int = 201) -> float:
        """Gain slope over a band, dB/decade: the least-squares line through
        :meth:`gain` against ``log10 f`` at ``num`` log-spaced frequencies in ``band`` (Hz)."""
        f = _band_freqs(band, num)
        return float(np.polyfit(np.log10(f), self.gain(f, output), 1)[0])

    # ------------------------------------------------------------------ discrete
    def sos(self, fs: float, output: str = "v", method: str = "bilinear",
            prewarp: float | None = None) -> np.ndarray:
        """Second-order sections from the sampled load (Pa) to an output (V).

        Parameters
        ----------
        fs : float
            Sample rate, Hz.
        output : {"v", "u"}
        method : {"bilinear", "matched"}
            See the module notes for the comparison of both over the band.
        prewarp : float, optional
            Bilinear only: frequency (Hz, ``0 < prewarp < fs/2``) where the discrete
            response equals the analog one exactly. ``None`` (default): plain
            bilinear ``c = 2 fs``, exact at low frequency.

        Returns
        -------
        ndarray, shape (n_sections, 6)
        """
        import scipy.signal

        fs = sample_rate(fs)
        _check_output(output)
        if method not in _METHODS:
            raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
        z, p, k = self.zpk(output)
        if method == "bilinear":
            c = 2.0 * fs
            if prewarp is not None:
                f0 = float(prewarp)
                if not (math.isfinite(f0) and 0 < f0 < fs / 2):
                    raise ValueError(f"prewarp must lie in (0, fs/2) = (0, {fs / 2}) Hz, got {prewarp}")
                c = 2 * math.pi * f0 / math.tan(math.pi * f0 / fs)
            zd, pd, kd = scipy.signal.bilinear_zpk(z, p, k, c / 2.0)
        else:
            if prewarp is not None:
                raise ValueError("prewarp applies to method='bilinear' only")
            zd = np.exp(z / fs)
            pd = np.exp(p / fs)
            # match lim H(e^{jwT}) / (jw)^m with H(s) / s^m at w -> 0
            m = int(np.sum(z == 0))
            nz = zd[z != 0]
            g_dig = np.real(np.prod(1 - nz) / np.prod(1 - pd)) / fs**m
            kd = _low_frequency_gain_analog(z, p, k) / g_dig
        return scipy.signal.zpk2sos(zd, pd, kd)

    # ------------------------------------------------------------------ simulate
    def simulate(self, stress: npt.ArrayLike, fs: float, noise: float | tuple[float, float] = 0.0,
                 seed: int | np.random.Generator | None = None, method: str = "bilinear",
                 prewarp: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Run sampled strip stresses through the circuit.

        Parameters
        ----------
        stress : array_like, shape (..., 3, n)
            Strip-averaged normal stresses ``s1, s2, s3``, Pa, sampled at ``fs``,
            time on the last axis. The circuit starts at rest.
        fs : float
            Sample rate, Hz.
        noise : float or (float, float)
            Sensor noise, V rms, white and Gaussian, added to ``v_out`` and
            ``u_out`` (one value for both, or one each). Default 0.
        seed : int or numpy.random.Generator, optional
            Seed of the noise.
        method, prewarp
            Discretisation, as in :meth:`sos`.

        Returns
        -------
        v_out, u_out : ndarray, shape (..., n)
            Output voltages, V.
        """
        fs = sample_rate(fs)
        check_noise(noise)
        s = stress_array(stress)
        return self.stream(fs, s.shape[:-2], noise=noise, seed=seed, method=method, prewarp=prewarp).process(s)

    def stream(self, fs: float, channels: int | tuple[int, ...] = 1, noise: float | tuple[float, float] = 0.0,
               seed: int | np.random.Generator | None = None, method: str = "bilinear",
               prewarp: float | None = None) -> CircuitStream:
        """The circuit in streaming form, at rest: see :class:`CircuitStream`."""
        return CircuitStream(self, fs, channels, noise=noise, seed=seed, method=method, prewarp=prewarp)
