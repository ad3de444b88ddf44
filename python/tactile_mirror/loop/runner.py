"""Run a pipeline and a stage at a fixed rate from a sample source.

:class:`LoopRunner` ticks ``source -> pipeline -> stage`` at the pipeline's rate,
either paced in real time (busy-waiting on ``time.perf_counter_ns`` between ticks,
as a DAQ-clocked loop would) or as fast as possible in simulated time. Every tick's
latency (sample handed over -> stage command issued) is measured; the result gives
percentiles and overrun counts, and can be saved as a :class:`~tactile_mirror.loop.Recording`.

A source is any object with ``read(stage_position, t) -> ndarray | None``
(float64, shape ``(pipeline.n_inputs,)``; None ends the run): :class:`ArraySource`
plays samples from an array, the closed-loop experiment plays the simulated pad.

Hardware in the loop without the hardware: with ``realtime=True`` and a source that
simulates the finger on the FEM pad (:class:`~tactile_mirror.loop.scene.PlantSource`
over :class:`~tactile_mirror.contact.plants.FemPad`, every ridge stepped by one
compiled call), a real stage driver, or a C program through ``tm.h``
(:class:`~tactile_mirror.loop.capi.CPipeline`), runs against the simulated pad at the
pipeline's rate. The whole tick (plant + pipeline + stage) must then fit the period:
``tick_ns`` and :meth:`LoopResult.tick_percentiles` report it, ``overruns`` counts the
ticks that ended after their deadline.
"""
from __future__ import annotations

import math
import numbers
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from tactile_mirror.checks import real_number
from tactile_mirror.loop.recording import Recording

__all__ = ["ArraySource", "LoopResult", "LoopRunner", "StageError"]


class ArraySource:
    """Samples from an array of shape (n, n_inputs), one row per tick."""

    def __init__(self, samples):
        a = np.asarray(samples)
        if a.dtype.kind not in "biuf" or a.ndim != 2:
            raise ValueError(f"samples must be a real array of shape (n, n_inputs), got {a.dtype} {a.shape}")
        self.samples = np.ascontiguousarray(a, dtype=np.float64)
        self.i = 0

    def read(self, stage_position: float, t: float):
        if self.i >= len(self.samples):
            return None
        row = self.samples[self.i]
        self.i += 1
        return row


@dataclass
class LoopResult:
    """What a run produced (arrays of length ``n``, the ticks run).

    Attributes
    ----------
    t : ndarray
        Tick times, s (``k / fs``).
    samples : ndarray, (n, n_inputs)
    outputs : ndarray, (n, n_outputs)
        The pipeline's outputs (``x_cmd, v_cmd, y_slip_0, y_non_0, y_pred_0, ...``).
    accepted : ndarray of bool
    stage_position : ndarray
        Stage position read at each tick (before the command), m.
    latency_ns : ndarray of int64
        Sample handed over -> stage command returned, per tick.
    tick_ns : ndarray of int64
        Work of the whole tick: source read (the simulated plant, if any) + pipeline
        step + stage command, per tick. What must fit the period in a paced run.
    overruns : int
        Ticks that ended after their deadline (real-time runs) or whose latency
        exceeded the period (simulated-time runs).
    late_starts : int
        Real-time runs: ticks that started more than one period late.
    fs : float
    realtime : bool
    x0 : float
    """

    t: np.ndarray
    samples: np.ndarray
    outputs: np.ndarray
    accepted: np.ndarray
    stage_position: np.ndarray
    latency_ns: np.ndarray
    overruns: int
    late_starts: int
    fs: float
    realtime: bool
    x0: float = 0.0
    status: dict = field(default_factory=dict)
    tick_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @staticmethod
    def _percentiles(ns: np.ndarray) -> dict:
        v = ns.astype(np.float64) / 1e3
        if v.size == 0:
            return {"p50": math.nan, "p99": math.nan, "p99.9": math.nan, "max": math.nan}
        p50, p99, p999 = np.percentile(v, [50, 99, 99.9])
        return {"p50": float(p50), "p99": float(p99), "p99.9": float(p999), "max": float(v.max())}

    def latency_percentiles(self) -> dict:
        """p50, p99, p99.9 and max of the tick latency, microseconds."""
        return self._percentiles(self.latency_ns)

    def tick_percentiles(self) -> dict:
        """p50, p99, p99.9 and max of the whole tick's work (:attr:`tick_ns`), microseconds."""
        return self._percentiles(self.tick_ns)

    def to_recording(self, config: dict, metadata: dict | None = None) -> Recording:
        """The run as a :class:`Recording` (``config``: the pipeline's :attr:`config`)."""
        meta = {"realtime": self.realtime, "overruns": int(self.overruns), "late_starts": int(self.late_starts),
                "latency_us": self.latency_percentiles(), "tick_us": self.tick_percentiles()}
        meta.update(metadata or {})
        return Recording(fs=self.fs, samples=self.samples, outputs=self.outputs, accepted=self.accepted,
                         stage_position=self.stage_position, config=config, x0=self.x0, metadata=meta)


