"""Nothing a user had is lost on the newer commands (issue 22): import never overwrites its
dataset, diagnose never leaves a mixed folder, a refused experiment rerun never empties results."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from aibo.cli import main
from tests.test_mrclam import tiny_dataset


def _one_line_error(capsys, *expect: str) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("aibo: error:"), err
    for text in expect:
        assert text in err[0], err
    return err[0]


def _alias(kind: str, target: Path, tmp_path: Path) -> Path:
    """A path naming ``target``: itself, ``..``, a symlink or a hard link to it."""
    if kind == "same":
        return target
    if kind == "dotdot":
        return target.parent / ".." / target.parent.name / target.name
    alias = tmp_path / f"{kind}.npz"
    if kind == "symlink":
        alias.symlink_to(target)
    else:
        os.link(target, alias)
    return alias


@pytest.mark.parametrize("name", ["Robot1_Odometry.dat", "Barcodes.dat", "Robot2_Measurement.dat"])
@pytest.mark.parametrize("kind", ["same", "dotdot", "symlink", "hardlink"])
def test_import_mrclam_never_overwrites_its_dataset(kind, name, tmp_path, capsys):
    (tmp_path / "data").mkdir()
    data = tiny_dataset(tmp_path / "data")
    target = data / name
    if not target.exists():  # another robot's file: still the dataset's
        target.write_text("# robot 2\n")
    before = {p.name: p.read_bytes() for p in data.iterdir()}
    out = _alias(kind, target, tmp_path)
    assert main(["import", "mrclam", str(data), "--robot", "1", "--out", str(out)]) == 2
    _one_line_error(capsys, f"--out {out}", name, "never overwritten")
    assert {p.name: p.read_bytes() for p in data.iterdir()} == before


def test_import_mrclam_refuses_huge_values(tmp_path, capsys):
    (tmp_path / "data").mkdir()
    data = tiny_dataset(tmp_path / "data")
    lines = (data / "Landmark_Groundtruth.dat").read_text().splitlines()
    lines[5] = "7 1e300 -1.0 0 0"
    (data / "Landmark_Groundtruth.dat").write_text("\n".join(lines) + "\n")
    assert main(["import", "mrclam", str(data), "--robot", "1", "--out", str(tmp_path / "x.npz")]) == 2
    _one_line_error(capsys, "Landmark_Groundtruth.dat", "row 2", "column 2", "1e+300")
    assert not (tmp_path / "x.npz").exists()
