"""The detector build's scene sets: simulated once, kept in a cache folder between builds.

:func:`simulate_scenes` simulates a list of scenes (in processes when
``tactile_mirror.simulate_many`` is there); :func:`simulate_cached` simulates the random
scene set ``scenes.random(n, seed=seed, **kwargs)`` and keeps it in a pickle file named by
:func:`cache_key`, so a second build with the same scene options reads it back.
"""
from __future__ import annotations

import numpy as np

__all__ = ["cache_key", "random_scenes", "simulate_cached", "simulate_scenes"]


def simulate_scenes(scenes, progress: bool = True, executor=None) -> list:
    """Simulate ``scenes`` (an iterable of :class:`~tactile_mirror.scenes.Scene`): with
    ``tactile_mirror.simulate_many`` (processes, on ``executor`` if given) when there is more
    than one and it is available, else one after the other; ``progress`` shows a bar.

    Returns the list of :class:`~tactile_mirror.contact.simulation.SimulationResult`, in the
    scenes' order.
    """
    import tactile_mirror

    scenes = list(scenes)
    many = getattr(tactile_mirror, "simulate_many", None)
    if many is not None and len(scenes) > 1:
        return list(many(scenes, executor=executor, progress=progress))
    from tqdm.auto import tqdm

    return [tactile_mirror.simulate(s) for s in tqdm(scenes, desc="simulate", disable=not progress, leave=False)]


def simulate_cached(n: int, seed: int, kwargs: dict, cache_dir=None, progress: bool = True) -> list:
    """``simulate_scenes(scenes.random(n, seed=seed, **kwargs))``, kept in ``cache_dir`` (pickle) if given.

    The cache file is named by ``n``, ``seed`` and a hash of ``kwargs`` and of the
    library version, so changed scene options never read stale results; delete the
    directory after a change of the contact solver. The hash covers the full content of
    every value (a numpy array's dtype, shape and bytes, not its abbreviated repr); for
    plain values (numbers, strings, tuples, lists, dicts of them) it is the hash of their
    repr, as it always was. Only for files this process or one like it wrote: pickle runs
    code from the file.

    ``cache_dir`` is checked (a folder, or one that can be made, in which the file can be
    written) before anything is simulated. A cache file that cannot be read or does not
    hold ``n`` simulation results (a truncated save, a foreign pickle) is a cache miss: a
    warning names it, the scenes are simulated again and the file is replaced atomically.
    """
    if cache_dir is None:
        return simulate_scenes(random_scenes(n, seed, **kwargs), progress)
    import os
    import pickle

    from tactile_mirror import __version__
    from tactile_mirror.files import atomic_write, check_writable

    try:
        folder = os.fspath(cache_dir)
    except TypeError:
        raise TypeError(f"cache_dir must be a path (str or os.PathLike), got {cache_dir!r}") from None
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise NotADirectoryError(f"cache_dir {folder!r} is a file, not a folder")
    if not isinstance(kwargs, dict):
        raise TypeError(f"kwargs must be a dict of scenes.random options, got {type(kwargs).__name__}")
    key = cache_key(n, seed, kwargs, __version__)
    path = os.path.join(folder, f"scenes_{seed}_{n}_{key}.pkl")
    if os.path.exists(path):
        res = _load_cached_scenes(path, n)
        if res is not None:
            return res
    try:  # (before the simulation, not after it)
        os.makedirs(folder, exist_ok=True)
        check_writable(path)
    except OSError as exc:
        raise type(exc)(f"cache_dir {folder!r} cannot hold the scene cache: {exc}") from exc
    res = simulate_scenes(random_scenes(n, seed, **kwargs), progress)
    with atomic_write(path, "wb") as fh:
        pickle.dump(res, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return res


def _load_cached_scenes(path: str, n: int):
    """The ``n`` results in the cache file ``path``, or None (with a warning naming the file)
    if it cannot be unpickled or holds anything else."""
    import pickle
    import warnings
    from pathlib import Path

    from tactile_mirror.contact.simulation import SimulationResult

    try:
        value = pickle.loads(Path(path).read_bytes())
    except (pickle.UnpicklingError, EOFError, OSError, AttributeError, ImportError, IndexError, KeyError,
            TypeError, ValueError, MemoryError) as exc:  # (truncated: EOFError; garbage: UnpicklingError, ...)
        problem = f"cannot be read ({type(exc).__name__}: {exc})"
    else:
        if not isinstance(value, list):
            problem = f"holds a {type(value).__name__}, not a list of simulation results"
        elif len(value) != n:
            problem = f"holds {len(value)} results, not {n}"
        elif not all(isinstance(r, SimulationResult) for r in value):
            bad = next(r for r in value if not isinstance(r, SimulationResult))
            problem = f"holds a {type(bad).__name__} among its results, not only SimulationResult"
        else:
            return value
    warnings.warn(f"scene cache {path!r} {problem}; simulating the scenes again and replacing it",
                  RuntimeWarning, stacklevel=3)
    return None


def _plain(value) -> bool:
    """True if ``repr(value)`` holds all of ``value`` (numbers, strings, None, numpy scalars,
    and tuples, lists and dicts of them; not arrays, whose repr is abbreviated, nor objects)."""
    if value is None or isinstance(value, (bool, int, float, complex, str, bytes, np.generic)):
        return True
    if isinstance(value, (tuple, list)):
        return all(_plain(v) for v in value)
    if isinstance(value, dict):
        return all(_plain(k) and _plain(v) for k, v in value.items())
    return False


def _hash_content(h, value) -> None:
    """Feed the full content of ``value`` to the hash ``h`` (type-tagged: ``(1,)`` and ``[1]``,
    an array and its list, differ)."""
    if isinstance(value, np.ndarray):
        h.update(f"ndarray {value.dtype.str} {value.shape}\0".encode())
        if value.dtype.hasobject:
            for v in value.ravel(order="C"):
                _hash_content(h, v)
        else:
            h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, (tuple, list)):
        h.update(f"{type(value).__name__} {len(value)}\0".encode())
        for v in value:
            _hash_content(h, v)
    elif isinstance(value, dict):
        h.update(f"dict {len(value)}\0".encode())
        for k, v in sorted(value.items(), key=lambda kv: repr(kv[0])):
            _hash_content(h, k)
            _hash_content(h, v)
    elif _plain(value):
        h.update(f"{type(value).__name__} {value!r}\0".encode())
    else:  # any other object: its pickle holds its state (arrays in full)
        import pickle

        try:
            data = pickle.dumps(value, protocol=4)
        except (pickle.PicklingError, TypeError, AttributeError):
            data = repr(value).encode()
        h.update(f"object {type(value).__module__}.{type(value).__qualname__} {len(data)}\0".encode())
        h.update(data)


