"""What a task's bits depend on, and the check that a worker has the same.

Two processes give identical arrays for the same task when they run the same compiled
core on the same kernel paths with the same numpy, scipy and scikit-fem. The first task
on a worker compares its identity with the one the driver sent, before it computes
anything, and refuses with both sides named where they differ.
"""
from __future__ import annotations

import functools
import hashlib
import platform
from importlib import metadata

__all__ = ["IDENTITY_KEYS", "BuildMismatch", "build_identity", "identity_differences", "task_identity"]

#: The entries of an identity, in the order they are reported.
IDENTITY_KEYS = ("package", "core", "simd", "numpy", "scipy", "scikit-fem", "python")


class BuildMismatch(RuntimeError):
    """A worker whose build would change the bits of a result; ``differences`` maps each
    differing entry to ``(driver's, worker's)``."""

    def __init__(self, differences: dict, worker: str = "a worker"):
        self.differences = dict(differences)
        self.worker = worker
        lines = "; ".join(f"{k}: driver {a!r}, {worker} {b!r}" for k, (a, b) in self.differences.items())
        super().__init__(f"{worker} runs another build than this process ({lines}); install the same wheel "
                         "on every worker, or pass portable=True where only the kernel paths differ")

    def __reduce__(self):  # crosses process boundaries whole
        return type(self), (self.differences, self.worker)


@functools.lru_cache(maxsize=1)
def _core_digest() -> str:
    from tactile_mirror import _core

    h = hashlib.sha256()
    with open(_core.__file__, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:16]


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "absent"


@functools.lru_cache(maxsize=1)
def _fixed_identity() -> tuple:
    """The entries that cannot change while a process runs (hashed and looked up once)."""
    import tactile_mirror

    return (("package", tactile_mirror.__version__), ("core", _core_digest()), ("numpy", _version("numpy")),
            ("scipy", _version("scipy")), ("scikit-fem", _version("scikit-fem")),
            ("python", platform.python_version()))


def build_identity() -> dict:
    """This process's identity: ``package`` (tactile-mirror's version), ``core`` (a hash of
    the compiled core's file), ``simd`` (the path each kernel family runs now, as
    :func:`tactile_mirror.kernels.simd_paths`), the ``numpy``, ``scipy`` and
    ``scikit-fem`` versions, and the ``python`` version. Plain strings and dicts (JSON).
    All but ``simd`` are computed once per process, so a check per task costs microseconds."""
    from tactile_mirror.kernels import simd_paths

    fixed = dict(_fixed_identity())
    fixed["simd"] = simd_paths()
    return {k: fixed[k] for k in IDENTITY_KEYS}


def task_identity(portable: bool = False) -> dict:
    """What a task's result depends on: :func:`build_identity`, with ``simd`` the word
    ``"baseline"`` when ``portable`` (every worker then runs the baseline kernels, whatever
    paths this process has). Keys a result in a :class:`~tactile_mirror.engine.store.ResultStore`."""
    identity = build_identity()
    if portable:
        identity["simd"] = "baseline"
    return identity


def identity_differences(driver: dict, worker: dict, portable: bool = False) -> dict:
    """The entries where ``worker`` differs from ``driver``, as ``{key: (driver's, worker's)}``;
    ``portable`` leaves out the kernel paths (every worker then runs the baseline ones)."""
    keys = [k for k in IDENTITY_KEYS if not (portable and k == "simd")]
    return {k: (driver.get(k), worker.get(k)) for k in keys if driver.get(k) != worker.get(k)}
