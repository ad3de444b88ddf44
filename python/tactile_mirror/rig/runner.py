"""The loop on the rig, paced by the acquisition's clock.

:class:`RigRunner` reads the acquisition's blocks (it waits in ``read_block`` until the DAQ
has the next one: no busy wait, no clock of its own), puts every sample of a block through
the pipeline and commands the stage once the block's ticks are computed:

* ``command_mode == "per_tick"`` (an adapter that takes a command per tick, the analog
  path): every sample through :meth:`MirrorPipeline.step <tactile_mirror.MirrorPipeline.step>`;
  with one sample per block that is one command per tick. The ticks of a longer block are
  computed in one burst, microseconds apart, so only the last one's command is sent: the
  earlier ones would be overwritten before the stage could act on them;
* ``command_mode == "per_block"`` (a serial controller): the block through
  :meth:`MirrorPipeline.process_block <tactile_mirror.MirrorPipeline.process_block>` (the same
  ticks, bit for bit), then its last command.

A command goes to the driver at most every ``command_interval`` (the configured rate); one that
comes sooner (blocks handled in a burst after the loop was held up) is sent as soon as the
interval allows, unless a newer block's command replaces it first. A driver with a mailbox (a serial line's) takes every
block's target and sends the latest when its line allows, at most at its own measured
``command_interval``: the target it sends is at most a block old. The
:class:`~tactile_mirror.rig.supervisor.Supervisor` sees every block, position reading,
pipeline status and target; at its first fault the stage is stopped and :meth:`RigRunner.run`
raises :class:`~tactile_mirror.rig.supervisor.RigError` carrying the partial
:class:`RigResult`. Every sample the acquisition delivered is in the result; every sample it
lost is counted (``RigResult.block_lost``), and a loss stops the run (an overrun).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from tactile_mirror.checks import integer, real_number
from tactile_mirror.loop.recording import Recording, RigTrace
from tactile_mirror.rig.daq import Overrun
from tactile_mirror.rig.realtime import gc_paused, raised_priority
from tactile_mirror.rig.supervisor import RigError, Supervisor, Trip, fault_cause

__all__ = ["RigResult", "RigRunner"]


@dataclass
class RigResult:
    """What a rig run produced: per tick (rows: the samples delivered, in order), per block
    and per command.

    Attributes
    ----------
    fs : float
    samples, outputs, accepted, stage_position
        Per row: the pipeline's inputs, its outputs, whether it accepted the tick, the stage
        position read for the tick's block, m.
    aux : ndarray, shape (n, n_aux); aux_names : tuple of str
        Acquired channels the pipeline does not read.
    block_row, block_index, block_lost, block_t_ns, block_read_ns : ndarray of int64
        Per block: first row, first sample's index, samples lost before it, time of its
        last sample, when the loop had it.
    block_latency_ns : ndarray of int64
        Per block: its last sample -> the command sent for it returned (-1: none sent).
    command_row, command_t_ns, command_x : ndarray
        Per command sent: the row it came from, when ``move_to`` returned, the target (m).
    x0 : float
        The controller's start position, m (0 if the run stopped before it had one).
    config : dict
        The pipeline's configuration.
    command_mode : str
    command_interval : float
        The shortest interval between commands the stage received, s: the configured one, or
        the driver's own (measured) if longer.
    largest_position_age : float
        s, over the run's position readings.
    late_blocks : int
        Blocks handled later than the supervisor's bound.
    trip : Trip or None
        The fault that stopped the run (None: it ran its course).
    status : dict
        The pipeline's status at the end.
    skipped, lost_before : int
        Blocks acquired before the run started, read and not run (``catch_up``), and the
        samples lost before them.
    """

    fs: float
    samples: np.ndarray
    outputs: np.ndarray
    accepted: np.ndarray
    stage_position: np.ndarray
    aux: np.ndarray
    aux_names: tuple
    block_row: np.ndarray
    block_index: np.ndarray
    block_lost: np.ndarray
    block_t_ns: np.ndarray
    block_read_ns: np.ndarray
    block_latency_ns: np.ndarray
    command_row: np.ndarray
    command_t_ns: np.ndarray
    command_x: np.ndarray
    x0: float
    config: dict
    command_mode: str
    command_interval: float
    largest_position_age: float
    late_blocks: int
    trip: Trip | None = None
    status: dict = field(default_factory=dict)
    skipped: int = 0
    lost_before: int = 0

    @property
    def n_ticks(self) -> int:
        return int(self.samples.shape[0])

    @property
    def lost_samples(self) -> int:
        """Samples the acquisition lost (never delivered)."""
        return int(self.block_lost.sum())

    @property
    def overruns(self) -> int:
        """Blocks that came after lost samples."""
        return int(np.count_nonzero(self.block_lost))

    def latency_ms(self) -> dict:
        """p50, p99 and max of the block-to-command latency (a block's last sample -> the
        command sent for it), ms; NaN without commands."""
        v = self.block_latency_ns[self.block_latency_ns >= 0].astype(np.float64) / 1e6
        if v.size == 0:
            return {"p50": math.nan, "p99": math.nan, "max": math.nan}
        p50, p99 = np.percentile(v, [50, 99])
        return {"p50": float(p50), "p99": float(p99), "max": float(v.max())}

    def summary(self) -> dict:
        """The run's numbers (JSON-friendly)."""
        return {"ticks": self.n_ticks, "blocks": int(self.block_row.size), "commands": int(self.command_row.size),
                "lost_samples": self.lost_samples, "overruns": self.overruns, "late_blocks": int(self.late_blocks),
                "block_to_command_ms": self.latency_ms(), "largest_position_age_ms": 1e3 * self.largest_position_age,
                "command_mode": self.command_mode, "command_interval_ms": 1e3 * self.command_interval,
                "rejected": int(self.status.get("rejected", 0)), "blocks_before_the_start": int(self.skipped),
                "lost_before_the_start": int(self.lost_before),
                "stopped": None if self.trip is None else {"cause": self.trip.cause, "detail": self.trip.detail}}

    def to_recording(self, metadata: dict | None = None) -> Recording:
        """The run as a :class:`~tactile_mirror.loop.Recording` (format 2, with its
        :class:`~tactile_mirror.loop.recording.RigTrace`); ``metadata["rig"]`` gets
        :meth:`summary`, merged with what ``metadata`` already has there."""
        meta = dict(metadata or {})
        rig = dict(self.summary())
        rig.update(meta.get("rig", {}))
        meta["rig"] = rig
        trace = RigTrace(block_row=self.block_row, block_index=self.block_index, block_lost=self.block_lost,
                         block_t_ns=self.block_t_ns, command_row=self.command_row, command_t_ns=self.command_t_ns,
                         command_x=self.command_x, aux=self.aux, aux_names=self.aux_names)
        return Recording(fs=self.fs, samples=self.samples, outputs=self.outputs, accepted=self.accepted,
                         stage_position=self.stage_position, config=self.config, x0=self.x0, metadata=meta,
                         rig=trace)


