"""The simulated rig: a separate process with the FEM pad and the stage in real time, serving the
stage's serial line on a pseudo-terminal and the acquisition channels as clocked blocks.

- :mod:`~tactile_mirror.rig.sim.daq_shm`: the simulated DAQ in shared memory (:class:`DaqRing`,
  the host's :class:`ShmBlockSource` and :class:`ShmDaq`);
- :mod:`~tactile_mirror.rig.sim.process`: the process (:class:`SimulatedRig`,
  :class:`SimRigConfig`, its log :class:`SimRigLog`, the axis hook :class:`SimAxis`).
- :mod:`~tactile_mirror.rig.sim.serial_axis`: :class:`SerialAxis`, a simulated stage controller
  speaking a command dialect on a pseudo-terminal, paced at the line's baud rate.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from tactile_mirror._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "DaqRing": "daq_shm", "ShmBlockSource": "daq_shm", "ShmDaq": "daq_shm",
    "AnalogAxis": "process", "SimAxis": "process", "SimRigConfig": "process", "SimRigLog": "process",
    "SimulatedRig": "process",
    "SerialAxis": "serial_axis",
})

if TYPE_CHECKING:
    from tactile_mirror.rig.sim.daq_shm import DaqRing, ShmBlockSource, ShmDaq
    from tactile_mirror.rig.sim.process import AnalogAxis, SimAxis, SimRigConfig, SimRigLog, SimulatedRig
    from tactile_mirror.rig.sim.serial_axis import SerialAxis
