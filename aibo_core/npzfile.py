"""Strict reading of ``.npz`` files: every problem becomes one line naming the file and the field.

``read_npz`` opens the zip, reads each member's ``.npy`` header (shape, dtype) WITHOUT reading its
data, lets the caller check those declared shapes against each other and against sane limits
(``check_headers``), and only then reads the arrays. Pickled (object) arrays are never loaded.
Corrupt files (bad CRC, damaged compressed streams, damaged headers, unsupported compression)
raise ``FileFormatError``, never a traceback from zipfile, zlib or NumPy.
"""

from __future__ import annotations

import os
import zipfile
import zlib
from typing import Callable

import numpy as np

#: Largest array this reader accepts (bytes, from the declared header): far above any real log.
MAX_ARRAY_BYTES = 16 * 2**30


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
    try:
        with open(path, "rb") as f:
            if f.read(4) != b"PK\x03\x04":
                raise error(f"{source}: not an .npz file (no zip signature)")
        zf = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise error(f"{source}: file not found") from None
    except IsADirectoryError:
        raise error(f"{source}: is a folder, not a file") from None
    except PermissionError:
        raise error(f"{source}: permission denied") from None
    except (OSError, zipfile.BadZipFile, ValueError) as exc:
        raise error(f"{source}: not a readable .npz file ({exc})") from None
    with zf:
        members = {}
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                raise error(f"{source}: unexpected member '{info.filename}' (an .npz holds only .npy arrays)")
            members[info.filename[:-4]] = info
        headers: dict[str, Header] = {}
        for key, info in members.items():
            with _member(zf, info, source, key, error) as fp:
                headers[key] = _guard(lambda: _read_header(fp), source, key, error)
            shape, dtype = headers[key]
            if dtype.hasobject:
                fail(source, key, "holds Python objects (pickle), which are never loaded", error)
            nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
            if nbytes > MAX_ARRAY_BYTES:
                fail(source, key, f"declares {nbytes / 2**30:.1f} GiB (shape {shape}); limit "
                     f"{MAX_ARRAY_BYTES / 2**30:.0f} GiB", error)
        if check_headers is not None:
            check_headers(headers)
        out = {}
        for key, info in members.items():
            with _member(zf, info, source, key, error) as fp:
                out[key] = _guard(lambda: np.lib.format.read_array(fp, allow_pickle=False), source, key, error)
        return out


def _member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, source: str, key: str, error):
    try:
        return zf.open(info)
    except (NotImplementedError, zipfile.BadZipFile, RuntimeError, OSError) as exc:
        fail(source, key, f"cannot open the member ({exc})", error)


def _guard(read: Callable, source: str, key: str, error):
    """Run ``read()``; turn the errors of damaged members into one line."""
    try:
        return read()
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, NotImplementedError) as exc:
        fail(source, key, f"damaged data ({type(exc).__name__}: {exc})", error)
