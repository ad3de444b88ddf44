"""One call at a time on a Python object whose state carries over between calls (as
``owner.hpp`` does for the C++ objects): a second thread is refused at once with
RuntimeError, nothing waits."""
from __future__ import annotations

import contextlib
import threading

__all__ = ["claim"]


@contextlib.contextmanager
def claim(lock: threading.Lock, name: str, noun: str):
    """Hold ``lock`` for the block, or raise RuntimeError naming the object if another
    thread holds it (``name``: the class, ``noun``: what each thread should have its own of)."""
    if not lock.acquire(blocking=False):
        raise RuntimeError(f"this {name} is being used by another thread (its state carries over between calls; "
                           f"give each thread its own {noun})")
    try:
        yield
    finally:
        lock.release()
