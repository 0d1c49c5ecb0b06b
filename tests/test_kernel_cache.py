"""The kernels' on-disk cache is flushed when any kernel source changes (learners/inference/kernels/cache.py):
numba itself sees only a kernel's own file, not the helpers it inlines from other modules."""

from __future__ import annotations

from pathlib import Path

from learners.inference.kernels import cache


class _Cache:
    def __init__(self, folder: Path):
        self.cache_path = str(folder)
        self.flushes = 0

    def flush(self) -> None:
        self.flushes += 1


class _Kernel:
    def __init__(self, folder: Path):
        self._cache = _Cache(folder)


def test_a_changed_source_flushes_every_kernel_once_and_an_unchanged_one_none(tmp_path):
    kernels = [_Kernel(tmp_path), _Kernel(tmp_path)]
    assert cache.flush_if_changed(kernels, "a")  # no digest kept yet: flushed
    assert [k._cache.flushes for k in kernels] == [1, 1]
    assert not cache.flush_if_changed(kernels, "a")
    assert [k._cache.flushes for k in kernels] == [1, 1]
    assert cache.flush_if_changed(kernels, "b")  # a helper changed
    assert [k._cache.flushes for k in kernels] == [2, 2]
    assert (tmp_path / cache.STAMP).read_text() == "b"


def test_the_digest_covers_every_source_of_the_folder(tmp_path):
    for name in ("algebra.py", "estep.py"):
        (tmp_path / name).write_text("x = 1\n")
    before = cache.sources_digest(tmp_path)
    (tmp_path / "algebra.py").write_text("x = 2\n")  # a helper module alone
    assert cache.sources_digest(tmp_path) != before


def test_the_real_kernels_are_found_and_their_cache_holds_the_current_digest():
    import learners.inference.kernels as kernels
    from learners.inference.kernels import algebra, estep, sensor

    found = cache.cached_dispatchers([estep, sensor, algebra])
    assert estep._smooth_kernel in found and sensor._sensor_gram in found and algebra._inv in found
    stamp = Path(estep._smooth_kernel._cache.cache_path) / cache.STAMP
    if stamp.exists():  # (not where the cache folder cannot be written)
        assert stamp.read_text() == cache.sources_digest(Path(kernels.__file__).parent)
