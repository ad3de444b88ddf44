"""The simulated rig: a separate process with the FEM pad and the stage in real time, serving the
stage's serial line on a pseudo-terminal and the acquisition channels as clocked blocks.

- :mod:`~tactile_mirror.rig.sim.daq_shm`: the simulated DAQ in shared memory (:class:`DaqRing`,
  the host's :class:`ShmBlockSource` and :class:`ShmDaq`);
- :mod:`~tactile_mirror.rig.sim.config`: its settings (:class:`SimRigConfig`), its log
  (:class:`SimRigLog`), the faults it can make (:data:`FAULTS`);
- :mod:`~tactile_mirror.rig.sim.axis`: the axis hook (:class:`SimAxis`) and the analog path's
  axis (:class:`AnalogAxis`);
- :mod:`~tactile_mirror.rig.sim.process`: the process (:class:`SimulatedRig`);
- :mod:`~tactile_mirror.rig.sim.serial_axis`: :class:`SerialAxis`, a simulated stage controller
  speaking a command dialect on a pseudo-terminal, paced at the line's baud rate;
- :mod:`~tactile_mirror.rig.sim.serial_path`: the simulated rig's serial path, its controller in
  a process of its own (:class:`SerialPathAxis`, the ``axis_factory``
  :func:`~tactile_mirror.rig.sim.serial_path.serial_axis`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from tactile_mirror._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "DaqRing": "daq_shm", "ShmBlockSource": "daq_shm", "ShmDaq": "daq_shm",
    "FAULTS": "config", "SimRigConfig": "config", "SimRigLog": "config",
    "AnalogAxis": "axis", "SimAxis": "axis",
    "SimulatedRig": "process",
    "SerialAxis": "serial_axis", "SerialPathAxis": "serial_path",
})

if TYPE_CHECKING:
    from tactile_mirror.rig.sim.axis import AnalogAxis, SimAxis
    from tactile_mirror.rig.sim.config import FAULTS, SimRigConfig, SimRigLog
    from tactile_mirror.rig.sim.daq_shm import DaqRing, ShmBlockSource, ShmDaq
    from tactile_mirror.rig.sim.process import SimulatedRig
    from tactile_mirror.rig.sim.serial_axis import SerialAxis
    from tactile_mirror.rig.sim.serial_path import SerialPathAxis
