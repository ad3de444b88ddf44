"""Versioned ``.npz`` files: the checks shared by detector weights and loop recordings.

Reading is bounded: only the members a format names are read, and each one's npy
header (dtype, shape) is checked against the format's bounds before its data is
touched, so a foreign, corrupt or hostile file costs at most what a valid one of
the largest allowed size would. Any defect of the file's content raises the format's
own error type; only the path itself (missing, a folder, unreadable) raises
:class:`OSError`.
"""
from __future__ import annotations

import json
import os
import struct
import tokenize
import zipfile
import zlib
from dataclasses import dataclass

import numpy as np

from tactile_mirror.files import save_npz

__all__ = ["Member", "check_json", "read_versioned", "write_versioned"]

#: The largest ratio deflate can reach (258-byte matches in 2-bit codes is about
#: 1032:1); a member that declares more uncompressed bytes than this times its
#: compressed size cannot be genuine.
_MAX_DEFLATE_RATIO = 1100
_MAX_HEADER = 10_000  # numpy's own limit for an npy header
_CHUNK = 1 << 20
_KIND_NAMES = {"f": "float", "i": "integer", "u": "integer", "b": "bool", "U": "text"}

# exceptions that zipfile / zlib / numpy's header parser raise on malformed input (the
# parser tokenizes the header: an unbalanced bracket in it is a tokenize.TokenError)
_MALFORMED = (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, struct.error, OSError, ValueError,
              EOFError, KeyError, RuntimeError, NotImplementedError, OverflowError, SyntaxError,
              TypeError, IndexError, UnicodeError, MemoryError, RecursionError, tokenize.TokenError)


@dataclass(frozen=True)
class Member:
    """What one member of a versioned file may hold.

    Attributes
    ----------
    kinds : str
        Allowed numpy dtype kinds (``"f"`` float, ``"i"``/``"u"`` integer, ``"b"``
        bool, ``"U"`` text).
    ndim : int
        Number of dimensions (0: a scalar).
    max_shape : tuple of int
        Bound on each dimension (``ndim`` entries).
    max_itemsize : int
        Bound on bytes per element (text: 4 per character).
    required : bool
        Whether the file must have it.
    """

    kinds: str
    ndim: int
    max_shape: tuple = ()
    max_itemsize: int = 8
    required: bool = True

    def check(self, dtype: np.dtype, shape: tuple, name: str) -> str | None:
        """What is wrong with a member declaring ``dtype`` and ``shape``, or None."""
        if dtype.hasobject or dtype.kind not in self.kinds or dtype.fields is not None or dtype.subdtype:
            kinds = " or ".join(dict.fromkeys(_KIND_NAMES[k] for k in self.kinds))
            return f"{name} must be a{'n' if kinds[0] in 'aeiou' else ''} {kinds} array, got dtype {dtype}"
        if dtype.itemsize > self.max_itemsize or dtype.itemsize == 0:
            return f"{name} has {dtype.itemsize}-byte elements, at most {self.max_itemsize} allowed"
        if len(shape) != self.ndim:
            return f"{name} has {len(shape)} dimensions, expected {self.ndim}"
        for k, (n, bound) in enumerate(zip(shape, self.max_shape)):
            if not 0 <= n <= bound:
                return f"{name} has {n} entries along axis {k}, at most {bound} allowed"
        return None


def _read_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, spec: Member, name: str, file_size: int,
                 error: type[Exception], where: str) -> np.ndarray:
    """One member, checked against ``spec`` from its npy header before its data is read."""
    if info.compress_type == zipfile.ZIP_STORED and info.file_size != info.compress_size:
        raise error(f"{where}: member {name} is damaged (stored sizes differ)")
    if info.compress_size > file_size:
        raise error(f"{where}: member {name} claims more bytes than the file has")
    if info.compress_type != zipfile.ZIP_STORED and info.file_size > _MAX_DEFLATE_RATIO * info.compress_size + 1024:
        raise error(f"{where}: member {name} claims {info.file_size} bytes from {info.compress_size} compressed")
    with zf.open(info) as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f, max_header_size=_MAX_HEADER)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f, max_header_size=_MAX_HEADER)
        else:
            raise error(f"{where}: member {name} has npy format version {version}, expected 1.0 or 2.0")
        problem = spec.check(dtype, shape, name)
        if problem is not None:
            raise error(f"{where}: {problem}")
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if f.tell() + nbytes != info.file_size:
            raise error(f"{where}: member {name} holds {info.file_size - f.tell()} data bytes, its header "
                        f"declares {nbytes}")
        out = np.empty(shape, dtype=dtype, order="F" if fortran else "C")
        view = memoryview(out.reshape(-1, order="A").view(np.uint8)) if out.size else memoryview(b"")
        done = 0
        while done < nbytes:
            n = f.readinto(view[done:done + _CHUNK])
            if not n:
                raise error(f"{where}: member {name} is truncated")
            done += n
        if f.read(1):  # also makes zipfile check the member's CRC
            raise error(f"{where}: member {name} has data beyond its declared shape")
    if not out.dtype.isnative:
        out = out.astype(out.dtype.newbyteorder("="))
    return out


