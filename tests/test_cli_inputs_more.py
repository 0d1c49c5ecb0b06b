"""Bad input refused up front, in one line naming the option or the file and its line: ``aibo experiment policies``'
options, ``aibo collect --preset`` with ``--model`` and its policy's margin, outputs that cannot be written
(``aibo bench --json``, ``aibo reproduce --out``), what an interrupted ``aibo reproduce`` says, and
``aibo import mrclam``'s files (written here, tiny; the real dataset only where it is present)."""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

import pytest

from aibo.cli import main
from tests._errors import one_line_error as _one_line_error
from tests.test_mrclam import DATA, HEADER, _write, needs_data, tiny_dataset


def _no_work(monkeypatch) -> None:
    """Any simulation or sweep run fails the test: the refusal must come before them."""
    import experiments.executors
    import experiments.loop

    def work(*args, **kwargs):
        raise AssertionError("work started before the input was checked")

    monkeypatch.setattr(experiments.loop, "simulate", work)
    monkeypatch.setattr(experiments.executors, "run_all", work)


# ---------------------------------------------------------------------------------------------- aibo experiment


def _sweep(out: Path, *extra: str) -> list[str]:
    return ["experiment", "policies", "--policies", "uniform", "--minutes", "0.2", "--seeds", "1",
            "--holdout-minutes", "0", "--max-iter", "5", "--backend", "serial", "--out", str(out), *extra]


@pytest.mark.parametrize("params, expect", [
    ('{"unifrom": {"hold_s": 1}}', "--policy-params: 'unifrom' is not one of --policies (uniform)"),
    ('{"informed": {"hold_s": 1}}', "--policy-params: 'informed' is not one of --policies (uniform)"),
    ('{"uniform": {"hold_s": 0}}', "--policy-params: policy 'uniform': hold_s must be positive seconds, got 0"),
    ('{"uniform": {"margin_mm": -5}}', "--policy-params: policy 'uniform': margin_mm must be >= 0"),
    ('{"uniform": {"margin_mm": 1e9}}', "--policy-params: policy 'uniform': margin_mm must be >= 0 and below half"),
])
def test_sweep_policy_params_of_no_policy_or_out_of_range_are_refused(params, expect, tmp_path, monkeypatch, capsys):
    """A typo'd policy, or one not in --policies, had its parameters dropped silently (exit 0); a hold of 0 s was
    found in the first run, after --out was made."""
    _no_work(monkeypatch)
    out = tmp_path / "sweep"
    assert main(_sweep(out, "--policy-params", params)) == 2
    assert _one_line_error(capsys, expect)
    assert not out.exists()


def test_sweep_policy_params_given_a_model_file_is_refused(tmp_path, monkeypatch, capsys):
    _no_work(monkeypatch)
    model = tmp_path / "M.json"
    model.write_text(json.dumps({"format": "aibo-model/1", "action_model": {}, "sensor_model": {}}))
    out = tmp_path / "sweep"
    assert main(_sweep(out, "--policy-params", str(model))) == 2
    _one_line_error(capsys, "--policy-params: 'format' is not one of --policies (uniform)")
    assert not out.exists()


def test_sweep_bad_policy_name_names_policies(tmp_path, monkeypatch, capsys):
    _no_work(monkeypatch)
    out = tmp_path / "sweep"
    assert main(_sweep(out, "--policies", "nope")) == 2
    err = _one_line_error(capsys, "--policies: policy 'nope' (valid choices: ")
    assert "--policy-params" not in err
    assert not out.exists()


