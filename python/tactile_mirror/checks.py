"""Argument checks shared by the library's constructors and functions, so that every
"must be a real number" error has one wording and one behaviour: TypeError for what is not
a real number (bools included), ValueError for a number out of range; both name the
argument, and its unit where one is given."""
from __future__ import annotations

import math
import numbers

__all__ = ["channel_shape", "integer", "real_array", "real_number", "real_numeric", "real_range", "real_sequence",
           "sample_rate"]


def real_number(value, name: str, *, unit: str | None = None, positive: bool = False,
                nonnegative: bool = False) -> float:
    """``value`` as a float, checked to be a finite real number (``> 0`` if ``positive``,
    ``>= 0`` if ``nonnegative``).

    Raises TypeError if ``value`` is not a real number (a bool is not), ValueError if it is
    NaN, infinite or out of the asked range. ``name`` and ``unit`` go into the message, e.g.
    ``fs must be positive and finite (Hz), got 0.0``.
    """
    if type(value) is float:  # (the common case, without the ABC check: per-tick callers)
        v = value
    elif isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number{f' ({unit})' if unit else ''}, got {type(value).__name__}")
    else:
        v = float(value)
    if not math.isfinite(v) or (positive and v <= 0) or (nonnegative and v < 0):
        sign = "positive and " if positive else ("non-negative and " if nonnegative else "")
        raise ValueError(f"{name} must be {sign}finite{f' ({unit})' if unit else ''}, got {value!r}")
    return v


def integer(value, name: str, lo: int, hi: int | None = None) -> int:
    """``value`` as an int in ``[lo, hi]`` (``hi`` None: no upper bound). TypeError for what is
    not an integer (a bool, a float such as 2.0 or a string is not), ValueError out of range."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an int, got {type(value).__name__}")
    if value < lo or (hi is not None and value > hi):
        raise ValueError(f"{name} must be in [{lo}, {hi}], got {value}" if hi is not None
                         else f"{name} must be >= {lo}, got {value!r}")
    return int(value)


def real_sequence(value, name: str) -> tuple[float, ...]:
    """``value`` as a tuple of floats: a sequence (list, tuple, 1-D array) of real numbers.

    Raises TypeError for a string (iterated, ``"123"`` became ``(1.0, 2.0, 3.0)``), a scalar,
    or an entry that is not a real number (a bool or a complex number is not). Range checks
    are the caller's.
    """
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise TypeError(f"{name} must be a sequence of real numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise TypeError(f"{name} must be a sequence of real numbers, got {value!r}")
        out.append(float(v))
    return tuple(out)


def real_range(value, name: str, *, unit: str | None = None, positive: bool = False,
               nonnegative: bool = False) -> tuple[float, float]:
    """``value`` as a pair ``(low, high)`` of floats with ``low <= high``, each checked as
    :func:`real_number` checks it (``positive``, ``nonnegative``).

    Raises TypeError for what is not a sequence of real numbers (a string, a scalar, a bool
    entry), ValueError for a sequence of another length than 2, an entry that is NaN,
    infinite or out of range, or ``low > high``; every message names ``name``.
    """
    pair = real_sequence(value, name)
    u = f" ({unit})" if unit else ""
    if len(pair) != 2:
        raise ValueError(f"{name} must be a pair (low, high){u}, got {len(pair)} values: {value!r}")
    lo = real_number(pair[0], f"{name} low", unit=unit, positive=positive, nonnegative=nonnegative)
    hi = real_number(pair[1], f"{name} high", unit=unit, positive=positive, nonnegative=nonnegative)
    if lo > hi:
        raise ValueError(f"{name} must be a range (low, high) with low <= high{u}, got {value!r}")
    return lo, hi


def real_array(value, name: str):
    """``value`` as a float64 numpy array, refusing (TypeError naming ``name``) what is not
    real numbers: complex (its imaginary part would be dropped with only a warning), bool,
    strings, objects. Shape and range checks are the caller's."""
    import numpy as np

    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    return arr.astype(np.float64, copy=False)


def real_numeric(a, name: str) -> None:
    """Refuse an array whose dtype is not integer or floating (``a`` is an ndarray)."""
    # bool is refused too: True/False samples are a mistake (a mask passed for a signal),
    # and SosFilter.step and the pipeline refuse them. sosfilt, scipy's drop-in, casts
    # them as scipy.signal.sosfilt does and does not come here.
    if a.dtype.kind not in "iuf":
        raise TypeError(f"{name} must hold real numbers, got dtype {a.dtype}")


def sample_rate(fs) -> float:
    """``fs`` as a float in [1, 1e7] Hz."""
    fs = real_number(fs, "fs", unit="Hz", positive=True)
    if not 1.0 <= fs <= 1e7:  # (as the pipeline: outside, the filter design failed naming its sections)
        raise ValueError(f"fs must lie in [1, 1e7] Hz, got {fs!r}")
    return fs


def channel_shape(channels) -> tuple[int, ...]:
    """``channels`` (an int or a tuple of ints) as a tuple of non-negative ints."""
    shape = (channels,) if isinstance(channels, numbers.Integral) and not isinstance(channels, bool) else channels
    try:
        shape = tuple(shape)
    except TypeError:
        raise TypeError(f"channels must be an int or a tuple of ints, got {channels!r}") from None
    if any(isinstance(c, bool) or not isinstance(c, numbers.Integral) or c < 0 for c in shape):
        raise ValueError(f"channels must be non-negative ints, got {channels!r}")
    return tuple(int(c) for c in shape)
