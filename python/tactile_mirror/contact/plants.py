"""Contact plants: the contact models the closed loop steps, behind one interface.

A plant (:class:`ContactPlant`) is a contact model stepped tick by tick with the
tangential displacement of the finger relative to the pad. Two plants exist:

* :class:`FemPad`: the FEM pad of this package (:class:`~tactile_mirror.contact.Pad`,
  plane-strain ridges with Coulomb friction) with a pressing finger;
* :class:`~tactile_mirror.contact.brush.BrushRidges`: a reduced quasi-static brush model
  of the same ridges (fast, for training and sweeps; not the FEM).

Units: displacements m, forces N, stresses Pa, friction coefficients dimensionless.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from tactile_mirror.circuit import PVDFCircuit

if TYPE_CHECKING:
    from tactile_mirror.contact.pad import Pad
    from tactile_mirror.geometry import RidgeGeometry

__all__ = ["REALTIME_CONTACT_MESH_SIZE", "ContactPlant", "ContactState", "FemPad"]

#: Contact-zone element size of :meth:`FemPad.realtime`, m (the default is 0.05 mm). The
#: cost of a tick grows with the contact nodes (their events and the size of the system
#: solved at each), while the strips' stress depends mostly on the mesh around them:
#: see :meth:`FemPad.realtime` for the figures.
REALTIME_CONTACT_MESH_SIZE = 0.2e-3


@dataclass
class ContactState:
    """What a plant reports after one step.

    Attributes
    ----------
    stress : ndarray, shape (n_ridges, 2)
        Equivalent load of the L and R strips (:meth:`PVDFCircuit.equivalent_load`), Pa.
    force_y : float
        Tangential force of the finger on the pad, N.
    force_z : float
        Normal (pressing) force, N.
    slip_fraction : ndarray, shape (n_ridges,)
        Share of each ridge's contact at the friction limit, in [0, 1].
    """

    stress: np.ndarray
    force_y: float
    force_z: float
    slip_fraction: np.ndarray


@runtime_checkable
class ContactPlant(Protocol):
    """The interface of a contact model in the loop.

    ``n_ridges`` ridges with two strips each; :meth:`advance` is called once per tick
    with the relative tangential displacement ``finger - pad`` (m) and returns the
    :class:`ContactState` of that tick. :meth:`reset` returns the contact to rest
    (unloaded, nothing slid). ``mu`` is the static friction coefficient now in force
    (a float, or one per ridge); :meth:`set_mu` changes it between ticks (e.g. sweat).
    """

    n_ridges: int

    @property
    def mu(self) -> float | np.ndarray: ...

    def set_mu(self, mu: npt.ArrayLike) -> None: ...

    def reset(self) -> None: ...

    def advance(self, dy: float) -> ContactState: ...


class FemPad:
    """The FEM pad of :mod:`tactile_mirror.contact` behind the plant interface.

    The finger first presses in (``indent`` reached at ``press_speed``, as in the paper's
    Fig. 5b), then holds that indent; :meth:`advance` takes the tangential relative
    displacement. Strip stresses become equivalent loads of the circuit
    (:meth:`PVDFCircuit.equivalent_load`).

    Parameters
    ----------
    n_ridges : int
        1 to :data:`~tactile_mirror.geometry.MAX_RIDGES` (64).
    mu : float, optional
        Static friction coefficient (default :data:`tactile_mirror.scenes.DEFAULT_FRICTION`);
        the kinetic one is ``mu * DEFAULT_KINETIC_RATIO``, as in the scenes.
    fs : float
        Tick rate, Hz (sets the press: ``press_speed / fs`` m of indent per tick).
    indent : float
        Final indent of the finger, m.
    press_speed : float
        Indent speed of the press, m/s.
    finger_radius : float
        Radius of the finger's curvature over the ridges, m.
    circuit : PVDFCircuit, optional
        Circuit whose load the strip stresses are expressed in (default ``PVDFCircuit()``).
    stepping : {"auto", "every"}
        Contact stepping of the pad (:class:`~tactile_mirror.contact.Pad`). The load comes
        tick by tick from the controller, so no tick knows the next: the path between
        two ticks is taken as straight and followed exactly with its events, and with
        ``"auto"`` a tick whose load does not move costs nothing (after the first such
        tick, which stops the sliding nodes) and a tick without a status change costs a
        few vector operations (the piece's unit responses).
    geometry : RidgeGeometry, optional
        Ridge geometry and mesh (default ``RidgeGeometry()``, the one the bundled detector
        and the loop's calibration were made with).
    threads : int
        Threads that step the ridges (:attr:`Pad.threads <tactile_mirror.contact.Pad>`; 1 or
        2, more count as 2): with 2 the ridges of a tick are shared with a second thread
        (the same results).
    """

    pad: Pad

    def __init__(self, n_ridges: int = 6, mu: float | None = None, fs: float = 1000.0, indent: float = 30e-6,
                 press_speed: float = 0.06e-3, finger_radius: float = 2.0, circuit: PVDFCircuit | None = None,
                 stepping: str = "auto", geometry: RidgeGeometry | None = None, threads: int = 1):
        from tactile_mirror.checks import integer
        from tactile_mirror.contact.model import ridge_model
        from tactile_mirror.contact.pad import MAX_RIDGES, Pad
        from tactile_mirror.scenes import DEFAULT_FRICTION, DEFAULT_KINETIC_RATIO

        # (before the ridge model is built; a float such as 6.7 was truncated to 6 ridges)
        self.n_ridges = integer(n_ridges, "n_ridges", 1, MAX_RIDGES)
        mu = DEFAULT_FRICTION if mu is None else float(mu)
        # static above kinetic friction, as in the scenes of tactile_mirror.scenes
        self.pad = Pad(ridge_model(geometry), mu, n_ridges=self.n_ridges, finger_radius=finger_radius,
                       mu_kinetic=mu * DEFAULT_KINETIC_RATIO, stepping=stepping, threads=threads)
        self.fs, self.indent, self.press_speed = float(fs), float(indent), float(press_speed)
        self.circuit = circuit or PVDFCircuit()
        self.reset()

    @classmethod
    def realtime(cls, n_ridges: int = 6, **kwargs) -> FemPad:
        """The FEM pad for a loop paced at 1 kHz: contact elements of
        :data:`REALTIME_CONTACT_MESH_SIZE` (41 contact nodes a ridge instead of 161); the
        rest of the mesh, and so the strips' stress, as the default.

        The worst case of the paced loop is the open loop: the finger slides over a pad
        that stands still, and the contact goes through breakaway cascades at every tick.
        Measured with ``python bench/bench_contact.py --realtime-only`` (nine runs, Intel
        Xeon, 2 cores), 6 ridges, the report paths at 5 / 20 mm/s, paced at 1 kHz, 3000
        ticks:

        * open loop: tick p99 202-257 / 274-332 us, 0-2 overruns; the default pad
          3.1-4.1 / 4.5-5.0 ms and 757-1241 overruns (2.5-2.8 / 3.4-3.7 ms with
          ``threads=2``);
        * closed loop, the default law: 0 gross slips, tick p99 77-119 / 78-130 us, no
          overrun (the default pad: 270-353 / 270-379 us, 5-11 overruns).

        What it gives up, against a pad with contact elements of 0.025 mm on the same
        open-loop paths (rms over the ticks and ridges, relative to the reference's peak):
        the strips' L - R stress 2.9 / 2.3 % (contact elements of 0.1 mm, 81 nodes: 1.9 /
        1.6 %; the default pad 1.0 / 0.7 %), the tangential force 0.31 / 0.20 % (0.15 /
        0.09 %; 0.06 / 0.05 %); the gross slips are the same (6 / 8). The plant alone at
        0.1 mm still takes 0.8 / 1.3 ms at p99 (``docs/figures/realtime_pad.png``). A
        second thread shortens this pad's slowest ticks by a sixth to a fifth (the plant
        alone, one run: p99 199 -> 165 us and 289 -> 232 us) but keeps the second core
        busy while it polls, so by default it runs on one (``threads=2`` to use both).
        Keyword arguments go to :class:`FemPad` (a ``geometry`` given there wins; None is
        this one's).
        """
        from tactile_mirror.geometry import RidgeGeometry

        if kwargs.get("geometry") is None:
            kwargs["geometry"] = RidgeGeometry(contact_mesh_size=REALTIME_CONTACT_MESH_SIZE)
        return cls(n_ridges, **kwargs)

    def reset(self) -> None:
        self.pad.reset()
        self.k = 0

    @property
    def mu(self) -> float:
        """Static friction coefficient now in force."""
        return self.pad.mu

    def set_mu(self, mu: npt.ArrayLike) -> None:
        """Set the static friction coefficient (the mean of ``mu`` if one per ridge)."""
        self.pad.mu = float(np.mean(np.asarray(mu, dtype=np.float64)))

    def advance(self, dy: float) -> ContactState:
        """One tick: relative displacement finger - pad ``dy`` (m) -> contact state."""
        self.k += 1
        z = min(self.indent, self.k * self.press_speed / self.fs)
        st = self.pad.advance(dy, z)
        load = self.circuit.equivalent_load(st.strip_stress[..., None])[..., 0]   # (R, 2)
        return ContactState(stress=load, force_y=st.force_y, force_z=st.force_z,
                            slip_fraction=np.asarray(st.slip_fraction, dtype=np.float64))