@pytest.mark.parametrize("extra, expect", [
    (["--policies", "uniform,uniform"], "--policies uniform,uniform: 'uniform' is given twice"),
    (["--minutes", "0.2,0.2"], "--minutes 0.2,0.2: 0.2 is given twice"),
    (["--minutes", "0.001"], "--minutes 0.001: a run of 0.001 min is 2 frame(s); a fit needs at least"),
    (["--config", '{"max_steps": 10}'], "--config: 'max_steps' 10 ends every run's log at 10 frame(s)"),
    (["--backend", "pool", "--address", "1.2.3.4"], "--address 1.2.3.4: only --backend ray"),
    (["--backend", "serial", "--jobs", "2"], "--jobs 2: --backend serial does one run at a time"),
])
def test_sweep_input_errors_come_before_out_and_name_their_option(extra, expect, tmp_path, monkeypatch, capsys):
    """The same run twice was found after --out was made ('identical specs', naming no option); a log too short for
    any fit died in the first run; --address and --jobs were ignored by the backends that take no such thing."""
    _no_work(monkeypatch)
    out = tmp_path / "sweep"
    assert main(_sweep(out, *extra)) == 2
    _one_line_error(capsys, expect)
    assert not out.exists()


def test_sweep_on_ray_without_ray_is_refused_before_out(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a))
    _no_work(monkeypatch)
    out = tmp_path / "sweep"
    assert main(_sweep(out, "--backend", "ray")) == 2
    _one_line_error(capsys, "--backend ray: Ray is not installed")
    assert not out.exists()


# ------------------------------------------------------------------------------------------------- aibo collect


def test_collect_refuses_a_preset_with_a_model(tmp_path, monkeypatch, capsys):
    """--preset was ignored with --model, yet the log's meta named its noise: the log lied about its noise."""
    from aibo_core import trajectory
    from learners.arrays.batch import make_batch
    from learners.model.io import save_model
    from learners.model.model import start_model
    from tests._logs import sim_log

    tr = sim_log(600)
    log = tmp_path / "L.npz"
    trajectory.save(tr, log)
    model = tmp_path / "M.json"
    save_model(model, start_model(make_batch([tr]), tr.dt, tr.sensor_kind, len(tr.attempted)), {"learner": "test"})
    _no_work(monkeypatch)
    out = tmp_path / "p1.npz"
    assert main(["collect", "--model", str(model), "--preset", "aibo", "--steps", "300", "--seed", "3",
                 "--out", str(out)]) == 2
    _one_line_error(capsys, "--preset aibo: not with --model")
    assert not out.exists()


@pytest.mark.parametrize("margin", ["-5", "1e9", "1800"])
def test_collect_refuses_a_margin_no_path_could_keep(margin, tmp_path, capsys):
    out = tmp_path / "x.npz"
    assert main(["collect", "--steps", "30", "--policy", "uniform", "--policy-params", f'{{"margin_mm": {margin}}}',
                 "--out", str(out)]) == 2
    _one_line_error(capsys, "--policy-params: policy 'uniform': margin_mm must be >= 0 and below half the field's "
                            "shorter side (1800 mm)")
    assert not out.exists()


# ------------------------------------------------------------------------- outputs that cannot be written, up front


def _unwritable(tmp_path: Path) -> list[tuple[Path, str]]:
    """(output path, what the error says) of outputs no command can write."""
    afile = tmp_path / "afile"
    afile.write_text("")
    cases = [(afile / "x" / "out", f"{afile} is a file, not a folder to write in")]
    if sys.platform.startswith("linux") and os.path.isdir("/proc"):
        cases.append((Path("/proc/nope/out"), "the folder /proc/nope does not exist and cannot be made in /proc"))
    return cases


