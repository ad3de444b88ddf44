"""The simulated DAQ: blocks, the stage's analog output and its encoder count in shared memory.

One :class:`DaqRing` (a :class:`multiprocessing.shared_memory.SharedMemory` block) is written
by the simulated rig's process and read by the host:

* a ring of sample blocks, clocked by the wall clock: with ``t0`` the clock's start
  (``time.monotonic_ns()``), sample ``i`` is taken at ``t0 + (i + 1) / fs`` and block ``k``
  (samples ``k n`` to ``(k + 1) n - 1``) is due at ``t0 + (k + 1) n / fs``, when the writer
  publishes it (:meth:`DaqRing.publish`). The ring holds the last ``capacity`` published
  blocks: a host that does not read in time loses the oldest ones, and
  :class:`ShmBlockSource` counts them (``Block.lost``, in samples). A late writer publishes
  late but never moves the clock: the next blocks are due when they would have been.
* the analog output: every value the host writes (:meth:`ShmDaq.write_ao`) goes into a
  command ring with its ``monotonic_ns`` time, so that the simulator sees (and logs) each
  one; the output's value is the last one written.
* the encoder count of every tick with the tick's index: the host's
  :meth:`ShmDaq.read_counter` returns the count of the last tick whose time has come, with
  that tick's time.

One writer and one reader per lane (blocks, commands, counts). Each slot carries the index
it holds, written last, and a reader checks it after copying (a sequence lock); the writer
only ever writes a block slot that has fallen out of the readable window, so a copy made
while the block was readable is whole. The stores are ordered on x86-64 (total store order).
"""
from __future__ import annotations

import math
import time
from multiprocessing import shared_memory

import numpy as np

from tactile_mirror.checks import integer, real_number, sample_rate
from tactile_mirror.rig.daq import Block

__all__ = ["COMMAND_SLOTS", "DEVICE_ERROR", "DEVICE_OK", "DEVICE_REMOVED", "DaqRing", "RingState", "ShmBlockSource",
           "ShmDaq"]

#: AO values a host may write between two simulator ticks before the oldest is overwritten.
COMMAND_SLOTS = 4096

_MAGIC = 0x544D444151524E47  # "TMDAQRNG"
_HEADER = 32      # int64 header entries
_FLOATS = 4       # float64 entries after them: fs, AO low, AO high, spare

# header entries
_H_MAGIC, _H_N, _H_INPUTS, _H_CAPACITY, _H_SLOTS, _H_T0, _H_PUBLISHED, _H_STATE = range(8)
_H_STOP, _H_SHUTDOWN, _H_MISSED, _H_COMMANDS, _H_ENC_LAST, _H_ENC_INIT, _H_TRIPS, _H_ENC_SLOTS = range(8, 16)
_H_CMD_SLOTS, _H_COMPUTE_MAX, _H_COMPUTE_SUM, _H_DEVICE = range(16, 20)

#: :attr:`DaqRing.device_fault` values: the device works, reports an error on every call, is gone.
DEVICE_OK, DEVICE_ERROR, DEVICE_REMOVED = 0, 1, 2


class RingState:
    """States of the simulated DAQ, in :attr:`DaqRing.state`."""

    CREATED = 0     #: the host made the memory; no simulator yet
    READY = 1       #: the simulator is built and waits for the clock to start
    RUNNING = 2     #: the clock runs, blocks are published
    STOPPED = 3     #: the acquisition was stopped; no more blocks
    FAILED = 4      #: the simulator raised (its traceback goes to the host by its pipe)
    EXITED = 5      #: the simulator's process has ended

    NAMES = {0: "created", 1: "ready", 2: "running", 3: "stopped", 4: "failed", 5: "exited"}


