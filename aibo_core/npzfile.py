"""Strict reading of ``.npz`` files: every problem becomes one line naming the file and the field.

``read_npz`` opens the zip, checks that the zip directory lists every entry its end record
declares (a damaged directory could otherwise drop members silently), reads each member's ``.npy``
header (shape, dtype) WITHOUT reading its data, checks that the declared size is what the member
holds and is under ``MAX_ARRAY_BYTES``, lets the caller check the declared shapes against each
other (``check_headers``), and only then reads the arrays, to the end of each member (so its
CRC-32 is always verified). Pickled (object) arrays are never loaded. Corrupt files (bad CRC,
damaged compressed streams, damaged headers, unsupported compression, a JSON or other file in
place of an ``.npz``) raise ``FileFormatError``, never a traceback from zipfile, zlib or NumPy.
"""

from __future__ import annotations

import os
import struct
import zipfile
from typing import BinaryIO, Callable

import numpy as np

#: Largest array this reader accepts (bytes, from the declared header): far above any real log.
MAX_ARRAY_BYTES = 16 * 2**30
_ZIP_MAGIC = b"PK\x03\x04"
_EMPTY_ZIP = b"PK\x05\x06"


class FileFormatError(ValueError):
    """A file that cannot be read as what it claims to be. The message names file and field."""


Header = tuple[tuple[int, ...], np.dtype]


def fail(source: str, key: str, what: str, error: type[FileFormatError] = FileFormatError):
    """Raise ``error("SOURCE: field 'KEY': WHAT")``."""
    raise error(f"{source}: field '{key}': {what}")


def _read_header(fp) -> Header:
    major, _ = np.lib.format.read_magic(fp)
    if major == 1:
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(fp)
    else:
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(fp)
    return tuple(int(n) for n in shape), np.dtype(dtype)


def read_npz(path: str | os.PathLike, check_headers: Callable[[dict[str, Header]], None] | None = None,
             error: type[FileFormatError] = FileFormatError) -> dict[str, np.ndarray]:
    """All arrays of the ``.npz`` at ``path`` (keys without ``.npy``).

    ``check_headers(headers)`` sees ``{key: (shape, dtype)}`` before any data is read and may
    raise. Raises ``error`` (a FileFormatError subclass) for anything unreadable.
    """
    source = str(path)
    with _open_zip(path, source, error) as zf:
        members = {}
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                raise error(f"{source}: unexpected member '{info.filename}' (an .npz holds only .npy arrays)")
            members[info.filename[:-4]] = info
        headers = {key: _member_header(zf, info, source, key, error) for key, info in members.items()}
        if check_headers is not None:
            check_headers(headers)
        return {key: _member_array(zf, info, source, key, error) for key, info in members.items()}


def _open_zip(path: str | os.PathLike, source: str, error) -> zipfile.ZipFile:
    """The zip at ``path`` with its directory checked against the declared entry count."""
    try:
        with open(path, "rb") as f:
            kind = _sniff(f.read(64))
            if kind:
                raise error(f"{source}: not an .npz file ({kind})")
            declared = _declared_entries(f)
        zf = zipfile.ZipFile(path)
    except FileFormatError:
        raise
    except FileNotFoundError:
        raise error(f"{source}: file not found") from None
    except IsADirectoryError:
        raise error(f"{source}: is a folder, not a file") from None
    except PermissionError:
        raise error(f"{source}: permission denied") from None
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001 - BadZipFile, NotImplementedError, struct.error, ...: all unreadable
        raise error(f"{source}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
    if declared is not None and declared != len(zf.infolist()):
        zf.close()
        raise error(f"{source}: damaged zip directory (it lists {len(zf.infolist())} members, "
                    f"its end record declares {declared})")
    return zf


def _sniff(start: bytes) -> str:
    """Why a file starting with ``start`` is not a zip ('' when it may be one)."""
    if start.startswith(_ZIP_MAGIC) or start.startswith(_EMPTY_ZIP):
        return ""
    if not start:
        return "the file is empty"
    if start.lstrip()[:1] in (b"{", b"["):
        return "it is a JSON file, such as an aibo model file"
    if start.startswith(b"\x89PNG"):
        return "it is a PNG image"
    if start.startswith(b"\x93NUMPY"):
        return "it is a single .npy array"
    return "no zip signature"


def _declared_entries(f: BinaryIO) -> int | None:
    """Entries declared by the zip's end-of-central-directory record (zip64 aware); None if absent."""
    size = f.seek(0, os.SEEK_END)
    f.seek(max(0, size - 22 - 65535))
    tail = f.read()
    i = tail.rfind(_EMPTY_ZIP)
    if i < 0 or len(tail) - i < 22:
        return None
    total = struct.unpack_from("<H", tail, i + 10)[0]
    if total != 0xFFFF or i < 20 or tail[i - 20:i - 16] != b"PK\x06\x07":
        return total
    f.seek(struct.unpack_from("<Q", tail, i - 12)[0])
    record = f.read(56)
    return struct.unpack_from("<Q", record, 32)[0] if record[:4] == b"PK\x06\x06" else None


def _member_header(zf: zipfile.ZipFile, info: zipfile.ZipInfo, source: str, key: str, error) -> Header:
    """The member's declared (shape, dtype), checked against what the member holds; no data read."""
    with _member(zf, info, source, key, error) as fp:
        shape, dtype = _guard(lambda: _read_header(fp), source, key, error)
        data_bytes = info.file_size - fp.tell()
    if dtype.hasobject:
        fail(source, key, "holds Python objects (pickle), which are never loaded", error)
    nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if nbytes > MAX_ARRAY_BYTES:
        fail(source, key, f"declares {nbytes / 2**30:.1f} GiB (shape {shape}); limit "
             f"{MAX_ARRAY_BYTES / 2**30:.0f} GiB", error)
    if nbytes != data_bytes:
        fail(source, key, f"header declares {nbytes} bytes of data (shape {shape}, {dtype}) but the member holds "
             f"{data_bytes}", error)
    return shape, dtype


def _member_array(zf: zipfile.ZipFile, info: zipfile.ZipInfo, source: str, key: str, error) -> np.ndarray:
    """The member's array, read to the member's end so that its CRC-32 is verified."""
    with _member(zf, info, source, key, error) as fp:
        array = _guard(lambda: np.lib.format.read_array(fp, allow_pickle=False), source, key, error)
        if _guard(lambda: fp.read(), source, key, error):
            fail(source, key, "data after the array's end", error)
    return array


def _member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, source: str, key: str, error):
    try:
        return zf.open(info)
    except (NotImplementedError, zipfile.BadZipFile, RuntimeError, OSError) as exc:
        fail(source, key, f"cannot open the member ({exc})", error)


def _guard(read: Callable, source: str, key: str, error):
    """Run ``read()`` on a member's untrusted bytes; any decoding failure becomes one line.

    Damaged headers raise a variety of errors (ValueError, SyntaxError, tokenize.TokenError, ...)
    and damaged streams zlib.error, BadZipFile or EOFError: all mean "damaged data" here.
    """
    try:
        return read()
    except MemoryError:
        raise
    except Exception as exc:  # noqa: BLE001 - decoding untrusted bytes: every failure is a format error
        fail(source, key, f"damaged data ({type(exc).__name__}: {exc})", error)
