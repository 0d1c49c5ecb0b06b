"""aibo_core.atomic: temp names that fit any legal target name, and cleaning after killed writes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from aibo_core.atomic import DEAD_OWNER_GRACE_S, STALE_AFTER_S, atomic_write, is_stale, remove_stale_temps


def _age(path, seconds: float) -> None:
    """Set the modification time of ``path`` to ``seconds`` ago."""
    t = time.time() - seconds
    os.utime(path, (t, t))


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_longest_legal_name_is_writable(tmp_path):
    """A 255-byte target name works: the temp file beside it does not grow with the name."""
    target = tmp_path / ("x" * 251 + ".npz")
    atomic_write(target, lambda f: f.write(b"data"))
    assert target.read_bytes() == b"data"
    assert os.listdir(tmp_path) == [target.name]


def test_stale_rule():
    assert is_stale(f".aibo-{_dead_pid()}-abcd_123.tmp", DEAD_OWNER_GRACE_S + 1)
    assert not is_stale(f".aibo-{_dead_pid()}-abcd_123.tmp", 5)  # grace: maybe another host's writer
    assert not is_stale(f".aibo-{os.getpid()}-abcd_123.tmp", DEAD_OWNER_GRACE_S + 1)  # a live writer
    assert is_stale(f".aibo-{os.getpid()}-abcd_123.tmp", STALE_AFTER_S + 1)
    assert is_stale(".abcd_123.tmp", STALE_AFTER_S + 1)  # the older name form
    assert not is_stale(".abcd_123.tmp", 600)
    for other in ("notes.tmp", ".notes.tmp", ".abcd_1234.tmp", ".aibo-12-abcd_123.tmpx", "a.npz"):
        assert not is_stale(other, 10 * STALE_AFTER_S)


def test_leftovers_of_killed_writes_are_cleaned_on_the_next_write(tmp_path):
    """kill -9 during a write leaves its temp file; the next write into the folder removes it."""
    code = ("import sys, time; from aibo_core.atomic import atomic_write\n"
            "atomic_write(sys.argv[1], lambda f: (f.write(b'half'), f.flush(), print('writing', flush=True), "
            "time.sleep(60)))")
    child = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "a.npz")], stdout=subprocess.PIPE,
                             text=True, cwd=os.getcwd())
    assert child.stdout.readline().strip() == "writing"
    child.send_signal(signal.SIGKILL)
    child.wait()
    leftover = [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]
    assert len(leftover) == 1 and leftover[0].startswith(f".aibo-{child.pid}-")
    keep = {"user.tmp": 0, ".abcdefgh.tmp": 60, f".aibo-{os.getpid()}-abcdefgh.tmp": 120}  # name: age in s
    for name, age in keep.items():
        (tmp_path / name).write_bytes(b"x")
        _age(tmp_path / name, age)
    (tmp_path / ".old_tmp1.tmp").write_bytes(b"x")
    _age(tmp_path / ".old_tmp1.tmp", STALE_AFTER_S + 5)
    _age(tmp_path / leftover[0], DEAD_OWNER_GRACE_S + 5)
    atomic_write(tmp_path / "a.npz", lambda f: f.write(b"whole"))
    assert sorted(os.listdir(tmp_path)) == sorted(["a.npz", *keep])
    assert (tmp_path / "a.npz").read_bytes() == b"whole"


def test_cleaning_ignores_missing_folders(tmp_path):
    assert remove_stale_temps(tmp_path / "nope") == []


@pytest.mark.parametrize("fail", [KeyboardInterrupt, OSError])
def test_failed_write_keeps_the_old_file_and_leaves_no_temp(tmp_path, fail):
    target = tmp_path / "m.json"
    target.write_text("old")

    def write(f):
        f.write(b"new")
        raise fail

    with pytest.raises(fail):
        atomic_write(target, write)
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["m.json"]