def _layout(n: int, n_inputs: int, slots: int, cmd_slots: int,
            enc_slots: int) -> dict[str, tuple[int, tuple]]:
    """Byte offsets and shapes of the arrays in the memory block."""
    out, off = {}, 0
    for name, shape in (("header", (_HEADER,)), ("floats", (_FLOATS,)), ("slot_head", (slots, 2)),
                        ("data", (slots, n, n_inputs)), ("cmd_seq", (cmd_slots,)), ("cmd_t", (cmd_slots,)),
                        ("cmd_v", (cmd_slots,)), ("enc", (enc_slots, 2))):
        out[name] = (off, shape)
        off += 8 * math.prod(shape)
    out["size"] = (off, ())
    return out


class DaqRing:
    """The shared memory of the simulated DAQ (see the module notes).

    Make it with :meth:`create` (the host: it owns the memory and :meth:`unlink` s it) or
    :meth:`attach` (the simulator's process, by :attr:`name`).
    """

    def __init__(self, shm: shared_memory.SharedMemory, owner: bool):
        self._shm = shm
        self.owner = owner
        buf = shm.buf
        header = np.ndarray((_HEADER,), np.int64, buf, 0)
        if int(header[_H_MAGIC]) != _MAGIC:
            raise ValueError(f"shared memory {shm.name!r} is not a simulated DAQ")
        self.block_size = int(header[_H_N])
        self.n_inputs = int(header[_H_INPUTS])
        self.capacity = int(header[_H_CAPACITY])
        self.slots = int(header[_H_SLOTS])
        lay = _layout(self.block_size, self.n_inputs, self.slots, int(header[_H_CMD_SLOTS]),
                      int(header[_H_ENC_SLOTS]))
        dtypes = {"slot_head": np.int64, "data": np.float64, "cmd_seq": np.int64, "cmd_t": np.int64,
                  "cmd_v": np.float64, "enc": np.int64, "header": np.int64, "floats": np.float64}
        for name, dtype in dtypes.items():
            off, shape = lay[name]
            setattr(self, "_" + name, np.ndarray(shape, dtype, buf, off))
        self.fs = float(self._floats[0])
        self.ao_range = (float(self._floats[1]), float(self._floats[2]))
        self._cmd_read = 0          # the simulator's next command to take
        self.commands_lost = 0      # commands overwritten before the simulator took them

    # ------------------------------------------------------------------ making
    @classmethod
    def create(cls, fs: float, block_size: int, n_inputs: int, capacity: int = 100,
               ao_range: tuple[float, float] = (-10.0, 10.0), name: str | None = None) -> DaqRing:
        """New shared memory for blocks of ``block_size`` samples of ``n_inputs`` inputs at
        ``fs`` Hz, holding ``capacity`` blocks; ``ao_range`` (V) of the analog output."""
        fs = sample_rate(fs)
        n = integer(block_size, "block_size", 1)
        m = integer(n_inputs, "n_inputs", 1)
        cap = integer(capacity, "capacity", 1)
        lo, hi = (real_number(v, "ao_range", unit="V") for v in ao_range)
        if not lo < 0.0 < hi:
            raise ValueError(f"ao_range must contain 0 V, got {ao_range!r}")
        slots = cap + 2            # two more than readable: a block waiting for its due time, the next one
        enc_slots = 4 * n + 64     # the writer runs at most one block ahead of the clock
        lay = _layout(n, m, slots, COMMAND_SLOTS, enc_slots)
        shm = shared_memory.SharedMemory(name=name, create=True, size=lay["size"][0])
        header = np.ndarray((_HEADER,), np.int64, shm.buf, 0)
        header[:] = 0
        sizes = (_H_N, _H_INPUTS, _H_CAPACITY, _H_SLOTS, _H_CMD_SLOTS, _H_ENC_SLOTS)
        header[list(sizes)] = (n, m, cap, slots, COMMAND_SLOTS, enc_slots)
        header[_H_ENC_LAST] = -1
        floats = np.ndarray((_FLOATS,), np.float64, shm.buf, lay["floats"][0])
        floats[:] = (fs, lo, hi, 0.0)
        header[_H_MAGIC] = _MAGIC
        ring = cls(shm, owner=True)
        ring._slot_head[:, 0] = -1
        ring._cmd_seq[:] = -1
        ring._enc[:, 0] = -1
        return ring

    @classmethod
    def attach(cls, name: str) -> DaqRing:
        """The memory ``name`` made by :meth:`create` in another process. The attaching
        process does not register it for removal: its owner removes it."""
        from multiprocessing import resource_tracker

        register = resource_tracker.register
        # (SharedMemory registers every block it opens with the resource tracker, which then
        # removes it when this process ends and warns of a leak; only the owner may remove it)
        resource_tracker.register = lambda *args, **kwargs: None
        try:
            shm = shared_memory.SharedMemory(name=name, create=False)
        finally:
            resource_tracker.register = register
        return cls(shm, owner=False)

    @property
    def name(self) -> str:
        """Name of the shared memory (for :meth:`attach`)."""
        return self._shm.name

    def close(self) -> None:
        """Let go of the memory in this process (the arrays become unusable)."""
        for name in ("header", "floats", "slot_head", "data", "cmd_seq", "cmd_t", "cmd_v", "enc"):
            setattr(self, "_" + name, None)
        self._shm.close()

    def unlink(self) -> None:
        """Remove the memory (the owner, once every process has closed it)."""
        if not self.owner:
            raise RuntimeError("only the process that created the simulated DAQ may remove it")
        self._shm.unlink()

    # ------------------------------------------------------------------ clock and state
    @property
    def t0_ns(self) -> int:
        """Start of the DAQ clock, ``monotonic_ns`` (0: not started)."""
        return int(self._header[_H_T0])

    def start_clock(self, t0_ns: int) -> None:
        """Start the DAQ clock at ``t0_ns`` (once)."""
        if self.t0_ns:
            raise RuntimeError("the simulated DAQ's clock has already started")
        self._header[_H_T0] = int(t0_ns)

    def due_ns(self, k: int) -> int:
        """``monotonic_ns`` time block ``k`` is due: its last sample's time."""
        return self.t0_ns + round((k + 1) * self.block_size * 1e9 / self.fs)

    def tick_ns(self, i: int) -> int:
        """``monotonic_ns`` time of sample (tick) ``i``."""
        return self.t0_ns + round((i + 1) * 1e9 / self.fs)

    @property
    def state(self) -> int:
        """One of :class:`RingState`."""
        return int(self._header[_H_STATE])

    def set_state(self, state: int) -> None:
        self._header[_H_STATE] = int(state)

    @property
    def published(self) -> int:
        """Blocks published so far (the next one's index)."""
        return int(self._header[_H_PUBLISHED])

    def request_stop(self) -> None:
        """Ask the writer to stop the acquisition."""
        self._header[_H_STOP] = 1

    @property
    def stop_requested(self) -> bool:
        return bool(self._header[_H_STOP])

    def request_shutdown(self) -> None:
        """Ask the simulator to stop everything and end its process."""
        self._header[_H_SHUTDOWN] = 1
        self._header[_H_STOP] = 1

    @property
    def shutdown_requested(self) -> bool:
        return bool(self._header[_H_SHUTDOWN])

    @property
    def device_fault(self) -> int:
        """:data:`DEVICE_OK`, or the fault the simulator made: :data:`DEVICE_ERROR` (the host's
        output writes and counter reads fail with a device error), :data:`DEVICE_REMOVED` (the
        device is gone: they and the block reads raise OSError)."""
        return int(self._header[_H_DEVICE])

    def set_device_fault(self, fault: int) -> None:
        """The simulator: make a device fault (:attr:`device_fault`)."""
        if fault not in (DEVICE_OK, DEVICE_ERROR, DEVICE_REMOVED):
            raise ValueError(f"fault must be DEVICE_OK, DEVICE_ERROR or DEVICE_REMOVED, got {fault!r}")
        self._header[_H_DEVICE] = int(fault)

    def check_device(self) -> None:
        """Raise what a failing device raises on the host: RuntimeError for
        :data:`DEVICE_ERROR`, OSError for :data:`DEVICE_REMOVED`."""
        fault = int(self._header[_H_DEVICE])
        if fault == DEVICE_ERROR:
            raise RuntimeError("the simulated DAQ reports a device error (error -200000, as a driver's "
                               "error code)")
        if fault == DEVICE_REMOVED:
            raise OSError("the simulated DAQ device is gone (removed)")

    # ------------------------------------------------------------------ counters the writer keeps
    def count_block(self, compute_ns: int, missed: bool) -> None:
        """The writer's record of one block: its compute time and whether it missed its due time."""
        h = self._header
        h[_H_COMPUTE_SUM] += int(compute_ns)
        if compute_ns > h[_H_COMPUTE_MAX]:
            h[_H_COMPUTE_MAX] = int(compute_ns)
        if missed:
            h[_H_MISSED] += 1

    def count_watchdog_trip(self) -> None:
        self._header[_H_TRIPS] += 1

    def counters(self) -> dict:
        """Live counters: blocks published, deadlines missed, mean and longest block compute
        time (s), watchdog trips, AO values written, the state."""
        h = self._header
        blocks = int(h[_H_PUBLISHED])
        return {"blocks": blocks, "missed_deadlines": int(h[_H_MISSED]),
                "compute_mean_s": float(h[_H_COMPUTE_SUM]) / max(blocks, 1) / 1e9,
                "compute_max_s": float(h[_H_COMPUTE_MAX]) / 1e9, "watchdog_trips": int(h[_H_TRIPS]),
                "ao_writes": int(h[_H_COMMANDS]), "state": RingState.NAMES.get(int(h[_H_STATE]), "?")}

    # ------------------------------------------------------------------ blocks: the writer
    def slot(self, k: int) -> np.ndarray:
        """The writable ``(block_size, n_inputs)`` slot of block ``k``, marked as being
        written: the next block to publish or the one after it (the writer computes at most
        one block ahead of the clock)."""
        if not self.published <= k <= self.published + 1:
            raise ValueError(f"block {k} cannot be written now: the next block to publish is "
                             f"{self.published}")
        s = k % self.slots
        self._slot_head[s, 0] = -1
        return self._data[s]

    def publish(self, k: int) -> None:
        """Make block ``k`` (written through :meth:`slot`) readable, stamped with its due time."""
        s = k % self.slots
        self._slot_head[s, 1] = self.due_ns(k)
        self._slot_head[s, 0] = k
        self._header[_H_PUBLISHED] = k + 1

    # ------------------------------------------------------------------ blocks: the reader
    def copy_block(self, k: int) -> tuple[np.ndarray, int] | None:
        """Block ``k``'s samples (a copy) and time, or None if it is no longer (or not yet) in
        the ring."""
        s = k % self.slots
        if self._slot_head[s, 0] != k:
            return None
        out = self._data[s].copy()
        t_ns = int(self._slot_head[s, 1])
        # readable during the whole copy: still within the last `capacity` published blocks
        if self._slot_head[s, 0] != k or k < int(self._header[_H_PUBLISHED]) - self.capacity:
            return None
        return out, t_ns

    # ------------------------------------------------------------------ analog output
    def write_command(self, volts: float, t_ns: int) -> None:
        """The host: one AO value, written at ``t_ns``."""
        h = self._header
        seq = int(h[_H_COMMANDS])
        j = seq % self._cmd_seq.shape[0]
        self._cmd_seq[j] = -1
        self._cmd_t[j] = t_ns
        self._cmd_v[j] = volts
        self._cmd_seq[j] = seq
        h[_H_COMMANDS] = seq + 1

    def take_commands(self) -> list[tuple[int, float]]:
        """The simulator: ``(t_ns, volts)`` of every AO value written since the last call, in
        order (those overwritten before this call are counted in :attr:`commands_lost`)."""
        end = int(self._header[_H_COMMANDS])
        size = self._cmd_seq.shape[0]
        out = []
        seq = max(self._cmd_read, end - size)
        self.commands_lost += seq - self._cmd_read
        while seq < end:
            j = seq % size
            t, v = int(self._cmd_t[j]), float(self._cmd_v[j])
            if self._cmd_seq[j] == seq:
                out.append((t, v))
            else:
                self.commands_lost += 1
            seq += 1
        self._cmd_read = end
        return out

    def last_command(self) -> tuple[int, float] | None:
        """``(t_ns, volts)`` of the last AO value written, None before the first."""
        seq = int(self._header[_H_COMMANDS]) - 1
        if seq < 0:
            return None
        j = seq % self._cmd_seq.shape[0]
        return int(self._cmd_t[j]), float(self._cmd_v[j])

    # ------------------------------------------------------------------ encoder
    def set_initial_count(self, count: int) -> None:
        """The count before the first tick."""
        self._header[_H_ENC_INIT] = int(count)

    def write_count(self, i: int, count: int) -> None:
        """The simulator: the encoder count at tick ``i`` (written ahead of the tick's time)."""
        e = i % self._enc.shape[0]
        self._enc[e, 0] = -1
        self._enc[e, 1] = int(count)
        self._enc[e, 0] = i
        self._header[_H_ENC_LAST] = i

    def read_count(self, now_ns: int) -> tuple[int, int]:
        """The encoder count of the last tick whose time has come by ``now_ns``, and that
        tick's time; before the first tick, the initial count at ``now_ns``. When the
        simulator is late, the last tick it wrote, with that tick's (older) time."""
        t0 = self.t0_ns
        init = int(self._header[_H_ENC_INIT])
        if t0 == 0 or now_ns < t0:
            return init, now_ns
        due = math.floor((now_ns - t0) * self.fs / 1e9) - 1   # the last tick whose time has come
        if due < 0:
            return init, now_ns
        for _ in range(4):
            j = min(due, int(self._header[_H_ENC_LAST]))
            if j < 0:
                return init, t0
            e = j % self._enc.shape[0]
            i1 = self._enc[e, 0]
            c = int(self._enc[e, 1])
            if i1 == j and self._enc[e, 0] == j:
                return c, self.tick_ns(j)
        raise RuntimeError("the simulated encoder count kept changing while it was read")