def _end_record_entries(fh, file_size: int) -> int | None:
    """The number of entries the zip's end-of-central-directory record counts (the last one in
    the file, as zipfile finds it); None where there is none or it defers to zip64's."""
    tail = min(file_size, 22 + 65535)
    fh.seek(file_size - tail)
    buf = fh.read(tail)
    i = buf.rfind(b"PK\x05\x06")
    if i < 0 or len(buf) - i < 22:
        return None
    (total,) = struct.unpack("<H", buf[i + 10:i + 12])
    return None if total == 0xFFFF else total


def read_versioned(path, fmt: str, version: int | tuple[int, ...], error: type[Exception], what: str,
                   members: dict[str, Member]) -> dict:
    """The ``members`` of an npz archive whose ``format`` is ``fmt`` and ``format_version`` is ``version``
    (or one of the versions, if a tuple).

    Only ``format``, ``format_version`` and the names in ``members`` are read (other
    members are ignored, unread, but every entry's local header must match the zip
    directory: a damaged name raises); each is checked against its :class:`Member` bound
    from its npy header first. Anything wrong with the file's content (not a zip,
    another format, another version, a missing required member, a dtype or shape out
    of bounds, a damaged member) raises ``error`` naming ``path`` and ``what`` the
    file should be. A path that cannot be opened raises :class:`OSError`
    (:class:`FileNotFoundError` if it does not exist).
    """
    path = os.fspath(path)
    header = {"format": Member("U", 0, max_itemsize=4 * 64), "format_version": Member("iu", 0)}
    with open(path, "rb") as fh:  # errors about the path itself stay OSError
        file_size = os.fstat(fh.fileno()).st_size
        try:
            with zipfile.ZipFile(fh) as zf:
                # the directory must hold the entries its end record counts: a damaged length
                # field in it hides the entries after it, and the format's optional members
                # with them
                count = _end_record_entries(fh, file_size)
                if count is not None and count != len(zf.infolist()):
                    raise error(f"{path!r} is not a readable {what}: its zip directory lists "
                                f"{len(zf.infolist())} entries where its end record counts {count}")
                infos = {}
                for info in zf.infolist():
                    # every entry's name in the directory must be its local header's (zipfile
                    # compares them on open, which reads only the header): a damaged name would
                    # otherwise hide a member the format reads, leaving its default in its place
                    zf.open(info).close()
                    if info.filename.endswith(".npy"):
                        infos.setdefault(info.filename[:-4], info)
                data = {}
                for name, spec in (*header.items(), *members.items()):
                    info = infos.get(name)
                    if info is None:
                        if name == "format":
                            raise error(f"{path!r} is not a {what} (format key missing)")
                        if name == "format_version":
                            raise error(f"{path!r}: format_version missing or not an integer")
                        if spec.required:
                            raise error(f"{path!r}: key {name!r} missing")
                        continue
                    if info.flag_bits & 0x1:
                        raise error(f"{path!r}: member {name!r} is encrypted")
                    data[name] = _read_member(zf, info, spec, name, file_size, error, repr(path))
                    if name == "format" and str(data[name]) != fmt:
                        raise error(f"{path!r} is not a {what} (format {str(data[name])[:64]!r})")
        except error:
            raise
        except _MALFORMED as exc:
            raise error(f"{path!r} is not a readable {what}: {type(exc).__name__}: {exc}") from None
    v = int(data["format_version"])
    versions = version if isinstance(version, tuple) else (version,)
    if v not in versions:
        which = f"version {versions[0]}" if len(versions) == 1 else f"versions {', '.join(map(str, versions))}"
        raise error(f"{path!r}: format_version {v} is not supported (this library reads {which})")
    return data


def write_versioned(path, fmt: str, version: int, **arrays) -> None:
    """Write an npz archive with ``format``/``format_version`` and ``arrays`` to ``path``, atomically.

    See :func:`tactile_mirror.files.atomic_write`: an interrupted save leaves the
    previous file intact.
    """
    save_npz(path, format=np.array(fmt), format_version=np.array(version), **arrays)


def parse_json(text, name: str, error: type[Exception], where: str):
    """``json.loads`` of a stored text member; any failure raises ``error``."""
    try:
        return json.loads(str(text))
    except (ValueError, RecursionError) as exc:
        raise error(f"{where}: {name} is not valid JSON: {exc}") from None


def check_json(value, name: str, error: type[Exception]) -> None:
    """Raise ``error`` unless ``value`` serialises to JSON (what the files store)."""
    try:
        json.dumps(value)
    except (TypeError, ValueError, RecursionError) as exc:
        raise error(f"{name} must be JSON-serialisable: {exc}") from None
