"""The docs against what the commands produce: every image and anchor a doc links exists, the numbers of
``aibo reproduce`` the docs quote equal those ``scripts/docs_figures.py`` recorded in ``docs/img/numbers.json``
(the slow test reruns the command against that file), and the docs' environment snippets run."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
NUMBERS = ROOT / "docs" / "img" / "numbers.json"
LINK = re.compile(r"\]\(([^)\s]+)\)")
FENCE = re.compile(r"```python\n(.*?)```", re.S)


def slug(heading: str) -> str:
    """GitHub's anchor of a markdown heading: lower case, punctuation but '-' and '_' dropped, spaces -> '-'."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    return {slug(m) for m in re.findall(r"^#+\s+(.*)$", text, flags=re.M)}


def broken_links(path: Path, text: str) -> list[str]:
    """The links of ``text`` (the doc at ``path``) to a local file that does not exist, or to an anchor its
    target has no heading for."""
    bad = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+://|mailto:", target):
            continue
        file, _, anchor = target.partition("#")
        dest = (path.parent / file).resolve() if file else path
        if not dest.exists():
            bad.append(f"{path.name}: {target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{path.name}: {target} (no such heading)")
    return bad


def missing_quotes(text: str, numbers: dict) -> list[str]:
    """What of numbers.json a doc should quote and does not: the reproduce table (verbatim)."""
    table = numbers["reproduce"]["table"]
    return [] if table in text else ["the `aibo reproduce` table of docs/img/numbers.json"]


def portability_mismatches(text: str, numbers: dict) -> list[str]:
    """docs/reproducibility.md's table rows whose iterations and velocity errors differ from numbers.json's."""
    bad = []
    for row in numbers.get("portability", {}).get("rows", []):
        cells = (f"| {row['numba']} | {row['openblas']} | {row['iterations']} | {row['vx_rms']:.4f} | "
                 f"{row['vy_rms']:.4f} | {row['vtheta_rms']:.6f} |")
        if cells not in text:
            bad.append(cells)
    return bad


@pytest.fixture(scope="module")
def numbers() -> dict:
    return json.loads(NUMBERS.read_text())


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_every_local_link_exists(path):
    assert broken_links(path, path.read_text()) == []


def test_the_link_check_can_fail():
    doc = ROOT / "docs" / "results.md"
    assert broken_links(doc, "![x](img/no_such_figure.png) [y](architecture.md#no-such-heading) [z](missing.md)") == [
        "results.md: img/no_such_figure.png (no such file)", "results.md: architecture.md#no-such-heading (no such heading)",
        "results.md: missing.md (no such file)"]
    assert broken_links(doc, "[a](architecture.md#the-layers) ![b](img/velocity_error.png)") == []


def test_results_quote_the_reproduce_table(numbers):
    assert missing_quotes((ROOT / "docs" / "results.md").read_text(), numbers) == []
    readme = (ROOT / "README.md").read_text()
    if re.search(r"^\s+paper\s+EM\s+oracle\s*$", readme, flags=re.M):  # the README quotes it too
        assert missing_quotes(readme, numbers) == []


def test_a_changed_number_is_caught(numbers):
    text = (ROOT / "docs" / "results.md").read_text()
    em_vx = f"{numbers['reproduce']['numbers']['em_vx_rms']:.2f}"
    changed = text.replace(numbers["reproduce"]["table"], numbers["reproduce"]["table"].replace(em_vx, "10.58"))
    assert missing_quotes(changed, numbers)


def test_reproducibility_rows(numbers):
    text = (ROOT / "docs" / "reproducibility.md").read_text()
    assert numbers["portability"]["rows"], "docs/img/numbers.json has no portability rows: run scripts/docs_figures.py"
    assert portability_mismatches(text, numbers) == []
    row = numbers["portability"]["rows"][0]
    assert portability_mismatches(text.replace(f"| {row['vx_rms']:.4f} |", "| 10.7053 |"), numbers)


def test_headline_numbers_in_results(numbers):
    """The iterations and error / bound ratios the prose quotes are the table's."""
    n = numbers["reproduce"]["numbers"]
    text = (ROOT / "docs" / "results.md").read_text()
    ratios = f"{n['vx_error_over_bound']:.2f} / {n['vy_error_over_bound']:.2f} / {n['vtheta_error_over_bound']:.2f}"
    bounds = f"{n['vx_bound_pct']:.2f}% / {n['vy_bound_pct']:.2f}% / {n['vtheta_bound_pct']:.2f}%"
    over_oracle = f"{n['vx_bound_over_oracle']:.1f}x / {n['vy_bound_over_oracle']:.1f}x / {n['vtheta_bound_over_oracle']:.1f}x"
    for quoted in (ratios, bounds, over_oracle, f"{n['iterations']} iterations"):
        assert quoted in text, quoted


@pytest.mark.parametrize("doc", ["environments.md"])
def test_environment_snippets_run(doc, capsys):
    """Every Python snippet of the doc that makes an env runs and prints what it says a user checks."""
    blocks = [b for b in FENCE.findall((ROOT / "docs" / doc).read_text()) if "gym.make(" in b and "stable_baselines3" not in b]
    assert len(blocks) >= 2
    for block in blocks:
        assert block.rstrip().splitlines()[-1].startswith("print("), "a snippet ends with what a user checks"
        exec(compile(block, doc, "exec"), {})
    assert capsys.readouterr().out.count("\n") >= len(blocks)


def test_model_vocabulary_snippet_runs(tmp_path, monkeypatch, capsys):
    """architecture.md's "from Python" snippet on a 2-minute simulated log (and an oracle model file as
    ``model.json``): it runs and prints the velocity, the mean size and the standard deviations it names."""
    from aibo_core import trajectory
    from aibo_gym.collect import collect
    from learners.model import io
    from learners.oracle import OracleLearner

    monkeypatch.chdir(tmp_path)
    tr = collect({"noise": "aibo"}, 3600, 3)
    trajectory.save(tr, "log.npz")
    io.save_result(OracleLearner().fit([tr]), "model.json")
    blocks = [b for b in FENCE.findall((ROOT / "docs" / "architecture.md").read_text()) if "load_model" in b]
    assert len(blocks) == 1 and blocks[0].rstrip().splitlines()[-1].startswith("print(")
    exec(compile(blocks[0], "architecture.md", "exec"), {})
    out = capsys.readouterr().out
    assert out.count("[") >= 3, out


@pytest.mark.slow
def test_reproduce_still_gives_the_recorded_numbers(tmp_path, numbers):
    """``aibo reproduce`` now against numbers.json (the same machine gives the same table; another CPU differs in
    the last digits, docs/reproducibility.md: compared to 2%)."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from docs_figures import headline, printed_table, run_reproduce

    stdout, report = run_reproduce(tmp_path / "run")
    now, recorded = headline(report), numbers["reproduce"]["numbers"]
    for key in ("em_vx_rms", "em_vy_rms", "em_vtheta_rms", "em_sensor_rms_px", "oracle_vx_rms"):
        assert np.isclose(now[key], recorded[key], rtol=0.02), (key, now[key], recorded[key])
    if printed_table(stdout) != numbers["reproduce"]["table"]:
        print("the table differs in its last digits (another CPU?): rerun scripts/docs_figures.py on the docs' machine")
