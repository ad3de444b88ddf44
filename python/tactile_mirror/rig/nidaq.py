"""NI-DAQmx adapters: the rig's acquisition and the stage's analog path on an NI device.

:class:`NiAnalogInput` is a :class:`~tactile_mirror.rig.daq.BlockSource`: a hardware-clocked,
continuous analog-input task with a DAQmx buffer, read in blocks; :class:`NiStageIO` is the
:class:`~tactile_mirror.rig.daq.StageIO` of :class:`~tactile_mirror.rig.analog_stage.AnalogStage`:
an on-demand analog-output task and an encoder counter-input task (X4 decoding, in counts);
:class:`NiDaq` puts the two together. They use the ``nidaqmx`` package (the ``nidaq`` extra),
imported when one is made; ``import tactile_mirror.rig.nidaq`` does not need it.

Buffer overflows. The input task overwrites unread samples when the host falls behind
(``OverwriteMode.OVERWRITE_UNREAD_SAMPLES``), so that the acquisition itself never stops for
it; the read that finds its samples overwritten (DAQmx error -200279) moves on to recent
samples, and the block it returns counts the samples in between in ``Block.lost`` (from the
task's read position, exact). An overflow the acquisition cannot go on from (the device's
FIFO, error -200010, -200361 and the like; the driver stopping the task) raises
:class:`~tactile_mirror.rig.daq.Overrun`.
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from tactile_mirror.checks import integer, real_number, sample_rate
from tactile_mirror.rig.daq import Block, InputChannel, Overrun

__all__ = ["ACQUISITION_STOPPED_CODES", "ENCODER_KINDS", "SAMPLES_NOT_YET_AVAILABLE", "SAMPLES_OVERWRITTEN",
           "NiAnalogInput", "NiDaq", "NiStageIO"]

#: DAQmx error of a read whose samples were overwritten in the buffer before it came
#: (``SAMPLES_NO_LONGER_AVAILABLE``): the samples are lost, the acquisition goes on.
SAMPLES_OVERWRITTEN = -200279

#: DAQmx error of a read that timed out (``SAMPLES_NOT_YET_AVAILABLE``).
SAMPLES_NOT_YET_AVAILABLE = -200284

#: DAQmx errors after which the acquisition has stopped with samples lost: the device's FIFO
#: overflowed (-200010, -200361, -209829), its A/D converter overran (-200019), the driver
#: stopped the task so as not to overwrite its buffers (-200222, -200613, -200283).
ACQUISITION_STOPPED_CODES = (-200010, -200361, -209829, -200019, -200222, -200613, -200283)

#: Encoder kinds of :class:`NiStageIO`: a linear scale or a rotary encoder (on a screw).
ENCODER_KINDS = ("linear", "angular")


def _terminal(constants, name: str):
    return {"default": constants.TerminalConfiguration.DEFAULT, "diff": constants.TerminalConfiguration.DIFF,
            "rse": constants.TerminalConfiguration.RSE, "nrse": constants.TerminalConfiguration.NRSE,
            "pseudo_diff": constants.TerminalConfiguration.PSEUDO_DIFF}[name]


class NiAnalogInput:
    """Hardware-clocked, continuous analog input in blocks (a
    :class:`~tactile_mirror.rig.daq.BlockSource`).

    Parameters
    ----------
    channels : sequence of InputChannel
        The inputs in the pipeline's order, each with its terminal (``physical``, e.g.
        ``"Dev1/ai0"``), range, terminal configuration and kind: PVDF channels are delivered
        in V, force channels in N (V times ``n_per_v``).
    fs : float
        Sample rate, Hz (the device's sample clock).
    block_size : int
        Samples per channel in each block.
    buffer_blocks : int
        The DAQmx buffer, in blocks (default 100: 1 s at 1 kHz and 10 samples a block): how
        far behind the host may fall before samples are lost.
    task_name : str
        Name of the DAQmx task.
    """

    def __init__(self, channels: Sequence[InputChannel], fs: float, block_size: int, buffer_blocks: int = 100,
                 task_name: str = "tactile-mirror-ai"):
        import nidaqmx
        from nidaqmx import constants
        from nidaqmx.stream_readers import AnalogMultiChannelReader

        self.channels = tuple(channels)
        if not self.channels or not all(isinstance(c, InputChannel) for c in self.channels):
            raise TypeError("channels must be a non-empty sequence of InputChannel")
        missing = [c.name for c in self.channels if not c.physical]
        if missing:
            raise ValueError(f"channels {missing} have no physical terminal (e.g. 'Dev1/ai0')")
        self.fs = sample_rate(fs)
        self.block_size = integer(block_size, "block_size", 1)
        self.n_inputs = len(self.channels)
        self.buffer_size = self.block_size * integer(buffer_blocks, "buffer_blocks", 2)
        self._constants = constants
        self._scale = np.array([c.scale for c in self.channels], dtype=np.float64)
        task = nidaqmx.Task(task_name)
        try:
            for c in self.channels:
                task.ai_channels.add_ai_voltage_chan(c.physical, name_to_assign_to_channel=c.name,
                                                     terminal_config=_terminal(constants, c.terminal),
                                                     min_val=c.v_range[0], max_val=c.v_range[1])
            task.timing.cfg_samp_clk_timing(self.fs, sample_mode=constants.AcquisitionType.CONTINUOUS,
                                            samps_per_chan=self.buffer_size)
            task.in_stream.input_buf_size = self.buffer_size
            task.in_stream.overwrite = constants.OverwriteMode.OVERWRITE_UNREAD_SAMPLES
            task.in_stream.relative_to = constants.ReadRelativeTo.CURRENT_READ_POSITION
            task.in_stream.offset = 0
        except BaseException:
            task.close()
            raise
        self._task = task
        self._reader = AnalogMultiChannelReader(task.in_stream)
        self._buf = np.zeros((self.n_inputs, self.block_size), dtype=np.float64)
        self._next = 0          # index of the next sample expected
        self.lost_samples = 0
        self.overruns = 0
        self.blocks = 0
        self._running = False

    def start(self) -> None:
        """Start the acquisition (the sample clock)."""
        self._task.start()
        self._running = True

    def read_block(self, timeout: float = 1.0) -> Block:
        """The next ``block_size`` samples per channel, waiting up to ``timeout`` s for them
        (TimeoutError after that, nothing consumed). Samples overwritten before this read are
        counted in ``Block.lost``; an acquisition that stopped raises Overrun."""
        from nidaqmx.errors import DaqError

        timeout = real_number(timeout, "timeout", unit="s", nonnegative=True)
        if not self._running:
            raise RuntimeError("start() the acquisition before reading blocks")
        n = self.block_size
        stream = self._task.in_stream
        deadline = time.monotonic() + timeout
        try:
            while True:   # wait until the block is in the buffer: a read never returns part of one
                avail = stream.avail_samp_per_chan
                if avail >= n:
                    break
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no block of {n} samples within {timeout:g} s ({avail} acquired)")
                time.sleep(min(left, max((n - avail) / self.fs, 1e-4)))
            try:
                self._reader.read_many_sample(self._buf, number_of_samples_per_channel=n,
                                              timeout=max(timeout, 0.1))
            except DaqError as exc:
                if exc.error_code != SAMPLES_OVERWRITTEN:
                    raise
                self._resume_after_overwrite(n)
            end = stream.curr_read_pos          # samples read since the start
            backlog = stream.total_samp_per_chan_acquired - end
        except DaqError as exc:
            if exc.error_code == SAMPLES_NOT_YET_AVAILABLE:
                raise TimeoutError(f"no block of {n} samples within {timeout:g} s: {exc}") from exc
            if exc.error_code in ACQUISITION_STOPPED_CODES:
                self._running = False
                raise Overrun(f"the acquisition stopped with samples lost (DAQmx error {exc.error_code}) "
                              f"after sample {self._next}: {exc}", code=exc.error_code,
                              index=self._next) from exc
            raise
        t_ns = time.monotonic_ns() - round(backlog * 1e9 / self.fs)  # the newest sample is about now
        first = int(end) - n
        lost = max(first - self._next, 0)
        self._next = first + n
        self.blocks += 1
        if lost:
            self.lost_samples += lost
            self.overruns += 1
        samples = np.multiply(self._buf.T, self._scale, order="C")   # (n, n_inputs), rows contiguous
        return Block(samples=samples, index=first, lost=lost, t_ns=int(t_ns))

    def _resume_after_overwrite(self, n: int) -> None:
        """Read the block from the recent samples, half a buffer behind the newest (so that
        the next reads are not overwritten at once), then go on from there."""
        c = self._constants
        stream = self._task.in_stream
        keep = max(n, (self.buffer_size // 2) // n * n)
        stream.relative_to = c.ReadRelativeTo.MOST_RECENT_SAMPLE
        stream.offset = -keep
        try:
            self._reader.read_many_sample(self._buf, number_of_samples_per_channel=n, timeout=1.0)
        finally:
            stream.relative_to = c.ReadRelativeTo.CURRENT_READ_POSITION
            stream.offset = 0

    def stop(self) -> None:
        """Stop the acquisition."""
        if self._running:
            self._running = False
            self._task.stop()

    def close(self) -> None:
        """Stop and release the task."""
        try:
            self.stop()
        finally:
            self._task.close()


class NiStageIO:
    """The stage's analog path on an NI device (a :class:`~tactile_mirror.rig.daq.StageIO`):
    an on-demand analog output and an encoder counter read on demand.

    Parameters
    ----------
    ao : str
        The analog output's terminal, e.g. ``"Dev1/ao0"``.
    counter : str
        The counter, e.g. ``"Dev1/ctr0"`` (its A, B inputs on the device's default terminals).
    encoder : {"linear", "angular"}
        A linear scale (``add_ci_lin_encoder_chan``) or a rotary encoder
        (``add_ci_ang_encoder_chan``); either way X4 decoding and counts (``TICKS``): the
        scale to metres is :class:`~tactile_mirror.rig.analog_stage.AnalogStage`'s
        ``counts_per_m``.
    ao_range : (float, float)
        The output's range, V.
    idle_volts : float or None
        What the output is set to when the tasks start and when they close, V (0: the stop of
        a velocity command). None: it is left as it is; an amplifier taking a position
        command holds where its last command put it (0 V would be a position, a move).
    """

    def __init__(self, ao: str, counter: str, encoder: str = "linear",
                 ao_range: tuple[float, float] = (-10.0, 10.0), task_name: str = "tactile-mirror-stage",
                 idle_volts: float | None = 0.0):
        import nidaqmx
        from nidaqmx import constants

        if encoder not in ENCODER_KINDS:
            raise ValueError(f"encoder must be one of {ENCODER_KINDS}, got {encoder!r}")
        lo, hi = (real_number(v, "ao_range", unit="V") for v in ao_range)
        if not lo < 0.0 < hi:
            raise ValueError(f"ao_range must contain 0 V, got {ao_range!r}")
        self.ao_range = (lo, hi)
        self.encoder = encoder
        if idle_volts is not None:
            idle_volts = real_number(idle_volts, "idle_volts", unit="V")
            if not lo <= idle_volts <= hi:
                raise ValueError(f"idle_volts must lie in the output's range [{lo:g}, {hi:g}] V, got {idle_volts!r}")
        self.idle_volts = idle_volts
        self._ao = nidaqmx.Task(f"{task_name}-ao")
        self._ci = None
        try:
            self._ao.ao_channels.add_ao_voltage_chan(ao, min_val=lo, max_val=hi)
            self._ci = nidaqmx.Task(f"{task_name}-ci")
            if encoder == "linear":
                self._ci.ci_channels.add_ci_lin_encoder_chan(counter, decoding_type=constants.EncoderType.X_4,
                                                             units=constants.LengthUnits.TICKS)
            else:
                self._ci.ci_channels.add_ci_ang_encoder_chan(counter, decoding_type=constants.EncoderType.X_4,
                                                             units=constants.AngleUnits.TICKS)
            # started once: each write and read is then a single driver call
            self._ao.start()
            self._ci.start()
            if idle_volts is not None:
                self._ao.write(idle_volts)
        except BaseException:
            self._close_tasks()
            raise

    def write_ao(self, volts: float) -> None:
        """Set the output to ``volts`` now (V; ValueError outside :attr:`ao_range`, nothing written)."""
        v = real_number(volts, "volts", unit="V")
        lo, hi = self.ao_range
        if not lo <= v <= hi:
            raise ValueError(f"volts must lie in the analog output's range [{lo:g}, {hi:g}] V, got {volts!r}")
        self._ao.write(v)

    def read_counter(self) -> tuple[int, int]:
        """The encoder count now (X4 counts) and the ``monotonic_ns`` time of the read."""
        count = self._ci.read()
        t_ns = time.monotonic_ns()
        if not math.isfinite(count):
            raise ValueError(f"the counter returned {count!r}")
        return int(round(count)), t_ns

    def close(self) -> None:
        """Write :attr:`idle_volts` (unless None), then stop and release both tasks."""
        try:
            if self.idle_volts is not None:
                self._ao.write(self.idle_volts)
        finally:
            self._close_tasks()

    def _close_tasks(self) -> None:
        error = None
        for task in (self._ao, self._ci):
            if task is None:
                continue
            for step in (task.stop, task.close):
                try:
                    step()
                except Exception as exc:  # (release the other task too, then raise the first)
                    error = error or exc
        if error is not None:
            raise error


class NiDaq:
    """An NI device as the rig's :class:`~tactile_mirror.rig.daq.Daq`: its analog input in
    blocks and the stage's analog output and counter."""

    def __init__(self, analog_input: NiAnalogInput, stage_io: NiStageIO):
        self._input = analog_input
        self._io = stage_io
        self.ao_range = stage_io.ao_range

    @property
    def analog_input(self) -> NiAnalogInput:
        return self._input

    def write_ao(self, volts: float) -> None:
        self._io.write_ao(volts)

    def read_counter(self) -> tuple[int, int]:
        return self._io.read_counter()

    def close(self) -> None:
        """0 V on the output, then release the counter, the output and the input."""
        try:
            self._io.close()
        finally:
            self._input.close()
