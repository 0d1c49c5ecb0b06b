"""Corrupt or wrong files given to ``aibo learn`` as logs: exit status 2 and one line naming the
file, never a traceback, nothing written; huge declared arrays are refused from their headers."""

from __future__ import annotations

import io
import json
import struct
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    path = tmp_path_factory.mktemp("corrupt") / "a.npz"
    assert main(["collect", "--steps", "1800", "--seed", "1", "--out", str(path)]) == 0
    return path


def _data_offset(raw: bytes, info: zipfile.ZipInfo) -> int:
    """Where the member's (compressed) data starts: after its local header."""
    name_len, extra_len = struct.unpack_from("<HH", raw, info.header_offset + 26)
    return info.header_offset + 30 + name_len + extra_len


def _central_entries(raw: bytes) -> list[int]:
    """Offsets of the central-directory entries."""
    out, i = [], raw.find(b"PK\x01\x02")
    while i >= 0:
        out.append(i)
        i = raw.find(b"PK\x01\x02", i + 4)
    return out


def _npz(arrays: dict[str, bytes]) -> bytes:
    """A zip of raw ``.npy`` member bytes (stored)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for key, data in arrays.items():
            zf.writestr(f"{key}.npy", data)
    return buf.getvalue()


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, a)
    return buf.getvalue()


def _header_only(shape: tuple, descr: str) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue()


def _members(log) -> dict[str, bytes]:
    with zipfile.ZipFile(log) as zf:
        return {info.filename[:-4]: zf.read(info) for info in zf.infolist()}


def corrupt(case: str, log, tmp_path) -> tuple[bytes, str]:
    """The bytes of a damaged copy of ``log`` and a phrase the error line must contain."""
    raw = bytearray(log.read_bytes())
    infos = zipfile.ZipFile(log).infolist()
    pose = next(i for i in infos if i.filename == "pose.npy")
    start = _data_offset(raw, pose)
    if case == "bit_flip":
        raw[start + pose.compress_size // 2] ^= 0x01
        return raw, "Bad CRC-32"
    if case == "zlib_stream":
        raw[start:start + 4] = b"\xff" * 4
        return raw, "error"
    if case == "compression_method":
        for i in infos:
            struct.pack_into("<H", raw, i.header_offset + 8, 97)
        for c in _central_entries(raw):
            struct.pack_into("<H", raw, c + 10, 97)
        return raw, "compression method"
    if case == "zip_version":
        struct.pack_into("<H", raw, _central_entries(raw)[0] + 6, 0xAD)
        return raw, "zip file version"
    if case == "dropped_members":  # a huge comment length swallows the directory entries after landmarks
        struct.pack_into("<H", raw, _central_entries(raw)[8] + 32, 0x1000)
        return raw, "damaged zip directory"
    if case == "truncated":
        return raw[: len(raw) // 2], "not a readable .npz"
    members = _members(log)
    if case == "array_header":
        members["actions"] = members["actions"].replace(b"'shape': (", b"'shape': ((")
        return _npz(members), "field 'actions': damaged data"
    if case == "array_header_syntax":
        members["actions"] = members["actions"].replace(b"'descr'", b"'de\"scr'")
        return _npz(members), "field 'actions': damaged data"
    if case == "huge_rows":  # 10^10 frames: over the row and the byte limits, declared in 128 bytes
        members["actions"] = _header_only((10**10,), "<i8")
        return _npz(members), "field 'actions': declares"
    if case == "huge_within_limits":  # 8 GB declared, 0 bytes held: refused before any data is read
        for key, shape in (("actions", (10**9,)), ("head_pan", (10**9,)), ("pose", (10**9 + 1, 3))):
            members[key] = _header_only(shape, "<i8" if key == "actions" else "<f8")
        return _npz(members), "header declares 8000000000 bytes"
    if case == "trailing_data":
        members["dt"] = members["dt"] + b"\0" * 8
        return _npz(members), "field 'dt'"
    if case == "object_array":
        members["meta"] = _npy(np.array([{"a": 1}], dtype=object))
        return _npz(members), "pickle"
    raise ValueError(case)


CORRUPT = ["bit_flip", "zlib_stream", "compression_method", "zip_version", "dropped_members", "truncated",
           "array_header", "array_header_syntax", "huge_rows", "huge_within_limits", "trailing_data", "object_array"]


def _learn_fails_with_one_line(bad, expect: str, tmp_path, capsys) -> None:
    out = tmp_path / "m.json"
    assert main(["learn", str(bad), "--out", str(out), "--max-iter", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"aibo: error: {bad}") and expect in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("case", CORRUPT)
def test_corrupt_log_is_one_line(case, log, tmp_path, capsys, monkeypatch):
    data, expect = corrupt(case, log, tmp_path)
    bad = tmp_path / f"{case}.npz"
    bad.write_bytes(bytes(data))
    if case.startswith("huge"):
        def no_data(*args, **kwargs):
            raise AssertionError("array data read before the header was checked")

        monkeypatch.setattr(np.lib.format, "read_array", no_data)
    _learn_fails_with_one_line(bad, expect, tmp_path, capsys)


def _model(log, tmp_path) -> bytes:
    assert main(["learn", str(log), "--out", str(tmp_path / "m0.json"), "--max-iter", "2"]) == 0
    return (tmp_path / "m0.json").read_bytes()


WRONG = {
    "model_file": (lambda log, tmp: _model(log, tmp), "JSON file"),
    "json": (lambda log, tmp: json.dumps([1, 2]).encode(), "JSON file"),
    "empty": (lambda log, tmp: b"", "empty"),
    "png": (lambda log, tmp: b"\x89PNG\r\n\x1a\n" + b"\0" * 40, "PNG"),
    "npy": (lambda log, tmp: _npy(np.zeros(3)), "single .npy"),
    "random": (lambda log, tmp: bytes(range(256)), "no zip signature"),
    "checkpoint_like": (lambda log, tmp: _npz({"cur.disp": _npy(np.zeros((40, 3))), "scalars": _npy(np.array("{}"))}),
                        "field 'format': missing: not an aibo-trajectory log (its members: cur.disp, scalars)"),
}


@pytest.mark.parametrize("case", sorted(WRONG))
def test_wrong_kind_of_file_is_one_line(case, log, tmp_path, capsys):
    make, expect = WRONG[case]
    bad = tmp_path / f"{case}.npz"
    bad.write_bytes(make(log, tmp_path))
    capsys.readouterr()
    _learn_fails_with_one_line(bad, expect, tmp_path, capsys)


def test_real_checkpoint_as_log_is_one_line(log, tmp_path, capsys):
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions

    ckpt = tmp_path / "c.npz"
    learner = EMLearner(EMOptions(max_iter=40), checkpoint_path=ckpt, checkpoint_every=1)

    def stop(rec):
        if rec.iteration == 15:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        learner.fit([trajectory.load(log)], progress=stop)
    _learn_fails_with_one_line(ckpt, "not an aibo-trajectory log", tmp_path, capsys)


@pytest.mark.parametrize("case", ["bit_flip", "array_header_syntax"])
def test_corrupt_log_in_a_fresh_process(case, log, tmp_path):
    data, expect = corrupt(case, log, tmp_path)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(bytes(data))
    r = subprocess.run([sys.executable, "-m", "aibo.cli", "learn", str(bad), "--out", str(tmp_path / "m.json")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith(f"aibo: error: {bad}") and expect in r.stderr


def test_every_single_bit_flip_is_caught_or_harmless(tmp_path):
    """Flip one bit at every byte of a small log: it loads the same arrays, or fails with one
    TrajectoryError; never another exception, never different data."""
    small = tmp_path / "s.npz"
    assert main(["collect", "--steps", "30", "--seed", "1", "--out", str(small)]) == 0
    raw = small.read_bytes()
    good = trajectory.to_arrays(trajectory.load(small))
    bad = tmp_path / "b.npz"
    for pos in range(len(raw)):
        flipped = bytearray(raw)
        flipped[pos] ^= 1 << (pos % 8)
        bad.write_bytes(bytes(flipped))
        try:
            arrays = trajectory.to_arrays(trajectory.load(bad))
        except trajectory.TrajectoryError:
            continue
        assert arrays.keys() == good.keys() and all(np.array_equal(arrays[k], good[k]) for k in good), pos
