"""The mirror on a real rig: clocked acquisition in blocks, stage drivers that never block the
loop, and a simulated rig that stands in for the hardware.

- :mod:`~tactile_mirror.rig.daq`: blocks of samples (:class:`Block`), the :class:`BlockSource`
  and :class:`Daq` protocols, the analog inputs' map (:class:`InputChannel`);
- :mod:`~tactile_mirror.rig.analog_stage`: the stage on the DAQ's analog output and encoder
  counter (:class:`AnalogStage`);
- :mod:`~tactile_mirror.rig.nidaq`: the NI-DAQmx adapters;
- :mod:`~tactile_mirror.rig.stage`: the :class:`StageDriver` protocol and the soft-limit checks;
- :mod:`~tactile_mirror.rig.dialects`: controller command dialects as data (:class:`Dialect`,
  :data:`PI_GCS2`, :data:`ZABER_ASCII`);
- :mod:`~tactile_mirror.rig.serial_stage`: :class:`SerialStage`, a stage driver over a serial line;
- :mod:`~tactile_mirror.rig.config`: the rig's TOML configuration (:func:`load_config`, :class:`RigConfig`);
- :mod:`~tactile_mirror.rig.session`: a rig opened from it, on the devices or simulated (:class:`RigSession`);
- :mod:`~tactile_mirror.rig.supervisor`: the safety supervisor (:class:`Supervisor`, :class:`RigError`);
- :mod:`~tactile_mirror.rig.runner`: the loop paced by the acquisition (:class:`RigRunner`, :class:`RigResult`);
- :mod:`~tactile_mirror.rig.bringup`: bring-up on the rig, to a designed law (:func:`bring_up`);
- :mod:`~tactile_mirror.rig.realtime`: the garbage collector off during a run (:func:`gc_paused`)
  and a higher scheduling priority where permitted (:func:`raised_priority`);
- :mod:`~tactile_mirror.rig.sim`: the simulated rig.

Nothing here is imported by ``import tactile_mirror``; pyserial and nidaqmx (the optional
extras ``rig`` and ``nidaq``) load inside the drivers that use them.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from tactile_mirror._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "Block": "daq", "BlockSource": "daq", "Daq": "daq", "InputChannel": "daq", "Overrun": "daq",
    "StageIO": "daq", "input_names": "daq",
    "AnalogStage": "analog_stage",
    "NiAnalogInput": "nidaq", "NiDaq": "nidaq", "NiStageIO": "nidaq",
    "COMMAND_MODES": "stage", "StageDriver": "stage", "check_reading": "stage", "check_target": "stage",
    "DIALECTS": "dialects", "PI_GCS2": "dialects", "ZABER_ASCII": "dialects", "ControllerError": "dialects",
    "Dialect": "dialects", "ReplyError": "dialects",
    "SerialStage": "serial_stage",
    "ConfigError": "config", "RigConfig": "config", "load_config": "config", "parse_config": "config",
    "RigSession": "session", "RigError": "supervisor", "Supervisor": "supervisor", "Trip": "supervisor",
    "RigResult": "runner", "RigRunner": "runner", "BringUpResult": "bringup", "bring_up": "bringup",
    "gc_paused": "realtime", "raised_priority": "realtime",
})

if TYPE_CHECKING:
    from tactile_mirror.rig.analog_stage import AnalogStage
    from tactile_mirror.rig.bringup import BringUpResult, bring_up
    from tactile_mirror.rig.config import ConfigError, RigConfig, load_config, parse_config
    from tactile_mirror.rig.daq import Block, BlockSource, Daq, InputChannel, Overrun, StageIO, input_names
    from tactile_mirror.rig.dialects import (
        DIALECTS,
        PI_GCS2,
        ZABER_ASCII,
        ControllerError,
        Dialect,
        ReplyError,
    )
    from tactile_mirror.rig.nidaq import NiAnalogInput, NiDaq, NiStageIO
    from tactile_mirror.rig.realtime import gc_paused, raised_priority
    from tactile_mirror.rig.runner import RigResult, RigRunner
    from tactile_mirror.rig.serial_stage import SerialStage
    from tactile_mirror.rig.session import RigSession
    from tactile_mirror.rig.stage import COMMAND_MODES, StageDriver, check_reading, check_target
    from tactile_mirror.rig.supervisor import RigError, Supervisor, Trip
