"""The simulated rig: a separate process that stands in for the pad, the sensors, the DAQ and
the stage, in real time.

:class:`SimulatedRig` starts the process (``multiprocessing``, spawn) and hands the host a
:class:`~tactile_mirror.rig.sim.daq_shm.ShmDaq` over their shared memory. The process runs,
tick by tick, on the DAQ's clock (the wall clock, ``time.monotonic_ns()``):

* the finger: a seeded band-limited path (:func:`~tactile_mirror.loop.finger.finger_trajectory`;
  at rest while it presses in, at rest again after its ``duration``; with
  ``finger_wait`` it rides with the pad until the host places it
  (:meth:`SimulatedRig.place_finger`), then rests until :meth:`SimulatedRig.start_finger`);
* the stage's axis (:class:`~tactile_mirror.rig.sim.axis.SimAxis`; by default
  :class:`~tactile_mirror.rig.sim.axis.AnalogAxis`: the analog output's volts as a velocity
  or position command to a servo with a lag, the encoder's counts from its position);
* the contact plant stepped with ``finger - pad`` (by default
  :meth:`FemPad.realtime <tactile_mirror.contact.FemPad.realtime>`, the FEM pad that keeps
  up with 1 kHz), its strips' change of load through the PVDF circuit
  (:class:`~tactile_mirror.circuit.CircuitStream`) with the sensor noise of
  :class:`~tactile_mirror.noise.SensorNoise` (mains hum included), and the force sensor's
  ``F_y`` (the finger's force less the pad's inertia) and ``F_z``, with white noise.

Each tick is computed ``lead`` s ahead of its sample time (the axis takes the commands
that arrived by then: a dead time of ``lead``), so that block ``k`` is ready when it is due
at ``t0 + (k + 1) n / fs``; it is published then. A block finished after its due time is a
missed deadline: counted, published at once, and the clock goes on (the next blocks are due
when they would have been). A communication watchdog stops the axis when no command has
come for ``watchdog`` s (it is armed by the first command; a new command moves the axis
again). On shutdown the process returns its log (:class:`~tactile_mirror.rig.sim.config.SimRigLog`):
every command with its time, the stops, the deadline misses, each block's compute time, the
faults made, and per tick the finger, the pad and each ridge's slip fraction.

The host talks to the running process through a control pipe read once per block: start
the finger, reset the charge amplifiers (:meth:`SimulatedRig.reset_amplifiers`: the
simulator's stand-in for the amplifiers' reset line), make a fault
(:meth:`SimulatedRig.inject`, :data:`~tactile_mirror.rig.sim.config.FAULTS`).

The hook for other command paths (a serial line on a pseudo-terminal): ``axis_factory``
in :class:`~tactile_mirror.rig.sim.config.SimRigConfig` builds any axis in the process; its
``info()`` reaches the host as :attr:`SimulatedRig.axis_info` (e.g. the name of its port).
"""
from __future__ import annotations

import gc
import math
import multiprocessing
import time
import traceback

import numpy as np

from tactile_mirror.rig.daq import input_names
from tactile_mirror.rig.realtime import gc_paused, raised_priority
from tactile_mirror.rig.sim.axis import analog_axis
from tactile_mirror.rig.sim.config import FAULTS, SimRigConfig, SimRigLog
from tactile_mirror.rig.sim.daq_shm import DEVICE_ERROR, DEVICE_REMOVED, DaqRing, RingState, ShmDaq

__all__ = ["SimulatedRig"]