class ShmBlockSource:
    """The host's :class:`~tactile_mirror.rig.daq.BlockSource` over a :class:`DaqRing`.

    :meth:`start` starts the DAQ clock ``start_delay`` s from now (the simulator is waiting
    for it); :meth:`read_block` waits until the next block is due and published. Blocks that
    fell out of the ring before they were read are counted, never hidden: ``Block.lost`` (in
    samples), :attr:`lost_samples` and :attr:`overruns` (blocks returned after a loss).
    ``channels`` names the inputs (:func:`~tactile_mirror.rig.daq.input_names`).
    """

    def __init__(self, ring: DaqRing, channels: tuple[str, ...] | None = None, start_delay: float = 0.02):
        self.ring = ring
        self.fs = ring.fs
        self.n_inputs = ring.n_inputs
        self.block_size = ring.block_size
        if channels is not None and len(channels) != self.n_inputs:
            raise ValueError(f"channels must name the {self.n_inputs} inputs, got {len(channels)} names")
        self.channels = tuple(channels) if channels is not None else None
        self.start_delay = real_number(start_delay, "start_delay", unit="s", nonnegative=True)
        self._next = 0
        self.lost_samples = 0
        self.overruns = 0
        self.blocks = 0
        self._end = 0   # end (sample index) of the last block returned
        self._started = False

    def start(self) -> None:
        """Start the DAQ clock (block 0 is due ``start_delay + block_size / fs`` s from now)."""
        if self._started:
            raise RuntimeError("the acquisition has already started")
        self.ring.start_clock(time.monotonic_ns() + round(self.start_delay * 1e9))
        self._started = True

    def read_block(self, timeout: float = 1.0) -> Block:
        """The next block, waiting up to ``timeout`` s for it (TimeoutError after that; EOFError
        when the acquisition has stopped and every block was read; RuntimeError when the
        simulator failed)."""
        timeout = real_number(timeout, "timeout", unit="s", nonnegative=True)
        if not self._started:
            raise RuntimeError("start() the acquisition before reading blocks")
        ring = self.ring
        deadline = time.monotonic_ns() + round(timeout * 1e9)
        while True:
            if ring.device_fault == DEVICE_REMOVED:
                ring.check_device()
            published = ring.published
            if published > self._next:
                oldest = published - ring.capacity
                if self._next < oldest:
                    self._next = oldest
                got = ring.copy_block(self._next)
                if got is None:  # overwritten while it was copied: the window moved on
                    self._next = max(self._next + 1, ring.published - ring.capacity)
                    continue
                samples, t_ns = got
                n = self.block_size
                k = self._next
                lost = k * n - self._end
                self._end = (k + 1) * n
                self._next = k + 1
                self.blocks += 1
                if lost:
                    self.lost_samples += lost
                    self.overruns += 1
                return Block(samples=samples, index=k * n, lost=lost, t_ns=t_ns)
            state = ring.state
            if state == RingState.FAILED:
                raise RuntimeError("the simulated rig failed: its process raised (see SimulatedRig.stop())")
            if state in (RingState.STOPPED, RingState.EXITED):
                raise EOFError(f"the simulated acquisition has stopped after {published} blocks")
            now = time.monotonic_ns()
            if now >= deadline:
                clock = "runs" if ring.t0_ns else "has not started"
                raise TimeoutError(f"no block {self._next} within {timeout:g} s (the DAQ clock {clock}; "
                                   f"{published} published)")
            # sleep until it is due (or the deadline), then poll finely
            wait = min(ring.due_ns(self._next) - now, deadline - now) if ring.t0_ns else deadline - now
            time.sleep(max(wait - 100_000, 20_000) / 1e9 if wait > 150_000 else 2e-5)

    def stop(self) -> None:
        """Stop the acquisition (the simulator publishes no more blocks)."""
        self.ring.request_stop()

    def close(self) -> None:
        """Stop; the memory itself belongs to its owner (:class:`SimulatedRig`)."""
        self.stop()


