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

``atomic_folder`` does the same for a folder of outputs: they are written into a temp folder (same
name pattern) beside the target, which then takes the target's place in one exchange of names
(``renameat2(RENAME_EXCHANGE)`` on Linux; elsewhere two renames a few microseconds apart). An
interrupted run leaves the old folder as it was; the temp folder of a killed run is removed, by the
rule above but only once its process is gone, the next time anything is written beside it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import os
import re
import shutil
import tempfile
import time
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

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
    atomic_write_all([(path, write)])


def atomic_write_all(items: Sequence[tuple[str | os.PathLike, Callable[[Any], None]]]) -> None:
    """``atomic_write`` for files that belong together (an agent and its description): every ``write(fileobj)``
    runs on its own temp file first, and only when all have succeeded are they renamed into place, one right
    after another (microseconds apart). A failed or interrupted write leaves every target as it was."""
    temps: list[tuple[Path, str]] = []
    try:
        for path, write in items:
            path = Path(path)
            with _naming(path):
                path.parent.mkdir(parents=True, exist_ok=True)
                remove_stale_temps(path.parent)
                fd, tmp = tempfile.mkstemp(prefix=f".aibo-{os.getpid()}-", suffix=".tmp", dir=path.parent)
                temps.append((path, tmp))
                with os.fdopen(fd, "wb") as f:
                    write(f)
                    f.flush()
                    os.fsync(f.fileno())
                os.chmod(tmp, 0o666 & ~_umask())
        for path, tmp in temps:
            with _naming(path):
                os.replace(tmp, path)
    except BaseException:
        for _, tmp in temps:
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
        raise


@contextmanager
def _naming(path: Path) -> Iterator[None]:
    """Re-raise an OSError of the block (a full disk names no file, a read-only folder names our temp
    file) as one naming ``path``, the output the user asked for."""
    try:
        yield
    except OSError as exc:
        if exc.filename == str(path) or exc.errno is None:
            raise
        raise OSError(exc.errno, f"{exc.strerror} (writing {path})") from exc


@contextmanager
def atomic_folder(path: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty temp folder beside ``path``; when the block ends normally it replaces ``path``
    (a folder, or nothing yet) whole; when it raises, it is removed and ``path`` is untouched. A
    symlink to a folder: the folder it names is replaced, the link kept."""
    path = Path(os.path.realpath(path)) if os.path.islink(path) else Path(path)
    with _naming(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temps(path.parent)
        tmp = Path(tempfile.mkdtemp(prefix=f".aibo-{os.getpid()}-", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
        with _naming(path):
            os.chmod(tmp, 0o777 & ~_umask())
            if not path.exists():
                os.rename(tmp, path)
                return
            if not _exchange(tmp, path):
                old = Path(tempfile.mkdtemp(prefix=f".aibo-{os.getpid()}-", suffix=".tmp", dir=path.parent))
                os.rename(path, old)  # onto the empty folder just made: the name is ours
                os.rename(tmp, path)
                tmp = old
    finally:
        shutil.rmtree(tmp, ignore_errors=True)  # the new folder after a failure, else the old one


def _exchange(a: Path, b: Path) -> bool:
    """Swap the names of ``a`` and ``b`` in one step (Linux renameat2); False where not supported."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (22, 38, 95):  # EINVAL, ENOSYS, EOPNOTSUPP: this file system or kernel cannot
        return False
    raise OSError(err, os.strerror(err), str(b))


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
            elif entry.is_dir(follow_symlinks=False) and _dead_owner(entry.name) and \
                    is_stale(entry.name, now - entry.stat().st_mtime):
                shutil.rmtree(entry.path)
                removed.append(entry.name)
        except OSError:
            continue  # gone already, or not ours to delete
    return removed


def _dead_owner(name: str) -> bool:
    """True when ``name`` is a temp name of ours whose process is no longer running (a temp folder
    is removed only then: a long run may leave its folder unmodified for hours)."""
    m = _TEMP_NAME.fullmatch(name)
    return m is not None and m["pid"] is not None and not _running(int(m["pid"]))


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


def finite_json(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, +-inf) replaced by None, so that it is valid JSON."""
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def json_text(value: Any, indent: int | None = 1, sort_keys: bool = False) -> str:
    """Strict JSON of ``value`` (``finite_json``: NaN and infinities become null)."""
    return json.dumps(finite_json(value), indent=indent, sort_keys=sort_keys, allow_nan=False)


def write_json(path: str | os.PathLike, value: Any, indent: int | None = 1) -> None:
    """Write ``value`` to ``path`` as strict JSON (``json_text``), atomically."""
    text = json_text(value, indent)
    atomic_write(path, lambda f: f.write(text.encode()))


def write_jsonl(path: str | os.PathLike, records: list[Any], sort_keys: bool = False) -> None:
    """Write ``records`` to ``path``, one strict JSON object per line (``json_text``), atomically: a resumable run
    rewrites the whole file after each finished record, so an interruption never leaves half a line."""
    text = "".join(json_text(r, indent=None, sort_keys=sort_keys) + "\n" for r in records)
    atomic_write(path, lambda f: f.write(text.encode()))


def read_jsonl(path: str | os.PathLike) -> list[Any]:
    """The records of a JSON-lines file (blank lines skipped); [] when it does not exist."""
    path = Path(path)
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


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
