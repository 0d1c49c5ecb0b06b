"""The report page's figure of the calibrated check shows what disagrees, before and after the named effects."""

from __future__ import annotations

from aibo.diagnose_report import calibrated_bars, calibrated_rows


def _check(zs: dict[str, float | None]) -> dict:
    return {"statistics": [{"statistic": k, "z": z} for k, z in zs.items()], "disagree_z": 5.4, "replicas": 8}


def test_a_disagreement_the_named_effects_brought_is_among_the_rows_shown():
    before = _check({"calm, then off": 0.5, "off, then mended": 9.0, "mild both times": 3.0, "no spread": None})
    after = _check({"calm, then off": -12.0, "off, then mended": 0.4, "mild both times": 3.5, "no spread": 1.0})
    rows = [r["statistic"] for r in calibrated_rows(before, after, n=2)]
    assert rows == ["calm, then off", "off, then mended"]  # by the larger |z| of the two checks, the worst first
    assert [r["statistic"] for r in calibrated_rows(before, None, n=2)] == ["off, then mended", "mild both times"]
    assert "no spread" not in [r["statistic"] for r in calibrated_rows(before, after, n=10)]


def test_the_calibrated_figure_is_written_with_one_row_or_many(tmp_path):
    for n in (1, 12):
        zs = {f"statistic {i}": float(i) - 3.0 for i in range(n)}
        path = tmp_path / f"calibrated_{n}.png"
        calibrated_bars(path, _check(zs), _check({k: -z for k, z in zs.items()}))
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_page_says_how_many_sightings_were_set_aside_before_the_diagnosis():
    """report.json["outliers"] on the page: "none of N" when the search set none aside, else the count and share."""
    from aibo.diagnose_report import _set_aside

    none = {"set_aside": 0, "sightings": 4776, "share": 0.0, "gate_mahalanobis2": 50.0}
    assert _set_aside(none).endswith("under the search's base model): none of 4776.")
    some = dict(none, set_aside=101, sightings=4991, share=101 / 4991)
    assert _set_aside(some).endswith("): 101 of 4991 (2.0%); no fit or score here sees them.")
    assert "Mahalanobis^2 &gt; 50 " in _set_aside(some) and _set_aside(None) == ""


class _Stream:
    def __init__(self, tty: bool) -> None:
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def test_a_long_terminal_line_is_wrapped_on_a_terminal_and_left_whole_in_a_pipe(monkeypatch):
    """``aibo diagnose``'s lines (a 'still unlike' reading runs to 700-900 characters) wrap at the terminal's width at
    words, the continuation indented past the line's own; a pipe or file (scripts, tests) gets them whole."""
    import os

    from aibo.report import for_terminal

    monkeypatch.setattr("shutil.get_terminal_size", lambda *a, **k: os.terminal_size((81, 24)))
    line = "  still unlike its simulation: " + " ".join(f"word{i}" for i in range(60))
    text = line + "\nshort"
    assert for_terminal(text, _Stream(False)) == text
    wrapped = for_terminal(text, _Stream(True)).split("\n")
    assert len(wrapped) > 3 and wrapped[-1] == "short" and all(len(w) <= 80 for w in wrapped)
    assert wrapped[0].startswith("  still") and all(w.startswith("      word") for w in wrapped[1:-1])
    assert " ".join(w.strip() for w in wrapped[:-1]) == line.strip()  # nothing lost, nothing added
