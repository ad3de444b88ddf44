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
  permits it) and does nothing elsewhere; asked to, it makes the process real-time
  (``SCHED_RR`` at a low priority), which on the 2-core machine these were measured on cut the
  99.9th percentile of a 1 ms sleep's overshoot under load from 4-7 ms to 0.4 ms.

CPU affinity is left alone: on a machine with as many busy processes as cores, a process pinned
to a core waits when that core is busy instead of moving to the free one.
"""
from __future__ import annotations

import contextlib
import gc
import os
import threading

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


def _threads() -> list[int]:
    """The process's threads (Linux: their ids; elsewhere 0, the calling thread)."""
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except (OSError, ValueError):
        return [0]


@contextlib.contextmanager
def raised_priority(nice: int = -10, rt_priority: int = 0):
    """Inside: every thread of the process (the ones it starts inside too) at a higher
    scheduling priority where the operating system permits it; each restored on exit.
    ``rt_priority`` > 0: the real-time round-robin policy (``SCHED_RR``) at that priority (1 to
    99; a few is enough to come before every ordinary process), else, or where that is not
    permitted, the nice value lowered to ``nice`` (never raised).

    Yields ``{"nice": int or None, "rt_priority": int}``: what is in effect inside (``nice``
    None where there is none to read, not POSIX; ``rt_priority`` 0 where the policy is not
    real-time).

    Real time is for the parts that wait (the loop on its blocks, a driver on its answers):
    real-time threads that compute for most of a second are throttled by the kernel (it keeps
    5 % of each second for the others) and, while they compute, hold up the real-time threads
    that share their core; a collection of the garbage collector or a law's design does not
    belong inside."""
    threads = _threads()
    saved_nice: dict = {}
    if hasattr(os, "getpriority"):
        for t in threads:
            with contextlib.suppress(OSError):
                value = os.getpriority(os.PRIO_PROCESS, t)
                if nice < value:
                    os.setpriority(os.PRIO_PROCESS, t, nice)   # (OSError where not permitted)
                saved_nice[t] = value
    saved_rt: dict = {}
    if rt_priority > 0 and hasattr(os, "sched_setscheduler"):
        for t in threads:
            try:
                policy = (os.sched_getscheduler(t), os.sched_getparam(t))
                os.sched_setscheduler(t, os.SCHED_RR, os.sched_param(int(rt_priority)))
                saved_rt[t] = policy
            except (OSError, ValueError):   # (not permitted, or no such priority: the nice value only)
                break
    me = threading.get_native_id() if threads != [0] else 0
    now = None
    if hasattr(os, "getpriority"):
        with contextlib.suppress(OSError):
            now = os.getpriority(os.PRIO_PROCESS, me)
    try:
        yield {"nice": now, "rt_priority": int(rt_priority) if saved_rt else 0}
    finally:
        # (threads started inside took the raised priority from their starter: put back too)
        for t in _threads():
            base = 0 if threads == [0] else (t if t in saved_rt or t in saved_nice else me)
            if saved_rt and base in saved_rt:
                with contextlib.suppress(OSError):
                    os.sched_setscheduler(t, *saved_rt[base])
            if base in saved_nice:
                with contextlib.suppress(OSError):
                    os.setpriority(os.PRIO_PROCESS, t, saved_nice[base])
