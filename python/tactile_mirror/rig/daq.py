"""Acquisition on the rig: clocked blocks of samples in, one analog output and one encoder
counter for the stage.

A :class:`BlockSource` delivers the pipeline's inputs in blocks of ``block_size`` samples
(:class:`Block`), paced by the acquisition's own sample clock: ``read_block`` waits until
the next block has been acquired. A source that was not read in time loses its oldest
samples and says so (``Block.lost``), it never hides a gap. :class:`StageIO` is the stage's
analog path on the same device (:class:`~tactile_mirror.rig.analog_stage.AnalogStage`): one
analog-output value written per tick, one encoder-counter value read per tick. :class:`Daq`
is the two together, one device.

Implementations: the NI-DAQmx adapters of :mod:`tactile_mirror.rig.nidaq`, and the simulated
rig's shared memory (:mod:`tactile_mirror.rig.sim.daq_shm`).

Units: samples in the pipeline's units (PVDF outputs V, forces N), the analog output in V,
the counter in counts, times from ``time.monotonic_ns()`` (one clock every process shares).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from tactile_mirror.checks import real_number

__all__ = ["INPUT_KINDS", "TERMINAL_CONFIGS", "Block", "BlockSource", "Daq", "InputChannel", "Overrun",
           "StageIO", "input_names"]

#: Kinds of analog input: ``"pvdf"`` (a PVDF circuit's output, read in V as it is) and
#: ``"force"`` (a force sensor's amplifier output, V times its N/V scale).
INPUT_KINDS = ("pvdf", "force")

#: Terminal configurations of an analog input (``"default"``: the device's own).
TERMINAL_CONFIGS = ("default", "diff", "rse", "nrse", "pseudo_diff")


@dataclass(frozen=True)
class Block:
    """One block of samples from a :class:`BlockSource`.

    Attributes
    ----------
    samples : ndarray, float64, shape (block_size, n_inputs)
        One row per sample, in the pipeline's units (PVDF outputs V, forces N).
    index : int
        Index of its first sample since the acquisition started.
    lost : int
        Samples lost between the previous block returned and this one (the source was not
        read in time and its buffer overflowed): ``index`` of this block minus the end of
        the previous one. 0 when nothing was lost.
    t_ns : int
        ``time.monotonic_ns()`` time of its last sample.
    """

    samples: np.ndarray
    index: int
    lost: int
    t_ns: int


class Overrun(RuntimeError):
    """The acquisition stopped because samples were lost in a way it cannot go on from (a
    device-side FIFO overflow, an acquisition the driver stopped): the run must end.

    A buffer that was merely not read in time is not this: the next :class:`Block` reports
    its ``lost`` samples and the acquisition goes on.

    Attributes
    ----------
    code : int or None
        The driver's error code, if it gave one.
    index : int
        Index of the first sample that was not delivered.
    """

    def __init__(self, message: str, code: int | None = None, index: int = 0):
        super().__init__(message)
        self.code = code
        self.index = int(index)


@runtime_checkable
class BlockSource(Protocol):
    """Clocked acquisition in blocks.

    ``fs`` (Hz), ``n_inputs`` and ``block_size`` are fixed at construction. :meth:`start`
    starts the sample clock; :meth:`read_block` returns the next :class:`Block`, waiting
    until it has been acquired, and raises ``TimeoutError`` after ``timeout`` s without it;
    :meth:`stop` stops the acquisition; :meth:`close` releases the device (after a stop).
    """

    fs: float
    n_inputs: int
    block_size: int

    def start(self) -> None: ...

    def read_block(self, timeout: float) -> Block: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...


@runtime_checkable
class StageIO(Protocol):
    """The stage's analog path: one analog output and one encoder counter, on demand.

    :meth:`write_ao` sets the output now (V, within ``ao_range``; ValueError outside it, and
    nothing is written); :meth:`read_counter` returns the encoder count now and the
    ``time.monotonic_ns()`` time it holds for. Both are called once per tick and return
    within a bounded time.
    """

    ao_range: tuple[float, float]

    def write_ao(self, volts: float) -> None: ...

    def read_counter(self) -> tuple[int, int]: ...


@runtime_checkable
class Daq(StageIO, Protocol):
    """One acquisition device: analog input in blocks (:attr:`analog_input`), the stage's
    analog output and encoder counter (:class:`StageIO`); :meth:`close` writes 0 V to the
    output and releases the device."""

    @property
    def analog_input(self) -> BlockSource: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class InputChannel:
    """One analog input of the acquisition: where it is wired and how its volts become the
    pipeline's input.

    Attributes
    ----------
    name : str
        Name of the input (e.g. ``"v_out_0L"``, ``"force_y"``; :func:`input_names`).
    physical : str
        The device's terminal (e.g. ``"Dev1/ai0"``); empty where there is no device.
    kind : str
        ``"pvdf"``: the input is a PVDF circuit's output, delivered in V as read;
        ``"force"``: a force sensor's amplifier output, delivered in N (V times ``n_per_v``).
    n_per_v : float or None
        Force channels: the amplifier's scale, N/V (from its setting, never guessed; the sign
        gives the direction). None for PVDF channels.
    v_range : (float, float)
        Expected input range, V (the A/D range the device picks).
    terminal : str
        Terminal configuration, one of :data:`TERMINAL_CONFIGS`.
    """

    name: str
    physical: str = ""
    kind: str = "pvdf"
    n_per_v: float | None = None
    v_range: tuple[float, float] = (-10.0, 10.0)
    terminal: str = "default"

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"name must be a non-empty string, got {self.name!r}")
        if not isinstance(self.physical, str):
            raise TypeError(f"physical must be a string (a terminal such as 'Dev1/ai0'), "
                            f"got {self.physical!r}")
        if self.kind not in INPUT_KINDS:
            raise ValueError(f"kind of input {self.name!r} must be one of {INPUT_KINDS}, got {self.kind!r}")
        if self.kind == "force":
            if self.n_per_v is None:
                raise ValueError(f"force input {self.name!r} needs its amplifier's scale n_per_v (N/V)")
            k = real_number(self.n_per_v, f"n_per_v of {self.name!r}", unit="N/V")
            if k == 0:
                raise ValueError(f"n_per_v of {self.name!r} must not be 0 N/V")
            object.__setattr__(self, "n_per_v", k)
        elif self.n_per_v is not None:
            raise ValueError(f"PVDF input {self.name!r} is read in V: n_per_v must be None, "
                             f"got {self.n_per_v!r}")
        try:
            lo, hi = (real_number(v, f"v_range of {self.name!r}", unit="V") for v in self.v_range)
        except (TypeError, ValueError) as exc:
            raise type(exc)(f"v_range of {self.name!r} must be a pair (low, high) of volts, got "
                            f"{self.v_range!r}") from exc
        if not lo < hi:
            raise ValueError(f"v_range of {self.name!r} must have low < high, got {self.v_range!r}")
        object.__setattr__(self, "v_range", (lo, hi))
        if self.terminal not in TERMINAL_CONFIGS:
            raise ValueError(f"terminal of {self.name!r} must be one of {TERMINAL_CONFIGS}, "
                             f"got {self.terminal!r}")

    @property
    def scale(self) -> float:
        """The pipeline's unit per V: 1 for a PVDF input, ``n_per_v`` for a force input."""
        return 1.0 if self.kind == "pvdf" else float(self.n_per_v)


def input_names(n_ridges: int, force: bool = True) -> tuple[str, ...]:
    """Names of the pipeline's inputs on the rig, in its order: ``v_out`` of every strip
    (ridge ``r``, strips ``L`` and ``R``: ``v_out_0L, v_out_0R, v_out_1L, ...``), then
    ``u_out`` likewise, then (``force``) the force sensor's ``force_y`` and ``force_z``."""
    from tactile_mirror.checks import integer

    n_ridges = integer(n_ridges, "n_ridges", 1)
    strips = [f"{r}{side}" for r in range(n_ridges) for side in "LR"]
    names = [f"v_out_{s}" for s in strips] + [f"u_out_{s}" for s in strips]
    return tuple(names + (["force_y", "force_z"] if force else []))
