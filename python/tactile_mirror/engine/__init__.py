"""Spreading big jobs over workers with the same bits wherever they run.

Every sweep of the library (scene simulation, the detector build, the envelope, the bench
studies) goes through :func:`run_tasks`: items are submitted to any
:class:`concurrent.futures.Executor` (the standard pools, dask's ``Client.get_executor()``,
``mpi4py.futures``, loky) or run in this process, collected in order, each task with its
BLAS/OpenMP thread pools pinned (:func:`pinned_threads`) and, on an outside executor, run
only on a worker whose build matches this one (:func:`build_identity`); in the portable
mode every task runs the baseline kernels. Results can be kept in a
:class:`ResultStore`, a folder shared by every machine of a cluster, one file per result.
See ``docs/cluster.md``.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from tactile_mirror._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "BuildMismatch": "identity", "build_identity": "identity", "identity_differences": "identity",
    "task_identity": "identity",
    "TaskError": "spread", "TaskFailure": "spread", "TaskResults": "spread", "open_executor": "spread",
    "run_tasks": "spread", "warm_workers": "spread",
    "ResultStore": "store", "StoreWarning": "store",
    "pinned_threads": "threads",
}, submodules=("identity", "spread", "store", "threads"))

if TYPE_CHECKING:
    from tactile_mirror.engine import identity, spread, store, threads
    from tactile_mirror.engine.identity import (
        BuildMismatch,
        build_identity,
        identity_differences,
        task_identity,
    )
    from tactile_mirror.engine.spread import (
        TaskError,
        TaskFailure,
        TaskResults,
        open_executor,
        run_tasks,
        warm_workers,
    )
    from tactile_mirror.engine.store import ResultStore, StoreWarning
    from tactile_mirror.engine.threads import pinned_threads
