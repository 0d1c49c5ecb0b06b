"""Option values are checked up front: one line naming the option, exit status 2, no work done."""

from __future__ import annotations

import subprocess
import sys

import pytest

from aibo import options
from aibo.cli import main
from aibo_core import trajectory

LEARN = ["learn", "no-such-log.npz", "--out", "m.json"]  # the option is refused before the log is read
COLLECT = ["collect", "--out", "c.npz"]

BAD = [
    (LEARN + ["--gate", "nan"], "--gate", "finite"),
    (LEARN + ["--gate", "inf"], "--gate", "finite"),
    (LEARN + ["--gate=-inf"], "--gate", "finite"),
    (LEARN + ["--gate", "-1"], "--gate", ">= 0"),
    (LEARN + ["--gate", "lots"], "--gate", "expected a number"),
    (LEARN + ["--seed", "-1"], "--seed", ">= 0"),
    (LEARN + ["--max-iter", "0"], "--max-iter", ">= 1"),
    (LEARN + ["--patience", "0"], "--patience", ">= 1"),
    (LEARN + ["--max-iter", "1.5"], "--max-iter", "expected an integer"),
    (COLLECT + ["--steps", "0"], "--steps", ">= 1"),
    (COLLECT + ["--steps", "-5"], "--steps", ">= 1"),
    (COLLECT + ["--seed", "-1"], "--seed", ">= 0"),
    (COLLECT + ["--steps", "1000000000000"], "--steps", "more than"),
    (COLLECT + ["--config", '{"sigma_height": NaN}'], "--config", "non-finite number NaN"),
    (COLLECT + ["--config", '{"slip_std": [1, Infinity, 0.1]}'], "--config", "non-finite number Infinity"),
    (COLLECT + ["--config", "[1]"], "--config", "JSON object"),
    (["reproduce", "--seed", "-1", "--out", "r"], "--seed", ">= 0"),
    (["diagnose", "log.npz", "--out", "d", "--jobs", "100000"], "--jobs", "worker processes on"),
    (["diagnose", "log.npz", "--out", "d", "--replicas", "1000000000"], "--replicas", "must be <= 1,000"),
    (["diagnose", "log.npz", "--out", "d", "--rounds", "0"], "--rounds", ">= 1"),
    (LEARN + ["--starts", "1000000"], "--starts", "must be <= 64"),
    (["experiment", "policies", "--out", "d", "--seeds", "1000000000"], "--seeds", "must be <= 10,000"),
    (["experiment", "policies", "--out", "d", "--jobs", "100000"], "--jobs", "worker processes on"),
    (["train-explorer", "--policy", "sb3", "--out", "a.zip", "--n-envs", "100000"], "--n-envs", "worker processes on"),
    (["import", "csv", "log", "--out", "l.npz", "--sensor-pose", "0.2,0"], "--sensor-pose", "expected X,Y,YAW (metres"),
    (["import", "bag", "b.bag", "--commands", "/c", "--detections", "/d", "--landmarks", "m.csv", "--out", "l.npz",
      "--sensor-pose=0.2,0,nan"], "--sensor-pose", "three finite numbers"),
    (["import", "csv", "log", "--out", "l.npz", "--sensor-pose", "250,0,0"], "--sensor-pose", "250 m from the robot's origin"),
    (["import", "csv", "log", "--out", "l.npz", "--sensor-pose", "-0.1,0,90"], "--sensor-pose", "radians, not degrees"),
]


