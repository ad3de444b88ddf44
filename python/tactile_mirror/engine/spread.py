"""One way to spread a sweep over workers: :func:`run_tasks`.

Every big job of the library submits its items through here, so each gets the same
guarantees: results collected in item order whatever order they finish in, each task's
BLAS/OpenMP pools pinned, the build checked on an outside executor's workers before a
result is used, an error raised with the item it came from (or the sweep carried on and
the failures listed), results handed to a ``sink`` as they arrive (the driver need not
hold a sweep in memory), a progress bar.

Lost workers: dask reschedules the tasks of a worker that dies (its
``distributed.scheduler.allowed-failures``, 3 by default). The standard process pool
cannot: a dying worker breaks the whole pool, so the pool :func:`run_tasks` makes itself
(``workers=N``) is started again and the unfinished items resubmitted, up to ``retries``
times; an outside pool that breaks is an error naming the first unfinished item.
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import functools
import os
import threading
import warnings
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from tactile_mirror.engine.identity import BuildMismatch, build_identity, identity_differences
from tactile_mirror.engine.threads import pinned_threads

__all__ = ["ON_ERROR", "TaskError", "TaskFailure", "TaskResults", "open_executor", "run_tasks", "warm_workers"]

#: What a failed task does: stop the sweep, or carry on and list the failures at the end.
ON_ERROR = ("raise", "continue")


class TaskError(RuntimeError):
    """A task failed; ``index`` and ``item`` say which, ``__cause__`` is its own error."""

    def __init__(self, index: int, item: Any, error: BaseException):
        self.index, self.item, self.error = index, item, error
        super().__init__(f"task {index} failed on item {_brief(item)}: {type(error).__name__}: {error}")

    def __reduce__(self):
        return type(self), (self.index, self.item, self.error)


@dataclasses.dataclass(frozen=True)
class TaskFailure:
    """A task that failed in a sweep run with ``on_error="continue"``."""

    index: int
    item: Any
    error: BaseException

    def __str__(self) -> str:
        return f"task {self.index} ({_brief(self.item)}): {type(self.error).__name__}: {self.error}"


class TaskResults(list):
    """The results in item order (``None`` where a task failed or ``keep=False``);
    ``failures`` lists the tasks that failed, in item order."""

    failures: list[TaskFailure]


def _brief(item: Any, width: int = 120) -> str:
    text = repr(item)
    return text if len(text) <= width else text[:width - 3] + "..."


def run_task(fn: Callable, item: Any, threads: int, expected: dict | None, portable: bool) -> Any:
    """One task as a worker runs it: the build compared with ``expected`` (the driver's
    identity; ``None`` skips the check), the thread pools pinned to ``threads``, the
    baseline kernels when ``portable``, then ``fn(item)``."""
    if expected is not None:
        differences = identity_differences(expected, build_identity(), portable)
        if differences:
            raise BuildMismatch(differences, worker=f"worker {_worker_name()}")
    with pinned_threads(threads), _baseline_kernels(portable):
        return fn(item)


def _worker_name() -> str:
    import socket

    return f"{socket.gethostname()}:{os.getpid()}"


_baseline_lock = threading.Lock()
_baseline_state: dict = {"depth": 0, "before": False}


@contextlib.contextmanager
def _baseline_kernels(on: bool) -> Iterator[None]:
    """Hold the kernels to the baseline for the block, then restore the switch as it was
    (a worker started with ``TM_SIMD=baseline`` stays there). Blocks of a thread pool's
    tasks overlap: the first to start sets the switch, the last to end restores it."""
    if not on:
        yield
        return
    from tactile_mirror.kernels import baseline_in_use, use_baseline

    with _baseline_lock:
        if not _baseline_state["depth"]:
            _baseline_state["before"] = baseline_in_use()
            use_baseline(True)
        _baseline_state["depth"] += 1
    try:
        yield
    finally:
        with _baseline_lock:
            _baseline_state["depth"] -= 1
            if not _baseline_state["depth"]:
                use_baseline(_baseline_state["before"])


def _check_options(on_error, threads, workers, retries) -> None:
    if on_error not in ON_ERROR:
        raise ValueError(f"on_error must be one of {ON_ERROR}, got {on_error!r}")
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be a positive integer or None, got {workers!r}")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"retries must be a non-negative integer, got {retries!r}")


def _noop() -> None:
    return None


def _local_pool(workers: int, threads: int = 1) -> concurrent.futures.ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes (safe with threads in the parent), started now
    with the thread variables at ``threads``, so that no worker sizes its BLAS/OpenMP pools to the
    machine (the tasks pin them anyway; this spares the idle threads)."""
    import multiprocessing

    pool = concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        with pinned_threads(threads):  # a process starts at a submit while none is idle: start them all here
            started = [pool.submit(_noop) for _ in range(workers)]
        concurrent.futures.wait(started)
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    return pool