@pytest.mark.parametrize("command", ["bench", "reproduce", "collect"])
def test_an_output_that_cannot_be_written_is_refused_before_the_work(command, tmp_path, monkeypatch, capsys):
    """bench --json /proc/nope/x.json ran ~100 s, then failed with a raw Errno; reproduce simulated first."""
    _no_work(monkeypatch)
    for path, says in _unwritable(tmp_path):
        argv = {"bench": ["bench", "--quick", "--json", f"{path}.json"],
                "reproduce": ["reproduce", "--quick", "--out", str(path)],
                "collect": ["collect", "--steps", "30", "--out", f"{path}.npz"]}[command]
        assert main(argv) == 2
        _one_line_error(capsys, argv[-2] + " " + argv[-1] + ": ", says)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]  # no probe or temp file left


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root writes in a read-only folder")
def test_a_read_only_folder_is_refused_before_the_work(tmp_path, monkeypatch, capsys):
    _no_work(monkeypatch)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert main(["bench", "--quick", "--json", str(ro / "x.json")]) == 2
        _one_line_error(capsys, f"--json {ro / 'x.json'}: cannot write in the folder {ro}")
    finally:
        ro.chmod(0o755)
    assert list(ro.iterdir()) == []


# -------------------------------------------------------------------------------------- an interrupted reproduce