class StageError(RuntimeError):
    """The stage driver failed during :meth:`LoopRunner.run`: a driver call raised (chained as
    ``__cause__``) or ``stage.position()`` returned what is not a finite real number.

    The stage has been stopped (``stage.stop()``) before this is raised.

    Attributes
    ----------
    partial : LoopResult
        The ticks completed before the failure (possibly none): nothing recorded is lost.
    """

    def __init__(self, message: str, partial: LoopResult | None = None):
        super().__init__(message)
        self.partial = partial


class LoopRunner:
    """Tick ``source -> pipeline -> stage`` at the pipeline's rate.

    Parameters
    ----------
    pipeline : MirrorPipeline
        Anything with ``step(x, out) -> x_cmd``, ``n_inputs``, ``n_outputs``, ``fs``,
        ``reset(x0)`` (also the C ABI wrapper :class:`~tactile_mirror.loop.capi.CPipeline`).
    stage : Stage
        The stage; if it has ``advance(dt)`` (a simulated stage) it is advanced by
        one period after each tick. Its ``stop()`` is called when a run ends with an
        exception; a failing driver call ends the run with :class:`StageError`, which
        keeps the ticks run so far.
    source : object with ``read(stage_position, t)``
    realtime : bool
        Pace ticks on the wall clock (busy wait). False: simulated time, as fast as
        the source allows.
    command : bool
        Send the command to the stage (``move_to``) every tick. False: open loop,
        the stage is never commanded.
    """

    def __init__(self, pipeline, stage, source, realtime: bool = False, command: bool = True):
        for name in ("step", "n_inputs", "n_outputs", "fs", "reset"):
            if not hasattr(pipeline, name):
                raise TypeError(f"pipeline must have {name!r} (a MirrorPipeline), got {type(pipeline).__name__}")
        for name in ("move_to", "position"):
            if not hasattr(stage, name):
                raise TypeError(f"stage must have {name!r} (the Stage protocol), got {type(stage).__name__}")
        if not hasattr(source, "read"):
            raise TypeError(f"source must have a read(stage_position, t) method, got {type(source).__name__}")
        self.pipeline = pipeline
        self.stage = stage
        self.source = source
        self.realtime = bool(realtime)
        self.command = bool(command)

    def run(self, n_ticks: int | None = None, duration: float | None = None, x0: float | None = None,
            reset: bool = True) -> LoopResult:
        """Run until ``n_ticks`` ticks (or ``duration`` s) or the end of the source.

        Parameters
        ----------
        n_ticks : int, optional
        duration : float, optional
            Seconds; ``n_ticks = round(duration * fs)``. One of the two is required.
        x0 : float, optional
            Start position for the controller, m; default: the stage's position.
        reset : bool
            Reset the pipeline first (default).

        Raises
        ------
        StageError
            A stage driver call (``position``, ``move_to``, ``advance``) raised (the
            driver's exception is chained as ``__cause__``), or ``stage.position()``
            returned what is not a finite real number (NaN, inf, None, a string, an
            array, a bool). The stage has been stopped; the error's ``partial`` is the
            :class:`LoopResult` of the ticks completed before the failure.

        Notes
        -----
        Whenever a run ends with an exception (a driver error, the source or the
        pipeline raising, Ctrl-C), ``stage.stop()`` is called before the exception
        propagates; errors other than the driver's propagate unchanged. A run that
        ends normally leaves the stage on its last target (a following run with
        ``reset=False`` continues from there).
        """
        fs = float(self.pipeline.fs)
        if (n_ticks is None) == (duration is None):
            raise ValueError("give exactly one of n_ticks and duration")
        if duration is not None:
            duration = real_number(duration, "duration", unit="s", positive=True)
            n_ticks = round(duration * fs)
            if n_ticks < 1:
                raise ValueError(f"duration must last at least one tick (1 / {fs:g} s), got {duration!r} s")
        if isinstance(n_ticks, bool) or not isinstance(n_ticks, numbers.Integral) or n_ticks < 1:
            raise ValueError(f"n_ticks must be a positive integer, got {n_ticks!r}")
        if x0 is not None:
            x0 = real_number(x0, "x0", unit="m")
        n = int(n_ticks)
        pipe, stage, source = self.pipeline, self.stage, self.source
        ni, no = pipe.n_inputs, pipe.n_outputs
        samples = np.empty((n, ni))
        outputs = np.empty((n, no))
        accepted = np.empty(n, dtype=bool)
        pos = np.empty(n)
        lat = np.empty(n, dtype=np.int64)
        tick = np.empty(n, dtype=np.int64)
        out = np.zeros(no)
        period = 1.0 / fs
        period_ns = round(1e9 / fs)
        advance = getattr(stage, "advance", None)
        step = pipe.step
        position = stage.position
        move = stage.move_to if self.command else None
        clock = time.perf_counter_ns
        overruns = late = 0
        x_start = math.nan
        done = 0  # ticks completed (recorded)

        def result(k, overruns, late, x_start) -> LoopResult:  # the first k ticks
            status = dict(pipe.status) if hasattr(pipe, "status") else {}
            return LoopResult(t=np.arange(k) * period, samples=samples[:k], outputs=outputs[:k],
                              accepted=accepted[:k], stage_position=pos[:k], latency_ns=lat[:k],
                              overruns=int(overruns), late_starts=int(late), fs=fs, realtime=self.realtime,
                              x0=x_start, status=status, tick_ns=tick[:k])

        try:
            if x0 is None:
                try:
                    p = position()
                except Exception as exc:
                    raise _DriverFailure("stage.position() raised before the first tick", exc) from exc
                x_start = _checked_position(p, -1)
            else:
                x_start = x0
            if reset:
                pipe.reset(x_start)
            t_next = clock() + period_ns
            for k in range(n):
                if self.realtime:
                    while True:  # busy wait: sleep() cannot hold a 100 us period
                        now = clock()
                        if now >= t_next - period_ns:
                            break
                    if now > t_next:
                        late += 1
                t_start = clock()
                try:
                    p = position()
                except Exception as exc:
                    raise _DriverFailure(f"stage.position() raised at tick {k}", exc) from exc
                if not (isinstance(p, float) and p - p == 0.0):  # (inline: a finite float passes here)
                    p = _checked_position(p, k)
                x = source.read(p, k * period)
                if x is None:
                    break
                t0 = clock()
                cmd = step(x, out)
                if move is not None:
                    try:
                        move(cmd)
                    except Exception as exc:
                        raise _DriverFailure(f"stage.move_to({cmd!r}) raised at tick {k}", exc) from exc
                t1 = clock()
                lat[k] = t1 - t0
                tick[k] = t1 - t_start
                if self.realtime:
                    overruns += t1 > t_next
                    t_next += period_ns
                else:
                    overruns += (t1 - t0) > period_ns
                samples[k] = x
                outputs[k] = out
                accepted[k] = getattr(pipe, "last_accepted", True)
                pos[k] = p
                done = k + 1
                if advance is not None:
                    try:
                        advance(period)
                    except Exception as exc:
                        raise _DriverFailure(f"stage.advance({period!r}) raised at tick {k}", exc) from exc
        except _DriverFailure as failure:
            stop_error = _stop(stage)
            msg = f"{failure.what}: {failure.detail}; the stage was stopped, {done} tick(s) kept in .partial"
            if stop_error is not None:
                msg += f" (stage.stop() failed too: {type(stop_error).__name__}: {stop_error})"
            raise StageError(msg, result(done, overruns, late, x_start)) from failure.__cause__
        except BaseException as exc:
            stop_error = _stop(stage)
            if stop_error is not None:
                warnings.warn(f"stage.stop() failed after {type(exc).__name__} at tick {done}: "
                              f"{type(stop_error).__name__}: {stop_error}", RuntimeWarning, stacklevel=2)
            raise
        return result(done, overruns, late, x_start)


