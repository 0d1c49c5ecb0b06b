"""Torch stays out of the core: the tests run without torch and Stable-Baselines3."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib", reason="reading pyproject.toml needs Python 3.11+")

ROOT = Path(__file__).resolve().parents[1]

BLOCKED_RUN = """
import sys, importlib.abc
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("torch", "stable_baselines3"):
            raise ModuleNotFoundError(f"No module named {name!r} (blocked)")
        return None
sys.meta_path.insert(0, Block())
import pytest
sys.exit(pytest.main(sys.argv[1:]))
"""


def _section(readme: str, title: str) -> str:
    start = readme.index(f"## {title}")
    return readme[start : readme.index("\n## ", start + 1)]


def test_extras_keep_sb3_out_of_the_test_extra():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert not any(re.match(r"(stable[-_]baselines3|torch)\b", d) for d in extras["test"])
    assert any(d.startswith("stable-baselines3") for d in extras["agents"])


def test_quick_start_does_not_name_torch_and_ci_installs_every_extra():
    readme = (ROOT / "README.md").read_text()
    assert "torch" not in _section(readme, "Quick start").lower()
    env_section = _section(readme, "Environments")
    assert "pip install torch --index-url https://download.pytorch.org/whl/cpu" in env_section
    assert 'pip install -e ".[agents]"' in env_section and "torch==2.13.0" in env_section
    ci = (ROOT / ".ci" / "run").read_text()
    extras = re.search(r'-e "\.\[([a-z,]+)\]"', ci)
    assert extras and {"test", "agents", "ray", "minari"} <= set(extras.group(1).split(",")), extras
    assert ci.index("torch==2.13.0") < extras.start() < ci.index("python -m pytest")


def test_readme_runs_the_fast_suite_and_ci_runs_it_and_the_slow_studies():
    """The README's test command is the fast suite (pyproject deselects `slow`); CI runs that very command and then
    the slow studies, so nothing marked slow goes untested."""
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"```bash\n(.*?)```", _section(readme, "Quick start"), re.S).group(1).strip().splitlines()
    assert block[-1] == "python -m pytest", block
    addopts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["addopts"]
    assert '-m "not slow"' in addopts
    # on every core: pytest-xdist is in the extra the quick start installs, so `-n auto` is understood there
    assert "-n auto" in addopts
    test_extra = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["test"]
    assert any(d.startswith("pytest-xdist") for d in test_extra)
    ci = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert ci.index("python -m pytest") < ci.index("python -m pytest -m slow")
    assert "-m slow" in _section(readme, "Tests") and "-m \"slow or not slow\"" in _section(readme, "Tests")


def test_every_test_module_imports_without_torch_and_sb3(tmp_path):
    """Collect the whole suite (and run the SB3 tests: they must skip) with both packages blocked."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    args = ["-q", "-p", "no:cacheprovider", "-n", "0", "-rs", "tests/test_gym_sb3.py", "tests/test_env.py::test_sb3_env_checker",
            "tests/test_wheeled_env.py", "tests/test_explorer_policy.py",
            "tests/test_policies_spec.py::test_onboard_policies_need_no_true_pose_and_keep_on_field[explorer]"]
    collect = subprocess.run([sys.executable, "-c", BLOCKED_RUN, "--collect-only", "-q", "-p", "no:cacheprovider",
                              "-n", "0", "tests"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert collect.returncode == 0, collect.stdout[-3000:]
    run = subprocess.run([sys.executable, "-c", BLOCKED_RUN, *args], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-3000:]
    assert run.stdout.count("SKIPPED [") == 4 and "'agents' extra" in run.stdout  # SB3 tests skip, clearly (4 files)
    # the shipped explorer's policy spec refuses in one line naming the extra
    cli = BLOCKED_RUN.replace("import pytest\nsys.exit(pytest.main(", "from aibo.cli import main\nsys.exit(main(")
    out = subprocess.run([sys.executable, "-c", cli, "collect", "--steps", "30", "--policy", "explorer", "--out",
                          str(tmp_path / "log.npz")], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    err = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(err) == 1 and ".[agents]" in err[0], out.stderr[-3000:]
