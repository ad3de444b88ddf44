"""Versioned ``.npz`` files: the checks shared by detector weights and loop recordings."""
from __future__ import annotations

import json
import os
import zipfile

import numpy as np


def read_versioned(path, fmt: str, version: int, error: type[Exception], what: str) -> dict:
    """Arrays of an npz archive whose ``format`` key is ``fmt`` and ``format_version`` is ``version``.

    Anything else (not an npz archive, another format, a missing, non-integer or other
    version) raises ``error`` with a message naming ``path`` and ``what`` the file should
    be; a missing file raises :class:`FileNotFoundError`.
    """
    path = os.fspath(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, KeyError, AttributeError) as exc:
        raise error(f"{path!r} is not a readable {what}: {exc}") from None
    if str(data.get("format", "")) != fmt:
        raise error(f"{path!r} is not a {what} (format key missing or wrong)")
    v = data.get("format_version")
    if v is None or v.shape != () or v.dtype.kind not in "iu":
        raise error(f"{path!r}: format_version missing or not an integer")
    if int(v) != version:
        raise error(f"{path!r}: format_version {int(v)} is not supported (this library reads version {version})")
    return data


def check_json(value, name: str, error: type[Exception]) -> None:
    """Raise ``error`` unless ``value`` serialises to JSON (what the files store)."""
    try:
        json.dumps(value)
    except (TypeError, ValueError) as exc:
        raise error(f"{name} must be JSON-serialisable: {exc}") from None
