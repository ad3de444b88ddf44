"""BLAS and OpenMP thread pools pinned for a block of work.

A threaded BLAS may sum a product in another order than a serial one, so a result that
must not depend on where it ran is computed with a fixed number of threads. The pools
are limited through threadpoolctl (the libraries already loaded in this process) and
through the thread-count variables (libraries loaded inside the block, child processes).

The pools belong to the process, not to a thread: the blocks of a thread pool's tasks
share one limit, set by the first block to start and restored when the last one ends.
"""
from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator

__all__ = ["THREAD_VARIABLES", "pinned_threads"]

#: The environment variables that size the BLAS and OpenMP thread pools.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
                    "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")

_lock = threading.Lock()
_active: dict = {"depth": 0, "threads": 0, "limits": None, "saved": {}}


def _enter(threads: int) -> None:
    with _lock:
        if _active["depth"]:
            if threads != _active["threads"]:
                raise ValueError(f"threads={threads}: this process's thread pools are already pinned to "
                                 f"{_active['threads']} by a block still running (the pools are process-wide)")
            _active["depth"] += 1
            return
        from threadpoolctl import threadpool_limits

        _active["saved"] = {name: os.environ.get(name) for name in THREAD_VARIABLES}
        os.environ.update(dict.fromkeys(THREAD_VARIABLES, str(threads)))
        _active["limits"] = threadpool_limits(limits=threads)
        _active.update(depth=1, threads=threads)


def _exit() -> None:
    with _lock:
        _active["depth"] -= 1
        if _active["depth"]:
            return
        _active["limits"].restore_original_limits()
        for name, value in _active["saved"].items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        _active.update(threads=0, limits=None, saved={})


@contextlib.contextmanager
def pinned_threads(threads: int = 1) -> Iterator[None]:
    """Run the block with every BLAS/OpenMP pool of this process limited to ``threads``
    (a positive integer), then restore the pools and the variables as they were.

    Blocks may overlap (the tasks of a thread pool) when they ask for the same count; a
    different count while a block runs is a ``ValueError``.
    """
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    _enter(threads)
    try:
        yield
    finally:
        _exit()
