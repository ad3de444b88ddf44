"""What a Python process running a real-time loop does about the interpreter and the scheduler.

Two causes of the loop's stalls are the process's own, not the machine's:

- **the cyclic garbage collector**: a collection of the oldest generation scans every tracked
  object of the heap, and a process that has loaded scipy, scikit-fem and the detector holds
  tens of thousands: measured at up to 40 ms in the simulated rig's process and 250 ms in a
  test process, longer than a block, and every thread of the process waits (the stage
  driver's too). :func:`gc_paused` turns it off for a run; reference counting still frees what
  the loop drops (the rig's tick paths make no reference cycles). The collection itself goes
  where nothing waits: before the rig's threads start and after they end.
- **the scheduler's priority**: on a machine shared with other work, a process at the default
  priority waits behind it. :func:`raised_priority` lowers the process's nice value for a run
  where the operating system allows it (root, ``CAP_SYS_NICE`` or an ``RLIMIT_NICE`` that
  permits it) and does nothing elsewhere. It never makes a process real-time (``SCHED_FIFO``):
  a busy loop at that priority can take a core from the kernel's own threads.

CPU affinity is left alone: on a machine with as many busy processes as cores, a process pinned
to a core waits when that core is busy instead of moving to the free one.
"""
from __future__ import annotations

import contextlib
import gc
import os

__all__ = ["gc_paused", "raised_priority"]


@contextlib.contextmanager
def gc_paused():
    """Inside: the cyclic garbage collector is off, and the objects that existed on entry are
    frozen out of its reach (``gc.freeze``: a collection someone asks for scans only the new
    ones); on exit they are unfrozen and the collector is on again. Inside a pause already (the
    collector off), it does nothing.

    No collection runs here: one over a large heap holds every thread of the process up (a
    stage driver's I/O thread too) for tens to hundreds of ms. Run ``gc.collect()`` where
    nothing waits on the process: before the rig's threads start, after they end."""
    if not gc.isenabled():
        yield
        return
    gc.freeze()
    gc.disable()
    try:
        yield
    finally:
        gc.unfreeze()
        gc.enable()


@contextlib.contextmanager
def raised_priority(nice: int = -10):
    """Inside: the nice value lowered to ``nice`` (a higher scheduling priority) where the
    operating system permits it, never raised; restored on exit. Yields the nice value in
    effect inside (unchanged where it may not be lowered), or None where there is none to read
    (not POSIX). On Linux the nice value belongs to the calling thread and the threads it starts
    inherit it: enter before the rig's threads (the stage driver's, the live view's) start."""
    before = now = None
    if hasattr(os, "nice"):
        with contextlib.suppress(OSError):
            before = now = os.nice(0)
            if nice < before:
                now = os.nice(nice - before)   # (OSError where not permitted: unchanged)
    try:
        yield now
    finally:
        if now is not None and now != before:
            with contextlib.suppress(OSError):
                os.nice(before - os.nice(0))
