"""The detector build's scene sets: simulated once, kept in a cache folder, one file per scene.

:func:`simulate_scenes` simulates a list of scenes; with a cache folder it reads the
scenes simulated before (by this build of the library: the file names hash each scene's
content and the build, :class:`tactile_mirror.engine.ResultStore`) and simulates only
the others, through :func:`tactile_mirror.engine.run_tasks`, each result written to the
folder as it arrives. A sweep stopped half-way (Ctrl-C, a crash, a lost cluster) keeps
what it finished, sets that share scenes share their files, and any number of machines
may share the folder. :func:`simulate_cached` does this for the random scene set
``scenes.random(n, seed=seed, **kwargs)``.

The folder: ``cache_dir``, else the environment variable ``TM_CACHE_DIR`` if set, else
none (nothing is kept); its size limit ``TM_CACHE_LIMIT`` (default 10 GiB, the files used
longest ago go first). See ``docs/cluster.md``.
"""
from __future__ import annotations

import os

__all__ = ["random_scenes", "simulate_cached", "simulate_scenes"]

# what a file holds: the result of simulate() with its default options
_TASK = "simulate(progress=False, stepping='auto', backend='cpp')"


def _store(cache_dir):
    """The result store of ``cache_dir`` (checked now, before anything is simulated), or None."""
    from tactile_mirror.engine.store import FOLDER_VARIABLE, ResultStore

    if cache_dir is None:
        cache_dir = os.environ.get(FOLDER_VARIABLE) or None
        if cache_dir is None:
            return None
    try:
        folder = os.fspath(cache_dir)
    except TypeError:
        raise TypeError(f"cache_dir must be a path (str or os.PathLike), got {cache_dir!r}") from None
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise NotADirectoryError(f"cache_dir {folder!r} is a file, not a folder")
    store = ResultStore(folder)
    try:
        store.check()
    except OSError as exc:
        raise type(exc)(f"cache_dir {folder!r} cannot hold the scene cache: {exc}") from exc
    return store


def simulate_scenes(scenes, progress: bool = True, executor=None, workers: int | None = None, *,
                    cache_dir=None, portable: bool = False) -> list:
    """Simulate ``scenes`` (an iterable of :class:`~tactile_mirror.scenes.Scene`) with
    :func:`tactile_mirror.simulate`'s defaults, reading and keeping them in ``cache_dir``.

    Parameters
    ----------
    scenes : iterable of Scene
    progress : bool
        Show a bar over the scenes simulated.
    executor : concurrent.futures.Executor, optional
        Where to simulate (a process pool, dask's ``Client.get_executor()``, ...).
    workers : int, optional
        Without ``executor``: a local pool of this many processes (1: in this process).
        Default: one per core (at most one per scene), or in this process when one scene
        is to be simulated.
    cache_dir : path, optional
        The cache folder (see the module notes); checked before anything is simulated.
    portable : bool
        Run the baseline kernels in every task (workers whose CPUs differ; see
        :func:`tactile_mirror.engine.run_tasks`). Kept apart from the other results.

    Returns the list of :class:`~tactile_mirror.contact.simulation.SimulationResult`, in the
    scenes' order, each with its scene (the one given, for the results read back).
    """
    import functools

    from tactile_mirror.contact import simulation
    from tactile_mirror.contact.result_arrays import result_arrays, result_bounds, result_from_arrays
    from tactile_mirror.engine import run_tasks, task_identity
    from tactile_mirror.scenes import Scene

    scenes = list(scenes)
    for k, s in enumerate(scenes):
        if not isinstance(s, Scene):
            raise TypeError(f"scenes[{k}] must be a Scene, got {type(s).__name__}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be a positive integer or None, got {workers!r}")
    store = _store(cache_dir)
    results: list = [None] * len(scenes)
    identity = task_identity(bool(portable)) if store is not None else None
    if store is not None:
        for k, s in enumerate(scenes):
            results[k] = store.load(f"{_TASK} {s.content_key}", identity, result_bounds(s),
                                    functools.partial(result_from_arrays, s))
    missing = [k for k, r in enumerate(results) if r is None]
    if not missing:
        return results

    def keep(j, result):
        k = missing[j]
        result.scene = scenes[k]  # (an equal copy came back from a worker)
        results[k] = result
        if store is not None:
            arrays, meta = result_arrays(result)
            try:
                store.save(f"{_TASK} {scenes[k].content_key}", identity, arrays, meta)
            except OSError as exc:  # a full or read-only disk costs the cache, not the sweep
                import warnings

                from tactile_mirror.engine.store import StoreWarning

                warnings.warn(f"scene {k} not cached: {exc}", StoreWarning, stacklevel=2)

    if executor is None and workers is None:
        workers = min(len(missing), os.cpu_count() or 1)
    task = functools.partial(simulation.simulate, progress=False)
    run_tasks(task, [scenes[k] for k in missing], executor=executor, workers=workers, sink=keep, keep=False,
              chunk="auto", progress=progress, desc="simulate", portable=bool(portable))
    return results


def simulate_cached(n: int, seed: int, kwargs: dict, cache_dir=None, progress: bool = True, executor=None,
                    workers: int | None = None, *, portable: bool = False) -> list:
    """``simulate_scenes(scenes.random(n, seed=seed, **kwargs))``, the scenes read from and
    kept in ``cache_dir`` (see the module notes; ``None``: ``TM_CACHE_DIR`` if set, else no
    cache). Only the scenes not in the cache are simulated, on ``executor`` or ``workers``
    processes (:func:`simulate_scenes`); a file that cannot be used (damaged, truncated,
    foreign, another build's) is a miss with a warning, simulated again and replaced."""
    if not isinstance(kwargs, dict):
        raise TypeError(f"kwargs must be a dict of scenes.random options, got {type(kwargs).__name__}")
    return simulate_scenes(random_scenes(n, seed, **kwargs), progress, executor, workers, cache_dir=cache_dir,
                           portable=portable)


def random_scenes(n: int, seed: int, **kwargs) -> list:
    """The scene set ``tactile_mirror.scenes.random(n, seed=seed, **kwargs)``: ``n`` random
    contact scenes (a list of :class:`~tactile_mirror.scenes.Scene`), drawn with ``seed``
    from the ranges ``kwargs`` give (the rest at ``scenes.random``'s defaults)."""
    from tactile_mirror import scenes

    return scenes.random(n, seed=seed, **kwargs)