class RigRunner:
    """The loop on the rig (see the module notes).

    Parameters
    ----------
    pipeline : MirrorPipeline
    stage : StageDriver
        ``position``, ``move_to``, ``stop``; ``command_mode`` (default ``"per_tick"``),
        ``command_interval``, ``fault``, ``position_age`` where it has them.
    source : BlockSource
        Started by the caller (bring-up runs on the same acquisition).
    supervisor : Supervisor, optional
        Default: one over the stage's own limits with its default bounds.
    columns : sequence of int, optional
        The block's columns that are the pipeline's inputs, in its order (default: the first
        ``pipeline.n_inputs``).
    aux_columns, aux_names : sequence, optional
        Other columns to keep (e.g. the force sensor's), and their names.
    command : bool
        False: the stage is never commanded (a sensors-only run).
    command_interval : float
        Shortest interval between two commands, s (the configured rate; the driver's own
        ``command_interval`` bounds it too).
    on_block : callable, optional
        ``on_block(block, outputs, position)`` after each block (``outputs``: its rows of
        the outputs): a live view takes its values here; it must return quickly.
    rt_priority : int
        During :meth:`run`, every thread of the process at this real-time priority where the
        system permits it (0: none; :func:`~tactile_mirror.rig.realtime.raised_priority`).
    """

    def __init__(self, pipeline, stage, source, supervisor: Supervisor | None = None, *, columns=None,
                 aux_columns=(), aux_names=(), command: bool = True, command_interval: float = 0.0,
                 on_block=None, rt_priority: int = 0):
        for name in ("step", "process_block", "n_inputs", "n_outputs", "fs", "reset", "status"):
            if not hasattr(pipeline, name):
                raise TypeError(f"pipeline must have {name!r} (a MirrorPipeline), got {type(pipeline).__name__}")
        for name in ("move_to", "position", "stop"):
            if not hasattr(stage, name):
                raise TypeError(f"stage must have {name!r} (a stage driver), got {type(stage).__name__}")
        for name in ("read_block", "block_size", "fs"):
            if not hasattr(source, name):
                raise TypeError(f"source must have {name!r} (a BlockSource), got {type(source).__name__}")
        if not math.isclose(float(source.fs), float(pipeline.fs), rel_tol=1e-9):
            raise ValueError(f"the acquisition's {source.fs:g} Hz differs from the pipeline's {pipeline.fs:g} Hz")
        self.pipeline, self.stage, self.source = pipeline, stage, source
        self.supervisor = supervisor if supervisor is not None else Supervisor(stage, stage.limits, signals=False)
        self.columns = list(range(pipeline.n_inputs)) if columns is None else [int(c) for c in columns]
        if len(self.columns) != pipeline.n_inputs:
            raise ValueError(f"columns must name the pipeline's {pipeline.n_inputs} inputs, got {len(self.columns)}")
        self.aux_columns = [int(c) for c in aux_columns]
        self.aux_names = tuple(aux_names)
        if len(self.aux_names) != len(self.aux_columns):
            raise ValueError("aux_names must name every aux column")
        self.command = bool(command)
        self.command_interval = real_number(command_interval, "command_interval", unit="s", nonnegative=True)
        self.command_mode = getattr(stage, "command_mode", "per_tick")
        if self.command_mode not in ("per_tick", "per_block"):
            raise ValueError(f"stage.command_mode must be 'per_tick' or 'per_block', got {self.command_mode!r}")
        self.on_block = on_block
        self.rt_priority = integer(rt_priority, "rt_priority", 0, 99)

    def run(self, duration: float, x0: float | None = None, reset: bool = True, catch_up: bool = True,
            cues=()) -> RigResult:
        """Run for ``duration`` s of samples (whole blocks), from ``x0`` (default: the stage's
        position). Raises :class:`~tactile_mirror.rig.supervisor.RigError` (``partial``: the
        :class:`RigResult` so far) when the supervisor stopped the run.

        ``catch_up``: the blocks the acquisition already holds when the run starts (acquired
        while bring-up computed) are read first and not run; the run starts with the next
        block, on time. :attr:`RigResult.skipped` counts them (and samples lost before them,
        outside the run, are in the summary's ``lost_before_the_start``).

        ``cues``: ``(t, fn)`` pairs: ``fn()`` is called once, after the block whose last sample
        is ``t`` s or more into the run (e.g. telling the operator to start moving the finger
        once the law has armed).

        The cyclic garbage collector is off during the run (:func:`~tactile_mirror.rig.realtime.gc_paused`:
        a collection of the host's heap holds the loop and the stage driver up for tens of ms),
        and the process's threads run at ``rt_priority``."""
        duration = real_number(duration, "duration", unit="s", positive=True)
        with gc_paused(), raised_priority(rt_priority=self.rt_priority):
            return self._run(duration, x0, reset, catch_up, cues)

    def _run(self, duration: float, x0, reset: bool, catch_up: bool, cues) -> RigResult:
        pipe, stage, src, sup = self.pipeline, self.stage, self.source, self.supervisor
        fs, n = float(src.fs), int(src.block_size)
        n_blocks = max(1, math.ceil(round(duration * fs) / n))
        rows = n_blocks * n
        ni, no = pipe.n_inputs, pipe.n_outputs
        samples = np.empty((rows, ni))
        outputs = np.empty((rows, no))
        accepted = np.ones(rows, dtype=bool)
        pos = np.empty(rows)
        aux = np.empty((rows, len(self.aux_columns)))
        blocks = np.full((n_blocks, 6), -1, dtype=np.int64)   # row, index, lost, t_ns, read_ns, latency
        cmds_row = np.empty(n_blocks, dtype=np.int64)
        cmds_t = np.empty(n_blocks, dtype=np.int64)
        cmds_x = np.empty(n_blocks)
        cols, acols = self.columns, self.aux_columns
        contiguous = cols == list(range(cols[0], cols[0] + len(cols))) if cols else False
        per_tick = self.command_mode == "per_tick"
        step, process_block = pipe.step, pipe.process_block
        max_hold = int(pipe.config.get("max_hold_ticks", 1)) if hasattr(pipe, "config") else 1
        interval_ns = round(self.command_interval * 1e9)
        last_cmd = -(1 << 62)
        nb = nc = row = 0
        x_start = math.nan
        timeout = min(sup.comm_timeout, 1.0)

        def send(cmd: float, cmd_row: int) -> bool:
            """Command the stage and log it; False (the supervisor tripped) if the driver raised."""
            nonlocal last_cmd, nc
            try:
                stage.move_to(cmd)
            except Exception as exc:  # noqa: BLE001
                fault = getattr(stage, "fault", lambda: None)()
                if fault:   # (the driver latched its fault since the last check: that is the cause)
                    sup.trip(fault_cause(fault), f"the stage driver reports: {fault}")
                else:
                    sup.trip("controller error", f"stage.move_to({cmd!r}) raised {type(exc).__name__}: {exc}")
                return False
            last_cmd = time.monotonic_ns()
            cmds_row[nc], cmds_t[nc], cmds_x[nc] = cmd_row, last_cmd, cmd
            nc += 1
            return True

        def result() -> RigResult:
            b = blocks[:nb]
            return RigResult(fs=fs, samples=samples[:row], outputs=outputs[:row], accepted=accepted[:row],
                             stage_position=pos[:row], aux=aux[:row], aux_names=self.aux_names, block_row=b[:, 0],
                             block_index=b[:, 1], block_lost=b[:, 2], block_t_ns=b[:, 3], block_read_ns=b[:, 4],
                             block_latency_ns=b[:, 5], command_row=cmds_row[:nc], command_t_ns=cmds_t[:nc],
                             command_x=cmds_x[:nc], x0=x_start if math.isfinite(x_start) else 0.0,
                             config=pipe.config, command_mode=self.command_mode,
                             command_interval=max(self.command_interval, _driver_interval(stage)),
                             largest_position_age=sup.largest_age, late_blocks=sup.late_total,
                             trip=sup.tripped, status=dict(pipe.status), skipped=skipped,
                             lost_before=lost_before)

        skipped = lost_before = 0
        cues = sorted(((float(t), fn) for t, fn in cues), key=lambda c: c[0])
        try:
            while catch_up:
                try:
                    block = src.read_block(0.0)
                except TimeoutError:
                    break
                skipped += 1
                lost_before += block.lost
            p = stage.position()
            if sup.check_stage(p):
                raise RigError(sup.tripped, result())
            x_start = p if x0 is None else real_number(x0, "x0", unit="m")
            if reset:
                pipe.reset(x_start)
            waited_since = time.monotonic()
            pending = None   # (target, row, block index): a command the interval held back
            while nb < n_blocks:
                if pending is not None:
                    wait = (last_cmd + interval_ns - time.monotonic_ns()) / 1e9
                    try:   # a block that comes first replaces it
                        block = src.read_block(max(wait, 0.0))
                    except TimeoutError:
                        cmd, crow, cblock = pending
                        pending = None
                        if not send(cmd, crow):
                            break
                        blocks[cblock, 5] = last_cmd - blocks[cblock, 3]
                        continue
                    except (EOFError, Overrun, OSError):
                        pending = None
                        continue
                    pending = None
                else:
                    block = None
                try:
                    if block is None:
                        block = src.read_block(timeout)
                except TimeoutError:
                    if sup.check_timeout(time.monotonic() - waited_since):
                        break
                    continue
                except EOFError:
                    sup.trip("closed port", "the acquisition ended (the device stopped sending blocks)")
                    break
                except Overrun as exc:
                    sup.trip("overrun", str(exc))
                    break
                except OSError as exc:
                    sup.trip("closed port", f"the acquisition failed: {type(exc).__name__}: {exc}")
                    break
                t_read = time.monotonic_ns()
                waited_since = time.monotonic()
                stop = sup.check_block(block, t_read, late=self.command)   # (lateness matters to commands)
                if not stop:
                    try:
                        p = stage.position()
                    except Exception as exc:  # noqa: BLE001 (a driver fails any way it likes)
                        sup.trip("controller error", f"stage.position() raised {type(exc).__name__}: {exc}")
                        stop = True
                    else:
                        stop = sup.check_stage(p)
                # the block's ticks (also after a fault: every sample delivered is in the result)
                k = block.samples.shape[0]
                x = block.samples[:, cols[0]:cols[0] + len(cols)] if contiguous else block.samples[:, cols]
                x = np.ascontiguousarray(x)
                r0, r1 = row, row + k
                if per_tick:
                    for j in range(k):
                        step(x[j], outputs[r0 + j])
                        accepted[r0 + j] = pipe.last_accepted
                else:
                    out, acc = process_block(x, accepted=True)
                    outputs[r0:r1] = out
                    accepted[r0:r1] = acc
                samples[r0:r1] = x
                pos[r0:r1] = p if isinstance(p, float) else math.nan
                if acols:
                    aux[r0:r1] = block.samples[:, acols]
                blocks[nb, :5] = (r0, block.index, block.lost, block.t_ns, t_read)
                nb += 1
                row = r1
                if not stop:
                    status = pipe.status
                    if status["fault"]:
                        stop = sup.check_pipeline(status, _fault_time(accepted[:r1], max_hold, block, fs))
                if not stop and self.command:
                    cmd = float(outputs[r1 - 1, 0])
                    if sup.check_target(cmd):
                        break
                    now = time.monotonic_ns()
                    if now - last_cmd < interval_ns:
                        pending = (cmd, r1 - 1, nb - 1)
                    else:
                        if not send(cmd, r1 - 1):
                            break
                        blocks[nb - 1, 5] = last_cmd - block.t_ns
                if stop or sup.check_signal():
                    break
                if self.on_block is not None:
                    self.on_block(block, outputs[r0:r1], p)
                while cues and cues[0][0] * fs <= row:
                    cues.pop(0)[1]()
        except RigError:
            raise
        except KeyboardInterrupt:
            sup.trip("SIGINT", "KeyboardInterrupt in the loop")
        except Exception as exc:  # noqa: BLE001 (stop first, then say what it was)
            sup.trip("error", f"{type(exc).__name__}: {exc}")
            raise RigError(sup.tripped, result()) from exc
        if sup.tripped is not None:
            raise RigError(sup.tripped, result())
        return result()


def _driver_interval(stage) -> float:
    try:
        v = float(getattr(stage, "command_interval", 0.0) or 0.0)
    except (TypeError, ValueError):
        return 0.0
    return v if math.isfinite(v) and v > 0 else 0.0


def _fault_time(accepted: np.ndarray, max_hold: int, block, fs: float) -> int:
    """``monotonic_ns`` time of the sample at which the pipeline went into fault: the
    ``max_hold``-th of the rejected samples that end the rows (samples are ``1 / fs`` apart:
    a run that loses samples stops at the first loss)."""
    n = accepted.size
    good = np.flatnonzero(accepted)
    first_bad = good[-1] + 1 if good.size else 0
    tick = min(first_bad + max_hold - 1, n - 1)
    behind = (n - 1) - tick          # samples between it and the block's last
    return int(block.t_ns - round(behind * 1e9 / fs))
