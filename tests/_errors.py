"""The one check every refusal test makes: the command said one line, ``aibo: error: ...``."""

from __future__ import annotations


def one_line_error(capsys, *expect: str) -> str:
    """The command's stderr (read from ``capsys``): exactly one line, starting ``aibo: error:`` and holding each of
    ``expect``; returned."""
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("aibo: error:"), err
    for text in expect:
        assert text in err[0], err
    return err[0]