class ShmDaq:
    """The host's :class:`~tactile_mirror.rig.daq.Daq` over a :class:`DaqRing`: the block
    source (:attr:`analog_input`), the stage's analog output (:meth:`write_ao`) and encoder
    counter (:meth:`read_counter`). One thread writes the output."""

    def __init__(self, ring: DaqRing, channels: tuple[str, ...] | None = None, start_delay: float = 0.02):
        self.ring = ring
        self._source = ShmBlockSource(ring, channels, start_delay)
        self.ao_range = ring.ao_range
        #: What :meth:`close` writes, V (None: nothing; see NiStageIO's ``idle_volts``).
        self.idle_volts: float | None = 0.0
        self._closed = False

    @property
    def analog_input(self) -> ShmBlockSource:
        return self._source

    def write_ao(self, volts: float) -> None:
        """Set the analog output to ``volts`` (V, within :attr:`ao_range`; ValueError outside,
        nothing written)."""
        v = real_number(volts, "volts", unit="V")
        lo, hi = self.ao_range
        if not lo <= v <= hi:
            raise ValueError(f"volts must lie in the analog output's range [{lo:g}, {hi:g}] V, got {volts!r}")
        if self._closed:
            raise RuntimeError("the simulated DAQ is closed")
        self.ring.check_device()
        self.ring.write_command(v, time.monotonic_ns())

    def read_counter(self) -> tuple[int, int]:
        """The encoder count now and the ``monotonic_ns`` time it holds for."""
        self.ring.check_device()
        return self.ring.read_count(time.monotonic_ns())

    def status(self) -> dict:
        """The simulator's live counters (:meth:`DaqRing.counters`)."""
        return self.ring.counters()

    def close(self) -> None:
        """Write :attr:`idle_volts` (0 V unless set otherwise) and stop the acquisition (the
        memory belongs to its owner)."""
        if not self._closed:
            try:
                if self.idle_volts is not None:
                    self.write_ao(self.idle_volts)
            finally:
                self._closed = True
                self._source.close()
