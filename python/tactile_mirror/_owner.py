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


class NotCopyable:
    """``copy.copy``, ``copy.deepcopy`` and ``pickle`` refuse an object holding a running
    compiled state, with a TypeError naming its class and how to make another: a shallow
    copy shared that state (two objects stepping one filter, each seeing the other's
    samples), and the compiled state cannot be pickled. ``_copy_hint`` says how."""

    _copy_hint = "make a new one from the same arguments"

    def _refuse_copy(self, what: str):
        raise TypeError(f"a {type(self).__name__} cannot be {what}: it holds a running compiled state; "
                        f"{self._copy_hint}")

    def __copy__(self):
        self._refuse_copy("copied")

    def __deepcopy__(self, memo):
        self._refuse_copy("copied")

    def __reduce_ex__(self, protocol):
        self._refuse_copy("pickled")
