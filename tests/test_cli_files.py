"""Files through the CLI: an output never overwrites an input (also via symlinks and hard links),
long legal names work, and the checkpoint name stays within NAME_MAX."""

from __future__ import annotations

import os

import pytest

from aibo.cli import main
from aibo.paths import CHECKPOINT_SUFFIX, checkpoint_path, name_max
from tests._errors import one_line_error as _one_line_error


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    path = tmp_path_factory.mktemp("files") / "a.npz"
    assert main(["collect", "--steps", "1800", "--seed", "1", "--out", str(path)]) == 0
    return path




def _alias(kind: str, log, tmp_path):
    """A path that names ``log``: itself, a symlink to it, a hard link, or a roundabout spelling."""
    if kind == "same":
        return log
    alias = tmp_path / f"{kind}.npz"
    if kind == "symlink":
        alias.symlink_to(log)
    elif kind == "hardlink":
        os.link(log, alias)
    else:
        return log.parent / ".." / log.parent.name / log.name
    return alias


@pytest.mark.parametrize("kind", ["same", "symlink", "hardlink", "dotdot"])
def test_learn_refuses_out_that_is_its_log(kind, log, tmp_path, capsys):
    before = log.read_bytes()
    out = _alias(kind, log, tmp_path)
    assert main(["learn", str(log), "--out", str(out), "--max-iter", "2"]) == 2
    _one_line_error(capsys, f"--out {out}", f"log {log}", "never overwritten")
    assert log.read_bytes() == before


def test_learn_refuses_out_that_is_its_init(log, tmp_path, capsys):
    model = tmp_path / "m.json"
    assert main(["learn", str(log), "--out", str(model), "--max-iter", "2"]) == 0
    capsys.readouterr()
    before = model.read_bytes()
    link = tmp_path / "link.json"
    link.symlink_to(model)
    assert main(["learn", str(log), "--init", str(link), "--out", str(model), "--max-iter", "2"]) == 2
    _one_line_error(capsys, "--out", "--init")
    assert model.read_bytes() == before


def test_learn_refuses_a_log_where_its_checkpoint_goes(log, tmp_path, capsys):
    """The checkpoint beside --out is deleted after the fit: it must not be a log."""
    os.link(log, tmp_path / f"m.json{CHECKPOINT_SUFFIX}")
    assert main(["learn", str(tmp_path / f"m.json{CHECKPOINT_SUFFIX}"), "--out", str(tmp_path / "m.json")]) == 2
    _one_line_error(capsys, "checkpoint", "never overwritten")
    assert (tmp_path / f"m.json{CHECKPOINT_SUFFIX}").read_bytes() == log.read_bytes()


def test_learn_refuses_plots_into_a_file(log, tmp_path, capsys):
    assert main(["learn", str(log), "--out", str(tmp_path / "m.json"), "--plots", str(log), "--max-iter", "2"]) == 2
    _one_line_error(capsys, f"--plots {log}: is a file")
    assert not (tmp_path / "m.json").exists()


def test_learn_refuses_plots_over_its_log(log, tmp_path, capsys):
    inp = tmp_path / "loglik.png"
    os.link(log, inp)
    assert main(["learn", str(inp), "--out", str(tmp_path / "m.json"), "--plots", str(tmp_path)]) == 2
    _one_line_error(capsys, "--plots figure", "never overwritten")


@pytest.mark.parametrize("kind", ["same", "symlink"])
def test_collect_refuses_plot_over_out(kind, tmp_path, capsys):
    out = tmp_path / "c.npz"
    plot = out if kind == "same" else tmp_path / "c.png"
    if kind == "symlink":
        plot.symlink_to(out)
    assert main(["collect", "--steps", "50", "--out", str(out), "--plot", str(plot)]) == 2
    _one_line_error(capsys, "--plot", "--out")
    assert not out.exists()


def test_reproduce_refuses_a_file_as_its_folder(tmp_path, capsys):
    (tmp_path / "f").write_text("mine")
    assert main(["reproduce", "--quick", "--out", str(tmp_path / "f")]) == 2
    _one_line_error(capsys, "is a file, not a folder")
    assert (tmp_path / "f").read_text() == "mine"


@pytest.mark.parametrize("length", [20, 235, 240, 241, 250, 255])
def test_checkpoint_name_fits_name_max(length, tmp_path):
    out = tmp_path / ("m" * (length - 5) + ".json")
    path = checkpoint_path(out)
    assert path.parent == tmp_path and path.name.endswith(CHECKPOINT_SUFFIX)
    assert len(os.fsencode(path.name)) <= name_max(tmp_path)
    if length + len(CHECKPOINT_SUFFIX) <= 255:
        assert path.name == out.name + CHECKPOINT_SUFFIX  # unchanged, so old checkpoints still resume
    else:
        assert path != checkpoint_path(tmp_path / ("m" * (length - 5) + ".jsox"))  # names differ by the hash


def test_checkpoint_name_does_not_split_a_character(tmp_path):
    path = checkpoint_path(tmp_path / ("é" * 120 + ".json"))  # 245 bytes
    assert len(os.fsencode(path.name)) <= 255 and path.name.encode("utf-8")


def test_long_legal_names_work_end_to_end(tmp_path, capsys):
    """A 244-byte log name and a 250-byte model name (its checkpoint would be 265 bytes)."""
    log = tmp_path / ("l" * 240 + ".npz")
    model = tmp_path / ("m" * 245 + ".json")
    assert main(["collect", "--steps", "1800", "--seed", "1", "--out", str(log)]) == 0
    assert main(["learn", str(log), "--out", str(model), "--max-iter", "45", "--patience", "100"]) == 0
    assert "45 iterations" in capsys.readouterr().out  # past the checkpoints at iterations 20 and 40
    assert sorted(os.listdir(tmp_path)) == sorted([log.name, model.name])


def test_too_long_name_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / ("x" * 252 + ".npz")
    assert main(["collect", "--steps", "50", "--out", str(out)]) == 2
    _one_line_error(capsys, "256 bytes", "at most 255")