def cache_key(n: int, seed: int, kwargs: dict, version: str) -> str:
    """The key of the scene set ``scenes.random(n, seed=seed, **kwargs)`` simulated by library
    ``version`` in :func:`simulate_cached`'s cache: 16 hex digits of a SHA-256 hash.

    For plain options (numbers, strings, None, and tuples, lists and dicts of them) the hash
    is of their repr, the key existing cache files were saved under; otherwise of the full
    content of every value (an array's dtype, shape and bytes, not its abbreviated repr).
    """
    import hashlib

    if _plain(kwargs):
        # the repr holds every value in full: the key the existing cache files were saved under
        return hashlib.sha256(repr((n, seed, sorted(kwargs.items()), version)).encode()).hexdigest()[:16]
    h = hashlib.sha256(b"simulate_cached content key 1\0")
    h.update(repr((n, seed, version)).encode())
    for name in sorted(kwargs):
        h.update(f"{name!r}\0".encode())
        _hash_content(h, kwargs[name])
    return h.hexdigest()[:16]


def random_scenes(n: int, seed: int, **kwargs) -> list:
    """The scene set ``tactile_mirror.scenes.random(n, seed=seed, **kwargs)``: ``n`` random
    contact scenes (a list of :class:`~tactile_mirror.scenes.Scene`), drawn with ``seed``
    from the ranges ``kwargs`` give (the rest at ``scenes.random``'s defaults)."""
    from tactile_mirror import scenes

    return scenes.random(n, seed=seed, **kwargs)