@pytest.mark.parametrize("argv, option, what", BAD, ids=[f"{b[0][0]} {' '.join(b[0][-2:])}" for b in BAD])
def test_bad_option_is_one_line_before_any_work(argv, option, what, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"aibo: error: argument {option}") and what in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_huge_step_count_is_refused_at_once_in_a_fresh_process(tmp_path):
    r = subprocess.run([sys.executable, "-m", "aibo.cli", "collect", "--steps", "1000000000000", "--out",
                        str(tmp_path / "c.npz")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stdout == "" and "Traceback" not in r.stderr
    assert r.stderr.count("\n") == 1 and "argument --steps" in r.stderr and "more than" in r.stderr


def test_step_limit_follows_memory(monkeypatch):
    """At most MAX_STEPS; fewer when half the machine's memory holds fewer (160 bytes/frame)."""
    assert 0 < options.max_steps() <= options.MAX_STEPS
    pages = {"SC_PHYS_PAGES": 2**20, "SC_PAGE_SIZE": 4096}  # a 4 GiB machine
    monkeypatch.setattr(options.os, "sysconf", pages.__getitem__)
    assert options.max_steps() == 2**31 // options.COLLECT_BYTES_PER_FRAME
    with pytest.raises(Exception, match="half of this machine's memory"):
        options.steps(str(options.max_steps() + 1))
    assert options.steps(str(options.max_steps())) == options.max_steps()


def test_gate_zero_still_means_off(tmp_path):
    from aibo.cli import build_parser
    from aibo.commands.learn import em_options

    args = build_parser().parse_args(LEARN + ["--gate", "0"])
    assert em_options(args).gate is None


def test_collect_gives_the_frames_asked_for_past_the_episode_limit(tmp_path):
    """--steps above the env's default episode limit (27000 frames) is honoured."""
    out = tmp_path / "c.npz"
    assert main(["collect", "--steps", "27300", "--out", str(out)]) == 0
    assert trajectory.load(out).n_frames == 27300
    assert main(["collect", "--steps", "300", "--out", str(out), "--config", '{"max_steps": 100}']) == 0
    assert trajectory.load(out).n_frames == 100  # an explicit episode limit still ends the episode


def _options(parser, where="aibo"):
    """(command, argparse action) of every option and positional of every subcommand."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options(sub, f"{where} {name}")
        elif not isinstance(action, argparse._HelpAction):
            yield where, action


def test_every_option_says_what_it_does_and_its_default():
    """--seed and --max-iter had no description; learn --starts named a class attribute; reproduce --out hid it."""
    import argparse

    from aibo.cli import build_parser

    for where, action in _options(build_parser()):
        name = f"{where} {action.option_strings[-1] if action.option_strings else action.dest}"
        assert action.help, f"{name}: no help text"
        assert "EMOptions" not in action.help, f"{name}: names a class, not a value"
        valued = action.option_strings and not isinstance(action, (argparse._StoreTrueAction,
                                                                   argparse.BooleanOptionalAction))
        if valued and action.default not in (None, {}, False):
            assert "default" in action.help, f"{name}: default {action.default!r} not in its help"


def test_the_agents_extra_is_named_with_the_cpu_torch_advice(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # import stable_baselines3 raises ImportError
    assert main(["collect", "--steps", "30", "--policy", "explorer", "--out", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'.[agents]'" in err and "CPU-only torch first" in err


@pytest.mark.parametrize("command, says", [
    (["collect", "--steps", "30", "--out", "x.npz"], "no output was written"),
    (["learn", "log.npz", "--out", "m.json"], "resumes from the checkpoint"),
    (["experiment", "policies", "--out", "sweep"], "results.jsonl"),
])
def test_an_interrupt_says_what_it_left(command, says, monkeypatch, capsys):
    """Every interrupt said 'a learn run resumes from its checkpoint', whatever the command."""
    from aibo import commands

    def interrupt(args):
        raise KeyboardInterrupt

    for name in ("run_collect", "run_learn", "run_experiment"):
        monkeypatch.setattr(commands, name, interrupt)
    assert main(command) == 130
    err = capsys.readouterr().err
    assert err.startswith("aibo: interrupted; ") and says in err and err.count("\n") == 1


def _modules_after(code: str) -> set[str]:
    """The modules a fresh interpreter holds after running ``code``."""
    r = subprocess.run([sys.executable, "-c", code + "\nimport sys; print(' '.join(sys.modules))"], capture_output=True,
                       text=True, timeout=120, check=True)
    return set(r.stdout.split())


def test_help_and_the_learn_command_import_only_what_they_need():
    """Start-up: 'aibo --help' loads no NumPy (it took 3 s when the parser's option defaults pulled in the model's
    SciPy); 'aibo learn' loads neither scipy.stats (lag.py, only for continuous commands) nor scipy.optimize
    (landmark_bias, only with that effect) until they are used."""
    helped = _modules_after("from aibo.cli import main\ntry:\n    main(['learn', '--help'])\nexcept SystemExit:\n    pass")
    assert not {"numpy", "scipy", "learners.model"} & helped
    learn = _modules_after("import aibo.commands.learn")
    assert "numpy" in learn and not {"scipy.stats", "scipy.optimize", "scipy.special"} & learn