def run_tasks(fn: Callable[[Any], Any], items: Iterable[Any], *, executor: concurrent.futures.Executor | None = None,
              workers: int | None = None, sink: Callable[[int, Any], None] | None = None, ordered: bool = False,
              keep: bool = True, on_error: str = "raise", threads: int = 1, portable: bool = False,
              check_build: bool = True, retries: int = 2, chunk: int | str = 1,
              order: Iterable[int] | None = None, progress: bool = True, desc: str = "tasks") -> TaskResults:
    """``[fn(item) for item in items]``, spread over workers, with the same bits wherever it runs.

    ``fn`` must be picklable (a module-level function or a ``functools.partial`` of one)
    for anything but the serial run. Where it runs:

    - ``executor``: any :class:`concurrent.futures.Executor` (a thread or process pool,
      dask's ``Client.get_executor()``, ``mpi4py.futures``, loky). On a process or remote
      executor each task first checks its worker's :func:`build_identity` against this
      process's (``check_build``) and refuses with both sides named;
    - else ``workers=N`` (N > 1): a local pool of N spawned processes, shut down at the end
      (``workers`` is not used with an ``executor``);
    - else in this process, one item after another.

    Every task runs with its BLAS/OpenMP pools pinned to ``threads`` (1), whatever the
    parent's settings, so all of these give identical arrays. ``portable`` runs every task
    on the baseline kernels (:func:`tactile_mirror.kernels.use_baseline`, no AVX2+FMA; the
    switch is restored after the task), for workers whose CPUs differ; the kernel paths
    are then left out of the build check. It holds for the kernels built inside the task
    (a filter, detector or pad that ``fn`` makes), not for one built before and passed in
    with the item, which keeps the path it was built with: make the models inside ``fn``.

    ``sink(index, result)`` is called in this process as each result arrives (in item order
    with ``ordered=True``, holding back the early ones); with ``keep=False`` results are
    not kept once sunk. ``on_error="raise"`` raises :class:`TaskError` (item named, the
    task's error as its cause) at the first failure and cancels the rest;
    ``"continue"`` carries on, warns with the failures at the end and lists them in
    ``TaskResults.failures``. A build mismatch is always raised. ``retries``: how often a
    broken pool of our own is restarted. ``chunk``: items per task on workers (consecutive
    items; each still has its own result, error and sink call), so that short items do not
    pay a task's overhead each; the results do not depend on it. ``"auto"``: one item a task
    up to 127 items, then about 64 tasks, of at most 16 items each (for sweeps of many short
    items, such as scenes of a few seconds). ``order``: the item indices in the order their
    tasks are submitted (a permutation; default item order), e.g. the costliest first, so
    that no long task is left to run alone at the end; results, sinks and errors keep item
    order (not with ``chunk`` > 1). ``progress`` shows a bar labelled ``desc``.
    """
    if not callable(fn):
        raise TypeError(f"fn must be callable, got {type(fn).__name__}")
    if executor is not None and not callable(getattr(executor, "submit", None)):
        raise TypeError(f"executor must be a concurrent.futures.Executor (with submit), got {type(executor).__name__}")
    if sink is not None and not callable(sink):
        raise TypeError(f"sink must be callable or None, got {type(sink).__name__}")
    _check_options(on_error, threads, workers, retries)
    if chunk != "auto" and (isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1):
        raise ValueError(f"chunk must be a positive integer or 'auto', got {chunk!r}")
    items = list(items)
    if chunk == "auto":
        chunk = max(1, min(16, len(items) // 64))
    if order is not None:
        order = list(order)
        if sorted(order) != list(range(len(items))):
            raise ValueError(f"order must be a permutation of the {len(items)} item indices")
        if chunk > 1:
            raise ValueError("order and chunk > 1 do not go together: a chunk's items are consecutive")
    results = TaskResults([None] * len(items))
    results.failures = []
    if not items:
        return results

    # Pinned in this process too, for the whole sweep: a task on a thread of this process
    # cannot pin the BLAS pool itself while this thread holds another limit (OpenBLAS keeps
    # the one this thread set), so the driver's limit must already be the tasks' one.
    with contextlib.ExitStack() as stack:
        stack.enter_context(pinned_threads(threads))
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = stack.enter_context(tqdm(total=len(items), desc=desc, unit="task"))
        collector = _Collector(items, results, sink, ordered, keep, on_error, bar)
        serial = executor is None and (workers is None or workers == 1)
        tasks, task_fn = items, fn
        if chunk > 1 and not serial:
            tasks = [items[i:i + chunk] for i in range(0, len(items), chunk)]
            task_fn = functools.partial(_each, fn)
            collector = _ChunkCollector(collector, chunk)
        if serial:
            for k, item in enumerate(items):
                try:
                    value = run_task(fn, item, threads, None, portable)
                except Exception as e:  # noqa: BLE001  (reported with its item)
                    collector.failed(k, e)
                else:
                    collector.done(k, value)
        elif executor is not None:
            expected = build_identity() if check_build and not isinstance(
                executor, concurrent.futures.ThreadPoolExecutor) else None
            try:
                _submit_all(executor, task_fn, tasks, order or range(len(tasks)), threads, expected, portable,
                            collector)
            except BrokenProcessPool as e:
                k, item = collector.first_pending()
                raise TaskError(k, item, e) from e
        else:
            _run_on_own_pool(workers, task_fn, tasks, threads, portable, retries, collector, order)
    collector.finish()
    return results


def _submit_all(executor, fn, items, indices, threads, expected, portable, collector) -> None:
    futures: dict = {}
    try:
        for k in indices:
            futures[executor.submit(run_task, fn, items[k], threads, expected, portable)] = k
        for f in concurrent.futures.as_completed(futures):
            k = futures.pop(f)
            try:
                value = f.result()
            except BuildMismatch:
                raise
            except BrokenProcessPool:
                futures[f] = k
                _salvage(futures, collector)
                raise
            except Exception as e:  # noqa: BLE001
                collector.failed(k, e)
            else:
                collector.done(k, value)
    finally:
        for f in futures:
            f.cancel()


def _salvage(futures: dict, collector: _Collector) -> None:
    """Collect the results that finished before a pool broke (they are not computed again)."""
    for f, k in list(futures.items()):
        if f.done() and not f.cancelled() and f.exception() is None:
            del futures[f]
            collector.done(k, f.result())


def _run_on_own_pool(workers, fn, items, threads, portable, retries, collector, order=None) -> None:
    expected = build_identity()
    for attempt in range(retries + 1):
        pending = collector.pending()
        if order is not None:
            left = set(pending)
            pending = [k for k in order if k in left]
        pool = _local_pool(min(workers, len(pending)), threads)
        try:
            _submit_all(pool, fn, items, pending, threads, expected, portable, collector)
            return
        except BrokenProcessPool as e:
            if attempt == retries:
                k, item = collector.first_pending()
                raise TaskError(k, item, e) from e
            warnings.warn(f"a worker process died; restarting the pool for the {len(collector.pending())} "
                          f"unfinished tasks ({attempt + 1} of {retries} retries)", RuntimeWarning, stacklevel=3)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


class _Collector:
    """Puts each result in its place, feeds the sink, and applies the error policy."""

    def __init__(self, items, results, sink, ordered, keep, on_error, bar):
        self.items, self.results, self.sink, self.ordered, self.keep = items, results, sink, ordered, keep
        self.on_error, self.bar = on_error, bar
        self.finished = [False] * len(items)
        self.held: dict[int, Any] = {}
        self.next_sink = 0

    def pending(self) -> list[int]:
        return [k for k, done in enumerate(self.finished) if not done]

    def first_pending(self) -> tuple[int, Any]:
        k = self.pending()[0]
        return k, self.items[k]

    def done(self, k: int, value: Any) -> None:
        self.finished[k] = True
        if self.keep:
            self.results[k] = value
        if self.sink is not None:
            if self.ordered:
                self.held[k] = value
                self._drain()
            else:
                self.sink(k, value)
        self._tick()

    def failed(self, k: int, error: Exception) -> None:
        if self.on_error == "raise":
            raise TaskError(k, self.items[k], error) from error
        self.finished[k] = True
        self.results.failures.append(TaskFailure(k, self.items[k], error))
        if self.ordered:
            self.held[k] = _FAILED
            self._drain()
        self._tick()

    def _drain(self) -> None:
        while self.next_sink in self.held:
            value = self.held.pop(self.next_sink)
            if value is not _FAILED:
                self.sink(self.next_sink, value)
            self.next_sink += 1

    def _tick(self) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def finish(self) -> None:
        self.results.failures.sort(key=lambda f: f.index)
        if self.results.failures:
            listed = "\n  ".join(map(str, self.results.failures))
            warnings.warn(f"{len(self.results.failures)} of {len(self.items)} tasks failed:\n  {listed}",
                          RuntimeWarning, stacklevel=3)


_FAILED = object()


def _each(fn: Callable, group: list) -> list[tuple[bool, Any]]:
    """A chunk's task: ``(True, fn(item))`` or ``(False, its error)`` for each item, in order."""
    out = []
    for item in group:
        try:
            out.append((True, fn(item)))
        except Exception as e:  # noqa: BLE001  (reported with its item by the driver)
            out.append((False, e))
    return out


class _ChunkCollector:
    """The item collector seen by tasks of ``size`` consecutive items each."""

    def __init__(self, items: _Collector, size: int):
        self.items, self.size = items, size

    def _indices(self, g: int) -> range:
        return range(g * self.size, min((g + 1) * self.size, len(self.items.finished)))

    def pending(self) -> list[int]:
        return sorted({k // self.size for k in self.items.pending()})

    def first_pending(self) -> tuple[int, Any]:
        return self.items.first_pending()

    def done(self, g: int, values: list) -> None:
        for k, (ok, value) in zip(self._indices(g), values):
            if self.items.finished[k]:
                continue
            if ok:
                self.items.done(k, value)
            else:
                self.items.failed(k, value)

    def failed(self, g: int, error: Exception) -> None:
        for k in self._indices(g):
            if not self.items.finished[k]:
                self.items.failed(k, error)

    def finish(self) -> None:
        self.items.finish()


@contextlib.contextmanager
def open_executor(scheduler: str | None = None, workers: int | None = None
                  ) -> Iterator[concurrent.futures.Executor | None]:
    """The executor the command line's ``--scheduler ADDRESS`` / ``--workers N`` ask for:
    a dask client's executor for a scheduler address (dask is needed then), a local
    process pool for N > 1 workers, or ``None`` (serial) for neither; closed at the end."""
    if scheduler is not None and workers is not None:
        raise ValueError("give scheduler or workers, not both")
    if scheduler is not None:
        try:
            from dask.distributed import Client
        except ImportError as e:
            raise ImportError("--scheduler needs dask.distributed: pip install 'dask[distributed]'") from e
        with Client(scheduler) as client:
            yield client.get_executor()
        return
    _check_options("raise", 1, workers, 0)
    if workers is None or workers == 1:
        yield None
        return
    pool = _local_pool(workers)
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def warm_workers(executor: concurrent.futures.Executor | None, fn: Callable, *args: Any, copies: int | None = None
                 ) -> list[concurrent.futures.Future]:
    """Submit ``copies`` calls ``fn(*args)`` to ``executor`` and return at once, so that its
    workers pay their first-task costs (imports, models built once per process) while this
    process still prepares the sweep. ``copies``: the pool's size where the executor says
    (the standard pools), else the machine's core count. Failures are left in the returned
    futures (a real task meets the same cause and reports it); ``None`` does nothing."""
    if executor is None:
        return []
    if copies is None:
        copies = getattr(executor, "_max_workers", None) or os.cpu_count() or 1
    # as a task runs: with its thread pools pinned (a model it builds and keeps is the one
    # the tasks would have built)
    call = functools.partial(_call, fn, args)
    return [executor.submit(run_task, call, None, 1, None, False) for _ in range(copies)]


def _call(fn: Callable, args: tuple, _item: Any) -> Any:
    return fn(*args)