class _DriverFailure(Exception):
    """Internal: a stage driver call failed (``what``), raised inside :meth:`LoopRunner.run`."""

    def __init__(self, what: str, cause: BaseException | None = None, detail: str | None = None):
        super().__init__(what)
        self.what = what
        self.detail = detail if detail is not None else f"{type(cause).__name__}: {cause}"


def _checked_position(value, tick: int) -> float:
    """``stage.position()``'s return at ``tick`` (-1: before the first) as a float: a finite real
    number (:func:`~tactile_mirror.checks.real_number`: int, float, numpy real scalar; not a
    bool, a string, an array, None), else :class:`_DriverFailure`. The tick loop calls it
    only for what is not a finite float."""
    try:
        return real_number(value, "stage.position()", unit="m")
    except (TypeError, ValueError):
        raise _DriverFailure(f"stage.position() returned {value!r} ({type(value).__name__}) {_when(tick)}",
                             detail="a position must be a finite real number, m") from None


def _when(tick: int) -> str:
    return "before the first tick" if tick < 0 else f"at tick {tick}"


def _stop(stage) -> BaseException | None:
    """``stage.stop()`` if the stage has one; the exception it raised, if any."""
    stop = getattr(stage, "stop", None)
    if stop is None:
        return None
    try:
        stop()
    except Exception as exc:  # noqa: BLE001 (a driver fails any way it likes; the caller reports it)
        return exc
    return None
