"""Atomic file writes: a failed or interrupted write never leaves a half-written or clobbered file.

``atomic_write`` writes to a temp file ``.aibo-PID-XXXXXXXX.tmp`` beside the target (at most 26
bytes, so any legal target name works: the temp name never grows with it) and renames it into
place. A process killed with SIGKILL cannot remove its temp file; such leftovers are cleaned the
next time anything is written into the same folder. The rule (``is_stale``): a file of ours is
stale when

- its name is ``.aibo-PID-XXXXXXXX.tmp``, process PID is not running on this machine, and the
  file has not been modified for ``DEAD_OWNER_GRACE_S`` (60 s: a guard for a writer in another
  PID namespace or on another host sharing the folder), or
- its name is ours (also the older ``.XXXXXXXX.tmp`` form) and it has not been modified for
  ``STALE_AFTER_S`` (1 hour: far longer than any write takes).

Nothing else is ever deleted.
"""

from __future__ import annotations

import os
import re
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

#: Seconds without modification after which a temp file of a dead process is removed.
DEAD_OWNER_GRACE_S = 60.0
#: Seconds without modification after which any temp file of ours is removed.
STALE_AFTER_S = 3600.0
# tempfile's random part: 8 characters of "abcdefghijklmnopqrstuvwxyz0123456789_"
_TEMP_NAME = re.compile(r"\.(?:aibo-(?P<pid>\d+)-)?[a-z0-9_]{8}\.tmp")


def atomic_write(path: str | os.PathLike, write: Callable[[Any], None]) -> None:
    """Call ``write(fileobj)`` on a temp file beside ``path`` and rename it into place.

    Stale temp files of earlier, killed writes in that folder are removed first (see the module
    docstring). The file gets the usual mode (0666 less the umask), not mkstemp's 0600.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(path.parent)
    fd, tmp = tempfile.mkstemp(prefix=f".aibo-{os.getpid()}-", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def is_stale(name: str, age_s: float) -> bool:
    """True when ``name`` is a temp file of ``atomic_write`` left by a killed write (rule above).

    ``age_s``: seconds since the file was last modified.
    """
    m = _TEMP_NAME.fullmatch(name)
    if m is None:
        return False
    if age_s >= STALE_AFTER_S:
        return True
    return m["pid"] is not None and age_s >= DEAD_OWNER_GRACE_S and not _running(int(m["pid"]))


def remove_stale_temps(folder: str | os.PathLike) -> list[str]:
    """Delete the stale temp files of ours in ``folder``; return their names. Never raises."""
    removed = []
    now = time.time()
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        try:
            if entry.is_file(follow_symlinks=False) and is_stale(entry.name, now - entry.stat().st_mtime):
                os.unlink(entry.path)
                removed.append(entry.name)
        except OSError:
            continue  # gone already, or not ours to delete
    return removed


def _running(pid: int) -> bool:
    """True if a process ``pid`` exists on this machine (possibly another user's)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, another user's
    except OverflowError:
        return False  # no such pid can exist
    return True


def write_npz(f, arrays: dict[str, np.ndarray]) -> None:
    """Like ``np.savez_compressed`` but with fixed zip timestamps: same content, same bytes."""
    with zipfile.ZipFile(f, mode="w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key, value in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)


def save_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` to ``path`` as a deterministic ``.npz``, atomically."""
    atomic_write(path, lambda f: write_npz(f, arrays))


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