class SimulatedRig:
    """The simulated rig's process, seen from the host.

    >>> with SimulatedRig(SimRigConfig()) as rig:       # doctest: +SKIP
    ...     src = rig.daq.analog_input
    ...     src.start()
    ...     block = src.read_block(timeout=1.0)
    ...     rig.daq.write_ao(0.5)
    >>> rig.log.summary()                                # doctest: +SKIP

    :meth:`start` spawns the process and waits until it has built its plant; the DAQ clock
    starts with ``rig.daq.analog_input.start()``. :meth:`stop` shuts the process down and
    removes the shared memory, and returns the process's :class:`SimRigLog`.
    """

    def __init__(self, config: SimRigConfig | None = None):
        self.config = config if config is not None else SimRigConfig()
        if not isinstance(self.config, SimRigConfig):
            raise TypeError(f"config must be a SimRigConfig, got {type(config).__name__}")
        self._ring: DaqRing | None = None
        self._daq: ShmDaq | None = None
        self._process = None
        self._conn = None
        self._control = None
        self.axis_info: dict = {}
        self.log: SimRigLog | None = None
        self.error: str | None = None

    @property
    def daq(self) -> ShmDaq:
        """The host's side of the simulated DAQ (after :meth:`start`)."""
        if self._daq is None:
            raise RuntimeError("start() the simulated rig first")
        return self._daq

    @property
    def process(self):
        """The ``multiprocessing.Process`` (None before :meth:`start`)."""
        return self._process

    @property
    def shm_name(self) -> str | None:
        """Name of the shared memory (None before :meth:`start`)."""
        return self._ring.name if self._ring is not None else None

    def start(self, timeout: float = 120.0) -> SimulatedRig:
        """Spawn the process and wait (up to ``timeout`` s) until it is ready."""
        if self._process is not None:
            raise RuntimeError("the simulated rig has already been started")
        c = self.config
        ctx = multiprocessing.get_context("spawn")
        self._ring = DaqRing.create(c.fs, c.block_size, c.n_inputs, c.buffer_blocks, c.ao_range)
        self._conn, child = ctx.Pipe(duplex=False)
        control, self._control = ctx.Pipe(duplex=False)
        self._process = ctx.Process(target=_process_main, args=(self._ring.name, c, child, control),
                                    name="tactile-mirror-simulated-rig", daemon=True)
        try:
            self._process.start()
            child.close()
            control.close()
            deadline = time.monotonic() + timeout
            while not self._conn.poll(0.05):
                if not self._process.is_alive():
                    raise RuntimeError(f"the simulated rig's process ended before it was ready "
                                       f"(exit code {self._process.exitcode})")
                if time.monotonic() > deadline:
                    raise TimeoutError(f"the simulated rig was not ready within {timeout:g} s")
            try:
                kind, payload = self._conn.recv()
            except EOFError:
                raise RuntimeError("the simulated rig's process ended before it was ready (it sent nothing; "
                                   "a script that starts it needs an `if __name__ == '__main__':` guard, "
                                   "the process is spawned)") from None
            if kind == "error":
                self.error = payload
                raise RuntimeError(f"the simulated rig failed to start:\n{payload}")
            self.axis_info = payload
        except BaseException:
            self.stop(timeout=5.0)
            raise
        self._daq = ShmDaq(self._ring, input_names(c.n_ridges))
        return self

    # ------------------------------------------------------------------ control
    def _send(self, message: tuple) -> None:
        if self._control is None or self._ring is None:
            raise RuntimeError("start() the simulated rig first")
        self._control.send(message)

    def place_finger(self) -> None:
        """``finger_wait``: the finger, riding with the pad until now (no shear), stays where the
        pad is (read by the process within a block)."""
        self._send(("place",))

    def start_finger(self) -> None:
        """``finger_wait``: the finger starts its path from where it was placed (placed now if
        it was not); read by the process within a block."""
        self._send(("finger",))

    def reset_amplifiers(self) -> None:
        """Reset the charge amplifiers (the PVDF circuits and the force sensor's): their outputs
        return to 0 at the present load, from the next block on."""
        self._send(("reset",))

    def inject(self, kind: str, **options) -> None:
        """Make the fault ``kind`` (:data:`~tactile_mirror.rig.sim.config.FAULTS`), from the next
        block on; the log's ``faults`` has when. Options: ``offset`` (m beyond the soft limit,
        ``"out_of_limit"``; default 5 mm past the axis's travel end), ``ticks`` (``"nan_burst"``,
        default 200)."""
        if kind not in FAULTS:
            raise ValueError(f"kind must be one of {FAULTS}, got {kind!r}")
        self._send(("fault", kind, dict(options)))

    def status(self) -> dict:
        """The process's live counters (:meth:`DaqRing.counters`) and whether it is alive."""
        out = self._ring.counters() if self._ring is not None else {}
        out["alive"] = bool(self._process is not None and self._process.is_alive())
        return out

    def stop(self, timeout: float = 10.0) -> SimRigLog | None:
        """Shut the process down (it stops the axis and returns its log), wait for it to end
        (terminated after ``timeout`` s), remove the shared memory. Returns the log (None if
        the process gave none; if it raised, its traceback is in :attr:`error`). Calling it
        again returns the same."""
        if self._ring is None:
            return self.log
        ring, proc, conn = self._ring, self._process, self._conn
        if proc is not None and proc.ident is None:   # never started
            proc = None
        try:
            ring.request_shutdown()
            deadline = time.monotonic() + timeout
            while proc is not None and conn is not None:
                if conn.poll(0.05):
                    try:
                        kind, payload = conn.recv()
                    except EOFError:
                        break
                    if kind == "log":
                        self.log = SimRigLog(**payload)
                        break
                    if kind == "error":
                        self.error = payload
                        break
                elif not proc.is_alive() or time.monotonic() > deadline:
                    break
            if proc is not None:
                proc.join(max(0.0, deadline - time.monotonic()))
                if proc.is_alive():
                    proc.terminate()
                    proc.join(2.0)
                if proc.is_alive():
                    proc.kill()
                    proc.join(2.0)
        finally:
            for c in (conn, self._control):
                if c is not None:
                    c.close()
            self._control = None
            self._daq = None
            self._ring = None
            try:
                ring.close()
            finally:
                ring.unlink()
        return self.log

    def close(self) -> None:
        self.stop()

    def __enter__(self) -> SimulatedRig:
        return self.start() if self._process is None else self

    def __exit__(self, *exc) -> None:
        self.stop()