def test_an_interrupt_before_em_says_nothing_was_written(tmp_path, monkeypatch, capsys):
    """It said 'the same command resumes EM from its checkpoint in --out' with no --out and no checkpoint."""
    import experiments.loop

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(experiments.loop, "simulate", interrupt)
    out = tmp_path / "rq2"
    assert main(["reproduce", "--quick", "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert err == "aibo: interrupted; no output was written or changed (each is written whole, at the end)\n", err
    assert not out.exists()


def test_an_interrupt_with_ems_checkpoint_says_it_resumes(tmp_path, monkeypatch, capsys):
    import experiments.loop
    from aibo.cli import build_parser
    from aibo.commands import reproduce

    out = tmp_path / "rq2"
    argv = ["reproduce", "--quick", "--out", str(out)]
    checkpoint = reproduce.run_checkpoint(out, build_parser().parse_args(argv), reproduce.QUICK_STEPS)
    out.mkdir()
    checkpoint.write_bytes(b"")  # left by an interrupted identical run

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(experiments.loop, "simulate", interrupt)
    assert main(argv) == 130
    assert "resumes EM from its checkpoint in --out" in capsys.readouterr().err
    assert main([*argv, "--no-resume"]) == 130
    assert "without --no-resume resumes from it" in capsys.readouterr().err


# -------------------------------------------------------------------------------------------- aibo import mrclam


def _import(folder: Path, *extra: str) -> list[str]:
    return ["import", "mrclam", str(folder), "--robot", "1", "--out", str(folder / "x.npz"), *extra]


def _lines(folder: Path, name: str) -> list[str]:
    return (folder / name).read_text().splitlines()


def _refused(folder: Path, capsys, *expect: str, extra: tuple[str, ...] = ()) -> str:
    assert main(_import(folder, *extra)) == 2
    err = _one_line_error(capsys, *expect)
    assert "np.float64" not in err and "usecols" not in err and "shape" not in err
    assert not (folder / "x.npz").exists()
    return err


def test_a_measurement_file_in_place_of_the_odometry_is_refused(tmp_path, capsys):
    """4 columns where 3 are read: the import took time, barcode and range as time, v and omega (exit 0)."""
    data = tiny_dataset(tmp_path)
    shutil.copy(data / "Robot1_Measurement.dat", data / "Robot1_Odometry.dat")
    _refused(data, capsys, "Robot1_Odometry.dat: expected rows of 3 numbers (time s, v m/s, omega rad/s), got rows "
                           "of 4")


def test_an_odometry_file_in_place_of_the_measurements_is_refused(tmp_path, capsys):
    data = tiny_dataset(tmp_path)
    shutil.copy(data / "Robot1_Odometry.dat", data / "Robot1_Measurement.dat")
    _refused(data, capsys, "Robot1_Measurement.dat: expected rows of 4 numbers", "got rows of 3")


@needs_data
def test_the_real_measurement_file_in_place_of_the_odometry_is_refused(tmp_path, capsys):
    for name in ("Barcodes.dat", "Landmark_Groundtruth.dat", "Robot1_Measurement.dat", "Robot1_Groundtruth.dat"):
        shutil.copy(DATA / name, tmp_path / name)
    shutil.copy(DATA / "Robot1_Measurement.dat", tmp_path / "Robot1_Odometry.dat")
    _refused(tmp_path, capsys, "Robot1_Odometry.dat: expected rows of 3 numbers")


@pytest.mark.parametrize("row, expect", [
    ("100.3 61.5 2.2 0.46", "Robot1_Measurement.dat: line 5, column 2 (barcode): 61.5 is not an integer"),
    ("100.3 63 2.2 100", "Robot1_Measurement.dat: line 5, column 4 (bearing rad): bearing 100 is more than a full "
                         "turn"),
])
def test_a_fractional_barcode_or_a_bearing_beyond_a_turn_is_refused(row, expect, tmp_path, capsys):
    """61.5 went to subject 61; a bearing of 100 rad was wrapped, as the CSV and bag importers refuse it."""
    data = tiny_dataset(tmp_path)
    lines = _lines(data, "Robot1_Measurement.dat")
    lines[4] = row
    (data / "Robot1_Measurement.dat").write_text("\n".join(lines) + "\n")
    _refused(data, capsys, expect)


def test_a_fractional_subject_in_the_barcodes_is_refused(tmp_path, capsys):
    data = tiny_dataset(tmp_path)
    _write(data, "Barcodes.dat", [(1, 5), (2, 14), (6.5, 63), (7, 81), (8, 7)])
    _refused(data, capsys, "Barcodes.dat: line 7, column 1 (subject): 6.5 is not an integer")


def test_a_lag_not_well_below_the_log_is_refused(tmp_path, capsys):
    """--lag 5000 on an 894 s log: exit 0, every command the first one."""
    data = tiny_dataset(tmp_path)
    _refused(data, capsys, "--lag 5000: the log of robot 1 is 10 s long; a lag must be well below", extra=("--lag",
                                                                                                          "5000"))
    _refused(data, capsys, "--lag 1: the log of robot 1 is 10 s long", extra=("--lag", "1"))
    assert main(_import(data, "--lag", "0.2")) == 0


def test_a_file_cut_mid_line_names_the_line(tmp_path, capsys):
    data = tiny_dataset(tmp_path)
    text = (data / "Robot1_Odometry.dat").read_text()
    (data / "Robot1_Odometry.dat").write_text(text[:text.rindex(" \t", 0, len(text) - 1)])  # the last line cut
    n = len(_lines(data, "Robot1_Odometry.dat"))
    err = _refused(data, capsys, f"Robot1_Odometry.dat: line {n} has 2 numbers, the others 3")
    assert "not a table" not in err


@pytest.mark.parametrize("cell, expect", [("abc", "'abc' is not a number"),
                                          ("nan", "nan is not a finite number")])
def test_a_bad_number_names_its_line_as_an_editor_counts(cell, expect, tmp_path, capsys):
    """'abc' on line 10 was 'row 5', 'nan' on the same line 'row 6 of the data' with np.float64(nan)."""
    data = tiny_dataset(tmp_path)
    lines = _lines(data, "Robot1_Odometry.dat")
    fields = lines[9].split()
    lines[9] = " ".join([fields[0], cell, fields[2]])
    (data / "Robot1_Odometry.dat").write_text("\n".join(lines) + "\n")
    _refused(data, capsys, f"Robot1_Odometry.dat: line 10, column 2 (v m/s): {expect}")


def test_a_landmark_listed_twice_names_both_lines(tmp_path, capsys):
    data = tiny_dataset(tmp_path)
    (data / "Landmark_Groundtruth.dat").write_text(HEADER + "6 2.0 1.0 0 0\n\n# a note\n6 4.0 -1.0 0 0\n")
    _refused(data, capsys, "Landmark_Groundtruth.dat: subject 6 is listed on line 5 and on line 8")
