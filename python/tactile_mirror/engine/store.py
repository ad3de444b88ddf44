"""A folder of results shared by every process and machine of a sweep: one file per result.

Each result is one file whose name is a hash of what it was computed from (the content
key of its input, e.g. :attr:`tactile_mirror.Scene.content_key`) and of the build that
computed it (:func:`~tactile_mirror.engine.identity.task_identity`): a new build never
reads an old build's bits, and sweeps that share inputs share their files.

Safe on a network file system shared by many writers, without file locks: a file is
written under a unique temporary name in the same folder and renamed into place
(:func:`tactile_mirror.files.atomic_write`), so a reader sees a whole file or none, and
two writers of one key write the same bits. Files are read without pickle (an ``.npz``
archive read member by member with ``allow_pickle`` off, JSON metadata, every member's
dtype and shape checked against bounds before its data is read, as detector weights
are); a file that is damaged, truncated, of another format, or for another input or
build is a miss with a :class:`StoreWarning`, never an error or a wrong result.

Settings: the folder (``folder``; default the environment variable
:data:`FOLDER_VARIABLE`, ``TM_CACHE_DIR``, else :func:`default_folder`) and a size limit
(``limit``; default :data:`LIMIT_VARIABLE`, ``TM_CACHE_LIMIT``, else
:data:`DEFAULT_LIMIT`): past it the files read or written longest ago are removed.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from tactile_mirror._npzfile import Member, read_versioned, write_versioned

__all__ = ["DEFAULT_LIMIT", "FOLDER_VARIABLE", "FORMAT", "FORMAT_VERSION", "LIMIT_VARIABLE", "MAX_CONTENT_KEY",
           "MAX_IDENTITY", "ResultStore",
           "StoreWarning", "default_folder", "parse_size"]

#: The environment variable that sets a store's folder when none is given.
FOLDER_VARIABLE = "TM_CACHE_DIR"
#: The environment variable that sets a store's size limit when none is given: bytes, or a
#: number with a suffix K, M, G or T (powers of 1024), e.g. ``"20G"``.
LIMIT_VARIABLE = "TM_CACHE_LIMIT"
#: The size limit when neither ``limit`` nor :data:`LIMIT_VARIABLE` gives one: 10 GiB.
DEFAULT_LIMIT = 10 * 2**30
#: The ``format`` and ``format_version`` members of a store file.
FORMAT = "tactile-mirror cache entry"
FORMAT_VERSION = 1

#: A temporary file older than this (s) is left over from a writer that died; removed by trim().
_STALE_TEMPORARY = 3600.0
_NAME = re.compile(r"^[0-9a-f]{64}\.npz$")
_TEMPORARY = re.compile(r"^\.[0-9a-f]{64}\.npz\.[0-9a-f]+\.tmp$")
_PREFIX = "x_"  # the payload's members, apart from the store's own
#: The longest content key and identity (characters) a file holds.
MAX_CONTENT_KEY = 256
MAX_IDENTITY = 8192
_HEADER = {"content": Member("U", 0, max_itemsize=4 * MAX_CONTENT_KEY),
           "identity": Member("U", 0, max_itemsize=4 * MAX_IDENTITY),
           "meta": Member("U", 0, max_itemsize=4 * 65536)}
_SIZE = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?)\s*([KMGT]?)i?B?\s*$", re.IGNORECASE)


class StoreWarning(RuntimeWarning):
    """A store file that could not be used (damaged, foreign, another build's): a miss."""


class _BadEntry(Exception):
    """What is wrong with a store file (reported as a :class:`StoreWarning`)."""


def default_folder() -> str:
    """The folder a store uses when none is given: ``$TM_CACHE_DIR`` if set, else
    ``tactile-mirror`` in the user's cache folder (``$XDG_CACHE_HOME``, else ``~/.cache``;
    ``%LOCALAPPDATA%`` on Windows)."""
    folder = os.environ.get(FOLDER_VARIABLE)
    if folder:
        return folder
    base = os.environ.get("XDG_CACHE_HOME") or (os.environ.get("LOCALAPPDATA") if os.name == "nt" else None)
    return os.path.join(base or os.path.join(os.path.expanduser("~"), ".cache"), "tactile-mirror")


def parse_size(value: int | str, name: str = "limit") -> int:
    """A size in bytes from an integer or a text such as ``"500M"`` or ``"20G"`` (K, M, G, T:
    powers of 1024); positive, else a ``ValueError`` naming ``name``."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        size = int(value)
    elif isinstance(value, str):
        m = _SIZE.match(value)
        if m is None:
            raise ValueError(f"{name} must be a size in bytes, optionally with a suffix K, M, G or T "
                             f"(e.g. '20G'), got {value!r}")
        size = int(float(m.group(1)) * 1024 ** " KMGT".index(m.group(2).upper() or " "))
    else:
        raise TypeError(f"{name} must be an integer number of bytes or a text such as '20G', "
                        f"got {type(value).__name__}")
    if size <= 0:
        raise ValueError(f"{name} must be positive (bytes), got {value!r}")
    return size


def _canonical(identity: dict) -> str:
    try:
        return json.dumps(identity, sort_keys=True, separators=(",", ":"))
    except (TypeError, ValueError) as exc:
        raise TypeError(f"identity must be a JSON-serialisable dict: {exc}") from None


class ResultStore:
    """A folder of results, one file each, keyed by input content and build.

    Parameters
    ----------
    folder : str or os.PathLike, optional
        Where the files go (made on the first save). Default: :func:`default_folder`.
    limit : int or str, optional
        Size limit of the folder's store files, bytes (or ``"20G"``, see :func:`parse_size`).
        Default: ``$TM_CACHE_LIMIT``, else :data:`DEFAULT_LIMIT`. Each writer enforces it from
        what it sees of the folder (scanned once, then its own writes), removing the files
        read or written longest ago; with several writers the folder may pass it briefly.

    Files of other names in the folder are never read nor removed.
    """

    def __init__(self, folder=None, limit: int | str | None = None):
        if folder is None:
            folder = default_folder()
        try:
            self.folder = os.path.abspath(os.fspath(folder))
        except TypeError:
            raise TypeError(f"folder must be a path (str or os.PathLike), got {folder!r}") from None
        if os.path.exists(self.folder) and not os.path.isdir(self.folder):
            raise NotADirectoryError(f"the store's folder {self.folder!r} is a file, not a folder")
        if limit is None:
            text = os.environ.get(LIMIT_VARIABLE)
            self.limit = parse_size(text, LIMIT_VARIABLE) if text else DEFAULT_LIMIT
        else:
            self.limit = parse_size(limit, "limit")
        self._total: int | None = None  # bytes of store files, as this writer knows them

    def __repr__(self) -> str:
        return f"ResultStore({self.folder!r}, limit={self.limit})"

    # -- names

    @staticmethod
    def key(content_key: str, identity: dict) -> str:
        """The file key of the result of ``content_key`` computed by a build of ``identity``
        (a JSON dict): 64 hex digits."""
        if not isinstance(content_key, str) or not content_key:
            raise TypeError(f"content_key must be a non-empty str, got {content_key!r}")
        if len(content_key) > MAX_CONTENT_KEY:
            raise ValueError(f"content_key has {len(content_key)} characters, more than the {MAX_CONTENT_KEY} a "
                             "store file holds (pass a digest of the content)")
        canonical = _canonical(identity)
        if len(canonical) > MAX_IDENTITY:
            raise ValueError(f"identity takes {len(canonical)} characters as JSON, more than the {MAX_IDENTITY} a "
                             "store file holds")
        h = hashlib.sha256(b"tactile_mirror.engine.store key 1\0")
        h.update(content_key.encode() + b"\0" + canonical.encode())
        return h.hexdigest()

    def path(self, content_key: str, identity: dict) -> str:
        """The file that holds (or would hold) the result of ``content_key`` by ``identity``."""
        return os.path.join(self.folder, self.key(content_key, identity) + ".npz")

    def check(self) -> None:
        """Raise :class:`OSError` naming the folder now if files could not be saved in it."""
        from tactile_mirror.files import check_writable

        try:
            os.makedirs(self.folder, exist_ok=True)
            check_writable(os.path.join(self.folder, "0" * 64 + ".npz"))
        except OSError as exc:
            raise type(exc)(f"the store's folder {self.folder!r} cannot hold results: {exc}") from exc

    # -- reading and writing

    def load(self, content_key: str, identity: dict, members: dict[str, Member],
             decode: Callable[[dict, dict], Any] | None = None) -> Any:
        """The stored result of ``content_key`` by ``identity``, or ``None`` (a miss).

        ``members`` bounds the payload's arrays (:class:`tactile_mirror._npzfile.Member`:
        dtype kinds, dimensions, sizes), checked from each member's header before its data
        is read. Without ``decode`` the result is ``(arrays, meta)``; with it,
        ``decode(arrays, meta)``, whose ``ValueError``, ``TypeError`` or ``KeyError`` (a
        file whose content does not fit the input) makes a miss too. A missing file is a
        quiet miss; any other miss warns (:class:`StoreWarning`) with the file and why.
        A hit marks the file as recently used.
        """
        path = self.path(content_key, identity)
        want = _canonical(identity)
        try:
            data = read_versioned(path, FORMAT, FORMAT_VERSION, _BadEntry, "tactile-mirror cache entry",
                                  {**_HEADER, **{_PREFIX + k: m for k, m in members.items()}})
            if str(data["content"]) != content_key:
                raise _BadEntry(f"{path!r} holds the result of another input ({str(data['content'])[:64]!r})")
            if str(data["identity"]) != want:
                raise _BadEntry(f"{path!r} was computed by another build")
            try:
                meta = json.loads(str(data["meta"]))
            except (ValueError, RecursionError) as exc:
                raise _BadEntry(f"{path!r}: meta is not valid JSON: {exc}") from None
            if not isinstance(meta, dict):
                raise _BadEntry(f"{path!r}: meta is not a JSON object")
            arrays = {k[len(_PREFIX):]: v for k, v in data.items() if k.startswith(_PREFIX)}
            if decode is None:
                value = (arrays, meta)
            else:
                try:
                    value = decode(arrays, meta)
                except (ValueError, TypeError, KeyError) as exc:
                    raise _BadEntry(f"{path!r} does not hold a result of this input: {exc}") from None
        except FileNotFoundError:
            return None
        except (_BadEntry, OSError) as exc:
            warnings.warn(f"cache file unusable, a miss: {exc}", StoreWarning, stacklevel=2)
            return None
        try:
            os.utime(path)
        except OSError:
            pass
        return value

    def save(self, content_key: str, identity: dict, arrays: dict[str, np.ndarray], meta: dict) -> str | None:
        """Write the result of ``content_key`` by ``identity``: ``arrays`` (numeric or text
        numpy arrays, no objects) and ``meta`` (a JSON dict), atomically, replacing any file
        of the same key; then remove the oldest other files if the folder is over the limit.
        Returns the file's path, or ``None`` (with a :class:`StoreWarning`) when the one
        file is larger than the limit: it is not kept, and nothing else is removed for it."""
        for name, a in arrays.items():
            if not isinstance(a, np.ndarray) or a.dtype.hasobject:
                raise TypeError(f"arrays[{name!r}] must be a numpy array of numbers or text")
        try:
            meta_text = json.dumps(meta)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"meta must be JSON-serialisable: {exc}") from None
        path = self.path(content_key, identity)
        os.makedirs(self.folder, exist_ok=True)
        try:
            replaced = os.path.getsize(path)
        except OSError:
            replaced = 0
        write_versioned(path, FORMAT, FORMAT_VERSION, content=np.array(content_key),
                        identity=np.array(_canonical(identity)), meta=np.array(meta_text),
                        **{_PREFIX + k: v for k, v in arrays.items()})
        try:
            size = os.path.getsize(path)
        except OSError:  # (removed meanwhile by another writer's trim)
            size = 0
        if size > self.limit:
            with contextlib.suppress(OSError):
                os.unlink(path)
            warnings.warn(f"a result of {size} bytes is larger than the store's limit of {self.limit} bytes: "
                          "not kept", StoreWarning, stacklevel=2)
            return None
        if self._total is None:
            self._total = self._scan()[1]
        else:
            self._total += size - replaced
        if self._total > self.limit:
            self.trim(keep=path)
        return path

    # -- size

    def _scan(self) -> tuple[list, int]:
        """The store files (mtime, size, path) and their total size; stale temporaries removed."""
        entries, total, now = [], 0, time.time()
        try:
            it = os.scandir(self.folder)
        except FileNotFoundError:
            return [], 0
        with it:
            for e in it:
                try:
                    if _NAME.match(e.name):
                        st = e.stat()
                        entries.append((st.st_mtime, st.st_size, e.path))
                        total += st.st_size
                    elif _TEMPORARY.match(e.name) and now - e.stat().st_mtime > _STALE_TEMPORARY:
                        os.unlink(e.path)
                except OSError:  # (removed meanwhile by another process)
                    continue
        return entries, total

    def size(self) -> int:
        """The bytes the folder's store files take now."""
        return self._scan()[1]

    def trim(self, limit: int | None = None, keep: str | None = None) -> int:
        """Remove the store files read or written longest ago until they take at most
        ``limit`` bytes (default: the store's limit), never the file ``keep`` (the one just
        written); also temporaries left by writers that died over an hour ago. Returns the
        number of files removed.

        Each writer counts the bytes it wrote since its last look at the folder, so with
        many writers the folder may exceed the limit by what the others wrote since then,
        until one of them trims again."""
        limit = self.limit if limit is None else parse_size(limit, "limit")
        entries, total = self._scan()
        removed = 0
        for _, size, path in sorted(entries):
            if total <= limit:
                break
            if keep is not None and os.path.abspath(path) == os.path.abspath(keep):
                continue
            try:
                os.unlink(path)
            except FileNotFoundError:
                pass
            except OSError:
                continue
            total -= size
            removed += 1
        self._total = total
        return removed