# ---------------------------------------------------------------------- the process
class _Simulation:
    """The process's state: the finger, the axis, the plant, the circuit and the noise."""

    def __init__(self, config: SimRigConfig, ring: DaqRing):
        from tactile_mirror.circuit import PVDFCircuit
        from tactile_mirror.loop.finger import finger_trajectory, pressed_finger_path

        c = self.config = config
        self.ring = ring
        R = c.n_ridges
        self.circuit_model = PVDFCircuit(**(c.circuit or {}))
        if c.plant == "brush":
            from tactile_mirror.contact.brush import BrushRidges

            mu = 1.0 if c.mu is None else c.mu
            self.plant = BrushRidges(R, mu=mu * (1 + 0.04 * np.linspace(-1, 1, R)))
            press = 0.0
        else:
            from tactile_mirror.contact.plants import FemPad

            make = FemPad.realtime if c.plant == "realtime" else FemPad
            self.plant = make(R, mu=c.mu, fs=c.fs, circuit=self.circuit_model)
            press = c.press
        if c.finger_wait:
            self.finger = finger_trajectory(c.seed, c.duration, c.fs, **c.trajectory)
            self.finger_start = -1
            self.anchor = math.nan       # not placed yet: the finger rides with the pad
        else:
            self.finger = pressed_finger_path(c.seed, c.duration, c.fs, press, **c.trajectory)
            self.finger_start = 0
            self.anchor = 0.0
        self.circuit = self.circuit_model.stream(c.fs, 2 * R)
        rng = np.random.default_rng(30_000 + c.seed)
        L = max(1, round(c.noise_record * c.fs))
        if c.noise is not None:
            self.noise_v, self.noise_u = c.noise.draw(c.fs, L, 2 * R, seed=rng)
        else:
            self.noise_v = self.noise_u = np.zeros((2 * R, L))
        self.noise_f = rng.normal(0.0, c.force_noise, (2, L)) if c.force_noise else np.zeros((2, L))
        factory = c.axis_factory or analog_axis
        self.axis = factory(c, ring)
        self.cpm = float(c.counts_per_m)
        ring.set_initial_count(math.floor(self.axis.position() * self.cpm))
        self._stress0 = None
        self._force0 = np.zeros(2)
        self._tare_force = False
        self._pad0 = self._pad1 = 0.0   # the pad at the last two ticks, m
        self._watchdog_ns = round(c.watchdog * 1e9)
        self._tripped = False
        self._frozen = False          # the encoder stopped counting
        self._count_offset = 0.0      # m added to the encoder's reading
        self._nan_left = 0
        self.stops: list[tuple[int, str]] = []
        self.trips: list[int] = []
        self.faults: list[tuple[int, str]] = []
        self.resets: list[int] = []
        self.block_compute: list[int] = []
        self.missed: list[int] = []
        self.lateness: list[int] = []
        # finger, pad, slip fraction per tick, in chunks of a second: a new chunk costs
        # microseconds, where growing one array copied it whole (10 ms at 8 s, in the tick path)
        self._chunk = max(1, round(c.fs))
        self._ticks = [np.zeros((self._chunk, R + 2))]
        self._n_ticks = 0

    # ------------------------------------------------------------------ host's requests
    def control(self, conn) -> None:
        """Apply the host's requests that have arrived (at most a few per block)."""
        while conn is not None and conn.poll():
            try:
                message = conn.recv()
            except (EOFError, OSError):
                return
            now = time.monotonic_ns()
            if message[0] == "place":
                if math.isnan(self.anchor):
                    self.anchor = self._pad1
            elif message[0] == "finger":
                if math.isnan(self.anchor):
                    self.anchor = self._pad1
                if self.finger_start < 0:
                    self.finger_start = self._n_ticks
            elif message[0] == "reset":
                self.circuit.reset()   # (in place: a new stream costs 0.5 ms of the block's deadline)
                self._stress0 = None
                self._tare_force = True
                self.resets.append(now)
            elif message[0] == "fault":
                self._fault(message[1], message[2], now)

    def _fault(self, kind: str, options: dict, now: int) -> None:
        c, ring = self.config, self.ring
        self.faults.append((now, kind))
        inject = getattr(self.axis, "inject", None)
        if inject is not None and inject(kind, options):
            return
        if kind == "silent":
            self._frozen = True
        elif kind == "error_reply":
            ring.set_device_fault(DEVICE_ERROR)
        elif kind == "closed_port":
            ring.set_device_fault(DEVICE_REMOVED)
        elif kind == "out_of_limit":
            offset = float(options.get("offset", 0.005))
            x = self.axis.position()
            self._count_offset = c.limits.x_max + offset - x
        elif kind == "nan_burst":
            self._nan_left = int(options.get("ticks", 200))

    # ------------------------------------------------------------------ the clock
    def run(self, parent, conn) -> None:
        """Tick until the acquisition is stopped, the process is asked to shut down or the
        host's process is gone.

        Two timers: tick ``i`` is computed from ``tick_ns(i) - lead`` on, a finished block is
        published at its due time (before any tick that comes later); in between, it sleeps.
        """
        c, ring = self.config, self.ring
        n = c.block_size
        lead_ns = round(c.lead_s * 1e9)
        ring.set_state(RingState.RUNNING)
        i = 0
        slot = None
        compute = 0
        pending: list[tuple[int, int, int]] = []   # finished blocks: (index, finished ns, compute ns)
        while True:
            now = time.monotonic_ns()
            if pending:
                k, done, cost = pending[0]
                due = ring.due_ns(k)
                if due <= now:
                    ring.publish(k)
                    late = done > due
                    if late:
                        self.missed.append(k)
                        self.lateness.append(done - due)
                    ring.count_block(cost, late)
                    self.block_compute.append(cost)
                    pending.pop(0)
                    continue
            target = ring.tick_ns(i) - lead_ns
            if target > now:
                wake = min(target, due) if pending else target
                if pending and wake == due:
                    if due - now > 150_000:   # sleep, then wait out the last 0.1 ms
                        time.sleep((due - now - 100_000) / 1e9)
                    while time.monotonic_ns() < due:
                        pass
                else:
                    time.sleep((wake - now) / 1e9)
                continue
            k, j = divmod(i, n)
            if j == 0:
                if ring.stop_requested or (k % 100 == 0 and parent is not None and not parent.is_alive()):
                    break
                self.control(conn)
                slot = ring.slot(k)
                compute = 0
            c0 = time.perf_counter_ns()
            self._tick(i, slot[j])
            compute += time.perf_counter_ns() - c0
            if j == n - 1:
                pending.append((k, time.monotonic_ns(), compute))
            i += 1

    def _tick(self, i: int, row: np.ndarray) -> None:
        """Tick ``i``: commands, watchdog, axis, encoder, plant, circuit, noise -> ``row``."""
        c, ring, axis = self.config, self.ring, self.axis
        R, fs = c.n_ridges, c.fs
        now = time.monotonic_ns()
        axis.poll(now)
        last = axis.last_command_ns()
        if last >= 0 and now - last > self._watchdog_ns:
            if not self._tripped:
                axis.stop()
                self._tripped = True
                self.trips.append(now)
                self.stops.append((now, "watchdog"))
                ring.count_watchdog_trip()
        else:
            self._tripped = False
        pad = axis.advance(1.0 / fs)
        if not self._frozen:
            ring.write_count(i, math.floor((pad + self._count_offset) * self.cpm))
        s = self.finger_start
        if math.isnan(self.anchor):
            finger = pad
        else:
            finger = self.anchor + (0.0 if s < 0 else float(self.finger[min(i - s, self.finger.size - 1)]))
        st = self.plant.advance(finger - pad)
        load = st.stress.reshape(-1)
        if self._stress0 is None:
            self._stress0 = load.copy()  # the static normal preload is no change of stress
        v, u = self.circuit.step_load(load - self._stress0)
        m = i % self.noise_v.shape[1]
        row[:2 * R] = v + self.noise_v[:, m]
        row[2 * R:4 * R] = u + self.noise_u[:, m]
        p0, p1 = self._pad0, self._pad1
        acc = (pad - 2.0 * p1 + p0) * fs * fs if i >= 2 else 0.0
        self._pad0, self._pad1 = p1, pad
        fy = st.force_y - c.pad_mass * acc
        if self._tare_force:
            self._force0[:] = (fy, st.force_z)
            self._tare_force = False
        row[4 * R] = fy - self._force0[0] + self.noise_f[0, m]
        row[4 * R + 1] = st.force_z - self._force0[1] + self.noise_f[1, m]
        if self._nan_left:
            row[:4 * R] = math.nan
            self._nan_left -= 1
        t = self._n_ticks
        k, r = divmod(t, self._chunk)
        if k == len(self._ticks):
            self._ticks.append(np.zeros_like(self._ticks[0]))
        rec = self._ticks[k]
        rec[r, 0] = finger
        rec[r, 1] = pad
        rec[r, 2:] = st.slip_fraction
        self._n_ticks = t + 1

    def record(self) -> dict:
        c, ring = self.config, self.ring
        ticks = np.concatenate(self._ticks)[:self._n_ticks]
        return {"fs": c.fs, "block_size": c.block_size, "t0_ns": ring.t0_ns, "blocks": ring.published,
                "block_compute_ns": np.asarray(self.block_compute, dtype=np.int64),
                "missed_blocks": np.asarray(self.missed, dtype=np.int64),
                "lateness_ns": np.asarray(self.lateness, dtype=np.int64), "stops": list(self.stops),
                "watchdog_trips_ns": np.asarray(self.trips, dtype=np.int64), "commands": self.axis.log(),
                "faults": list(self.faults), "resets": list(self.resets), "finger_start": int(self.finger_start),
                "finger": ticks[:, 0].copy(), "pad": ticks[:, 1].copy(),
                "slip_fraction": np.ascontiguousarray(ticks[:, 2:].T)}


