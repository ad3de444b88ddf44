"""A rig built from its configuration: the acquisition, the stage driver, the amplifiers' reset.

:class:`RigSession` opens what a :class:`~tactile_mirror.rig.config.RigConfig` describes, on
the hardware (NI-DAQmx, a serial port) or, with ``simulate=True``, on the simulated rig
(:class:`~tactile_mirror.rig.sim.process.SimulatedRig`): the simulation stands in for the
devices and nothing else, the drivers, the supervisor and the runner are the same.
:func:`simulated_rig_config` is what the simulated rig is told (the same sample clock,
channels, scales, limits and watchdog as the file, the finger of ``[simulation]``).
"""
from __future__ import annotations

import time

from tactile_mirror.rig.config import RigConfig

__all__ = ["RigSession", "simulated_rig_config"]


def simulated_rig_config(config: RigConfig, **overrides):
    """The :class:`~tactile_mirror.rig.sim.config.SimRigConfig` standing in for the rig of
    ``config``; ``overrides`` replace its fields (e.g. ``duration``, ``buffer_blocks``)."""
    from tactile_mirror.loop.stage import StageLimits
    from tactile_mirror.noise import SensorNoise
    from tactile_mirror.rig.sim.config import SimRigConfig

    sim, stage, acq = config.simulation, config.stage, config.acquisition
    a = config.analog or {}
    lo, hi = sim["travel"]
    kw = {"fs": acq["fs"], "block_size": acq["block_size"], "buffer_blocks": acq["buffer_blocks"],
          "n_ridges": config.n_ridges, "plant": sim["plant"], "mu": sim["mu"], "seed": sim["seed"],
          "duration": sim["finger_duration"], "finger_wait": True,
          "trajectory": {"amplitude": sim["finger_amplitude"], "bandwidth": sim["finger_bandwidth"],
                         "v_max": sim["finger_speed"], "a_max": sim["finger_a_max"]},
          "noise": SensorNoise(circuit=config.circuit(), hum=sim["hum"]), "circuit": dict(config.front_end) or None,
          "force_noise": sim["force_noise"], "limits": StageLimits(lo, hi, stage["v_max"], stage["a_max"]),
          "lag": stage["lag"], "x0": sim["x0"], "lead": sim["lead"], "watchdog": config.safety["watchdog"],
          "rt_priority": sim["rt_priority"]}
    if config.stage["kind"] == "analog":
        kw.update(ao_mode=a["mode"], counts_per_m=a["counts_per_m"], ao_range=a["ao_range"],
                  volts_offset=a["volts_offset"])
        kw["volts_per_m" if a["mode"] == "position" else "volts_per_m_s"] = a["volts_per_m"] or a["volts_per_m_s"]
    else:
        kw.update(_serial_axis(config))
    kw.update(overrides)
    return SimRigConfig(**kw)


def _serial_axis(config: RigConfig) -> dict:
    """The simulated rig's settings for a serial controller's axis (its dialect on a pty)."""
    from tactile_mirror.rig.sim.serial_path import serial_path_options

    s = config.serial
    baud = config.simulation["baud"] or s["baud"]
    return serial_path_options(s["generic"] if s["dialect"] == "generic" else s["dialect"], s["units_per_m"], baud,
                               s["axis"], s["device"], processing=config.simulation["processing"])


