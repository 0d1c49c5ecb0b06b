"""The compiled kernels' on-disk cache, flushed whenever any kernel source changes.

numba keys a cached kernel by its own function's bytecode and its own file's time stamp only
(``numba.core.caching``: ``_index_key``, ``source_stamp``). The kernels inline helpers from other modules of this
package (``algebra``, ``structured``, ``fasttrig``), so after a change to a helper alone, e.g. a ``git pull`` in
an editable install, the kernels that inline it keep running their old machine code. Measured here: an E-step
cached during a since-reverted experiment on ``algebra`` gave results that differed at the rounding level from
a fresh compile, and the slow study of a log with 10% false sightings named nothing instead of false_sightings.

``flush_if_changed`` keeps a digest of every kernel source (and numba's version) beside the caches
(``STAMP``). When the digest differs from the kept one, it empties every kernel's cache index before any kernel
runs, so each kernel compiles again on its first call.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from types import ModuleType
from typing import Any, Iterable

import numba

from aibo_core.atomic import atomic_write

STAMP = "aibo-kernel-sources.sha256"  # beside the caches: the digest their code was compiled from


def sources_digest(folder: Path) -> str:
    """sha256 of numba's version and every ``*.py`` file of ``folder`` (by name, in name order)."""
    h = hashlib.sha256(numba.__version__.encode())
    for path in sorted(folder.glob("*.py")):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def cached_dispatchers(modules: Iterable[ModuleType]) -> list[Any]:
    """The ``@njit(cache=True)`` functions defined in ``modules`` (those whose cache has a folder)."""
    out = []
    for module in modules:
        for obj in vars(module).values():
            cache = getattr(obj, "_cache", None)
            if getattr(obj, "__module__", None) == module.__name__ and hasattr(cache, "flush") \
                    and getattr(cache, "cache_path", None):
                out.append(obj)
    return out


def flush_if_changed(dispatchers: list[Any], digest: str) -> bool:
    """Empty the cache index of every dispatcher when the ``STAMP`` file in its cache folder does not hold
    ``digest``, then write it there; returns whether any was flushed. A folder that cannot be written (no cache
    there either) is left alone."""
    folders: dict[Path, list[Any]] = {}
    for d in dispatchers:
        folders.setdefault(Path(d._cache.cache_path), []).append(d)
    flushed = False
    for folder, members in folders.items():
        stamp = folder / STAMP
        try:
            if stamp.is_file() and stamp.read_text().strip() == digest:
                continue
            for d in members:
                d._cache.flush()
            atomic_write(stamp, lambda f: f.write(digest.encode()))
            flushed = True
        except OSError:
            continue
    return flushed