def _process_main(name: str, config: SimRigConfig, conn, control) -> None:
    """The simulated rig's process: build, wait for the clock, run, report."""
    import sys

    # A thread of this process serves a serial controller's line (the serial path): it must get
    # the interpreter within a fraction of a millisecond, not after the default 5 ms switch
    # interval of the tick loop's thread.
    sys.setswitchinterval(1e-4)
    # a simulator that stands in for hardware must not wait behind the machine's other work
    with raised_priority():
        _serve(name, config, conn, control)


def _serve(name: str, config: SimRigConfig, conn, control) -> None:
    """Build the simulation, tell the host it is ready, run on the clock, send the log."""
    parent = multiprocessing.parent_process()
    ring = DaqRing.attach(name)
    sim = None
    try:
        sim = _Simulation(config, ring)
        gc.collect()   # (now, before the host talks to the process: a collection later holds it up)
        ring.set_state(RingState.READY)
        conn.send(("ready", sim.axis.info()))
        with gc_paused():
            while not ring.t0_ns and not ring.shutdown_requested:
                if parent is not None and not parent.is_alive():
                    return
                time.sleep(5e-4)
            if ring.t0_ns and not ring.stop_requested:
                with raised_priority(rt_priority=config.rt_priority):   # (the clock runs: the ticks wait on it)
                    sim.run(parent, control)
        sim.axis.stop()
        why = "shutdown" if ring.shutdown_requested else "acquisition stopped"
        sim.stops.append((time.monotonic_ns(), why))
        ring.set_state(RingState.STOPPED)
        while not ring.shutdown_requested:
            if parent is not None and not parent.is_alive():
                return
            time.sleep(2e-3)
        conn.send(("log", sim.record()))
        ring.set_state(RingState.EXITED)
    except BaseException:
        ring.set_state(RingState.FAILED)
        try:
            conn.send(("error", traceback.format_exc()))
        except Exception:  # (the host is gone: nothing to tell)
            pass
    finally:
        if sim is not None:
            sim.axis.close()
        conn.close()
        control.close()
        ring.close()
