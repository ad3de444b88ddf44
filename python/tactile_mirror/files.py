"""Safe file writes: a save either completes or leaves the previous file as it was.

Every file the library writes (detector weights, recordings, simulation outputs,
reports, figures) goes through :func:`atomic_write`: the data goes to a temporary
file in the target's folder, is flushed and ``fsync``-ed, and only then moved over
the target with :func:`os.replace` (atomic on POSIX and Windows within one file
system). If anything fails before that (a full disk, a file-size limit, an
exception in the code producing the data, Ctrl-C), the temporary file is removed
and the target is untouched: the previous weights, which may have taken minutes to
train, survive an interrupted save.

The helpers :func:`save_npz`, :func:`write_text`, :func:`write_json` and
(and :func:`tactile_mirror.lab.figure_files.save_figure` for figures) cover what the library writes; :func:`check_writable` lets a
long computation find out before it starts that its output cannot be written.
"""
from __future__ import annotations

import contextlib
import json
import os
import secrets
import stat
from collections.abc import Iterator
from typing import IO, Any

import numpy as np

__all__ = ["atomic_write", "check_writable", "save_npz", "write_json", "write_text"]

_TEMP_SUFFIX = ".tmp"


def _target(path) -> str:
    """The file to replace: ``path``, or what it links to (a save keeps a symlink a symlink)."""
    path = os.fspath(path)
    if os.path.islink(path):
        return os.path.realpath(path)
    return path


def _is_special(target: str) -> bool:
    """True if ``target`` exists and is not a regular file (a pipe, a device, a socket)."""
    try:
        return not stat.S_ISREG(os.stat(target).st_mode)
    except OSError:
        return False


def _open_temporary(target: str) -> tuple[int, str]:
    """A new file beside ``target``, created with the permissions ``open(target, "w")`` would give."""
    folder, name = os.path.split(os.path.abspath(target))
    for _ in range(100):
        tmp = os.path.join(folder, f".{name}.{secrets.token_hex(4)}{_TEMP_SUFFIX}")
        try:
            # 0o666 filtered by the umask, like a plain open(); O_EXCL: never reuse a name
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666), tmp
        except FileExistsError:
            continue
        except (FileNotFoundError, NotADirectoryError) as exc:
            # (the message named the hidden temporary, not the file the caller asked for)
            raise type(exc)(exc.errno, f"cannot save {target!r}: its folder {folder!r} does not exist or is not a "
                                       f"folder") from None
    raise FileExistsError(f"could not create a temporary file beside {target!r}")


def _sync_folder(folder: str) -> None:
    """Make the rename itself durable (POSIX; a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _refuse_read_only(target: str, path) -> None:
    """PermissionError if ``target`` exists and may not be written: by this process, or by
    anyone (no write bit: a file made read-only to keep it, which root could replace)."""
    try:
        st = os.stat(target)
    except FileNotFoundError:
        return
    if not os.access(target, os.W_OK) or not st.st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH):
        raise PermissionError(f"{os.fspath(path)!r} is read-only; it was not replaced")


@contextlib.contextmanager
def atomic_write(path, mode: str = "wb", *, encoding: str | None = None) -> Iterator[IO[Any]]:
    """Open a temporary file for writing that replaces ``path`` when the block ends without error.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write. Its folder must exist. An existing file keeps its
        permission bits; a symlink keeps pointing where it did (its target is replaced).
        A read-only file (no write bit, or not writable by this process) is not
        replaced: PermissionError, also for root.
    mode : {"wb", "w"}
        Binary or text.
    encoding : str, optional
        Text mode only; default UTF-8.

    Yields
    ------
    file object
        Write to it; do not close it.

    Notes
    -----
    On leaving the block normally the file is flushed, ``fsync``-ed and moved into
    place with :func:`os.replace`. On any exception, ``KeyboardInterrupt`` included,
    the temporary file is removed, ``path`` is left as it was, and the exception
    propagates. A ``path`` that is a pipe or a device (``/dev/null``, a FIFO) is
    written directly: it has no old content to keep and must not be replaced.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"mode must be 'wb' or 'w', got {mode!r}")
    if mode == "wb" and encoding is not None:
        raise ValueError("encoding is for text mode ('w') only")
    target = _target(path)
    if os.path.isdir(target):
        raise IsADirectoryError(f"{os.fspath(path)!r} is a folder, not a file")
    if _is_special(target):
        # a pipe or a device (/dev/null, a FIFO): nothing to keep, and replacing it would
        # put a regular file in its place; write to it directly
        with open(target, mode, **({"encoding": encoding or "utf-8", "newline": ""} if mode == "w" else {})) as f:
            yield f
        return
    _refuse_read_only(target, path)
    fd, tmp = _open_temporary(target)
    try:
        if mode == "w":
            f = os.fdopen(fd, "w", encoding=encoding or "utf-8", newline="")
        else:
            f = os.fdopen(fd, "wb")
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        try:
            os.chmod(tmp, stat.S_IMODE(os.stat(target).st_mode))
        except FileNotFoundError:
            pass
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _sync_folder(os.path.dirname(os.path.abspath(target)))


def check_writable(path, *, make_folder: bool = False) -> None:
    """Raise :class:`OSError` now if a file could not be saved at ``path`` later.

    Checks that ``path`` is not a folder and that a file can be created in its
    folder (by creating and removing a temporary one). With ``make_folder`` the
    folder is created first if missing. Use it before a long computation whose
    result goes to ``path``.
    """
    target = _target(path)
    if os.path.isdir(target):
        raise IsADirectoryError(f"{os.fspath(path)!r} is a folder, not a file")
    folder = os.path.dirname(os.path.abspath(target))
    if make_folder:
        os.makedirs(folder, exist_ok=True)
    elif os.path.exists(folder) and not os.path.isdir(folder):
        raise NotADirectoryError(f"the folder of {os.fspath(path)!r} is a file")
    elif not os.path.isdir(folder):
        raise FileNotFoundError(f"the folder of {os.fspath(path)!r} does not exist")
    if _is_special(target):
        if not os.access(target, os.W_OK):
            raise PermissionError(f"{os.fspath(path)!r} is not writable")
        return
    _refuse_read_only(target, path)
    fd, tmp = _open_temporary(target)
    os.close(fd)
    os.unlink(tmp)


def save_npz(path, compressed: bool = False, **arrays) -> None:
    """:func:`numpy.savez` (or ``savez_compressed``) of ``arrays`` to exactly ``path``, atomically.

    Unlike ``numpy.savez(path, ...)`` no ``.npz`` suffix is added: the file is
    written where asked.
    """
    writer = np.savez_compressed if compressed else np.savez
    with atomic_write(path, "wb") as f:
        writer(f, **arrays)


def write_text(path, text: str, *, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_write(path, "w", encoding=encoding) as f:
        f.write(text)


def write_json(path, value, **dumps_kwargs) -> None:
    """Write ``json.dumps(value, **dumps_kwargs)`` and a newline to ``path`` atomically.

    The text is made before the file is opened, so a value that does not
    serialise leaves no trace.
    """
    write_text(path, json.dumps(value, **dumps_kwargs) + "\n")