class RigSession:
    """The rig of a configuration, opened (:meth:`open`) and closed (:meth:`close`).

    Attributes (after :meth:`open`)
    -------------------------------
    source : BlockSource
        The acquisition (not yet started: :meth:`start_acquisition`).
    stage : StageDriver
    sim : SimulatedRig or None
        The simulated rig (``simulate=True``).
    sim_log : SimRigLog or None
        Its log, after :meth:`close`.
    """

    def __init__(self, config: RigConfig, simulate: bool = False, prompt=None, **sim_overrides):
        if not isinstance(config, RigConfig):
            raise TypeError(f"config must be a RigConfig, got {type(config).__name__}")
        self.config = config
        self.simulate = bool(simulate)
        self.sim_overrides = sim_overrides
        self.prompt = prompt if prompt is not None else input
        self.sim = None
        self.sim_log = None
        self.daq = None
        self.source = None
        self.stage = None
        self._started = False
        self._stage_started = False

    # ------------------------------------------------------------------ open, close
    def open(self) -> RigSession:
        """Connect: the acquisition (not started), the stage driver. Nothing moves."""
        c = self.config
        try:
            if self.simulate:
                from tactile_mirror.rig.sim.process import SimulatedRig

                self.sim = SimulatedRig(simulated_rig_config(c, **self.sim_overrides)).start()
                self.daq = self.sim.daq
                if c.stage["kind"] == "analog" and c.analog["mode"] == "position":
                    self.daq.idle_volts = None
            elif c.stage["kind"] == "analog":
                from tactile_mirror.rig.nidaq import NiAnalogInput, NiDaq, NiStageIO

                a, dev = c.analog, c.acquisition["device"]
                ai = NiAnalogInput(c.channels, c.fs, c.block_size, c.acquisition["buffer_blocks"])
                # a position command's 0 V is a position: the output is left as the amplifier holds it
                io = NiStageIO(_terminal(a["ao"], dev), _terminal(a["counter"], dev), a["encoder"], a["ao_range"],
                               idle_volts=None if a["mode"] == "position" else 0.0)
                self.daq = NiDaq(ai, io)
            else:
                from tactile_mirror.rig.nidaq import NiAnalogInput

                self.daq = None
                self.source = NiAnalogInput(c.channels, c.fs, c.block_size, c.acquisition["buffer_blocks"])
            if self.daq is not None:
                self.source = self.daq.analog_input
            self.stage = self._stage()
        except BaseException:
            self.close()
            raise
        return self

    def _stage(self):
        c = self.config
        if c.stage["kind"] == "analog":
            from tactile_mirror.rig.analog_stage import AnalogStage

            a = c.analog
            kw = ({"volts_per_m": a["volts_per_m"], "volts_offset": a["volts_offset"]} if a["mode"] == "position"
                  else {"volts_per_m_s": a["volts_per_m_s"]})
            return AnalogStage(self.daq, c.limits, a["counts_per_m"], mode=a["mode"], gain=a["gain"],
                               offset=a["offset"], **kw)
        from tactile_mirror.rig.serial_stage import SerialStage
        from tactile_mirror.rig.sim.serial_path import make_dialect

        s = c.serial
        port = self.sim.axis_info["port"] if self.sim is not None else s["port"]
        dialect = make_dialect(s["generic"] if s["dialect"] == "generic" else s["dialect"], s["units_per_m"],
                               s["axis"], s["device"])
        return SerialStage(port, dialect, c.limits, baudrate=s["baud"], timeout=s["timeout"],
                           reply_overdue=s["reply_overdue"], target_age=s["target_age"],
                           position_margin=c.safety["position_margin"])

    def start_stage(self) -> None:
        """Start the stage driver's own I/O (a serial driver's thread: it reads the position
        from then on; before it, bring-up's enable and home); nothing for a driver without."""
        start = getattr(self.stage, "start", None)
        if start is not None and not self._stage_started:
            start()
        self._stage_started = True

    def start_acquisition(self) -> None:
        """Start the sample clock (once)."""
        if not self._started:
            self.source.start()
            self._started = True

    def close(self) -> list[str]:
        """Stop the stage, release the stage's port and the DAQ, end the simulated rig (its
        log in :attr:`sim_log`). Returns what failed on the way, in words (each step is
        tried)."""
        problems = []
        for what, step in (("stage", getattr(self.stage, "close", None)), ("acquisition", getattr(
                self.daq if self.daq is not None else self.source, "close", None))):
            if step is None:
                continue
            try:
                step()
            except Exception as exc:  # noqa: BLE001 (release the rest too)
                problems.append(f"closing the {what}: {type(exc).__name__}: {exc}")
        self.stage = None
        if self.sim is not None:
            self.sim_log = self.sim.stop()
            if self.sim.error:
                problems.append(f"the simulated rig failed:\n{self.sim.error}")
        return problems

    def __enter__(self) -> RigSession:
        return self.open() if self.source is None else self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ what bring-up asks of the rig
    def reset_amplifiers(self, log=print) -> str:
        """Reset (tare) the charge amplifiers, as ``[amplifier_reset]`` says: the simulated
        rig's reset; a DAQ digital line pulsed high for ``pulse`` s (``"digital"``); the
        operator pressing the amplifiers' reset (``"manual"``: asked on the terminal);
        nothing (``"none"``). Returns what was done."""
        r = self.config.amplifier_reset
        if self.sim is not None:
            self.sim.reset_amplifiers()
            done = "simulated rig: amplifiers reset"
        elif r["kind"] == "digital":
            import nidaqmx

            line = _terminal(r["line"], self.config.acquisition["device"])
            with nidaqmx.Task("tactile-mirror-amp-reset") as task:
                task.do_channels.add_do_chan(line)
                task.write(True)
                time.sleep(r["pulse"])
                task.write(False)
            done = f"pulsed {line} for {r['pulse'] * 1e3:g} ms"
        elif r["kind"] == "manual":
            self.prompt("press the charge amplifiers' reset (PVDF and force), then Enter: ")
            done = "reset by the operator"
        else:
            done = "no reset (amplifier_reset.kind = 'none')"
        log(f"charge amplifiers: {done}")
        return done

    def place_finger(self, log=print) -> None:
        """The finger goes on the pad, and rests: the simulated finger is placed; on the rig,
        the operator is asked (and confirms with Enter)."""
        if self.sim is not None:
            self.sim.place_finger()
        else:
            self.prompt("place the finger on the pad and keep it still, then Enter: ")

    def start_finger(self, log=print) -> None:
        """The finger's part of the run begins: the simulated finger starts its path; on the
        rig, the operator is told."""
        if self.sim is not None:
            self.sim.start_finger()
        else:
            log("the loop is running: move the finger on the pad now")

    def adapters(self) -> dict:
        """What stands behind the acquisition and the stage, in words (for the recording)."""
        c = self.config
        where = "simulated rig (tactile_mirror.rig.sim)" if self.simulate else f"NI-DAQmx {c.acquisition['device']}"
        if c.stage["kind"] == "analog":
            a = c.analog
            stage = (f"AnalogStage ({a['mode']} command on {a['ao']}, encoder on {a['counter']}, "
                     f"{a['counts_per_m']:g} counts/m)")
        else:
            s = c.serial
            stage = f"SerialStage ({s['dialect']} at {s['baud']} baud, {s['units_per_m']:g} units/m)"
        return {"acquisition": f"{type(self.source).__name__} on {where}", "stage": f"{stage} on {where}",
                "simulated": self.simulate}


def _terminal(name: str, device: str) -> str:
    return name if "/" in name or not device else f"{device}/{name}"
