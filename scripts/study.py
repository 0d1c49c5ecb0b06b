"""What the MRCLAM study scripts share (``mrclam_diagnose.py``, ``mrclam_crossval.py``, ``mrclam_ablation.py``,
``lag_recovery.py``): their arguments (the dataset folder, ``--out``, ``--robots``), the ``aibo`` command run and
timed as a user runs it, and the resumable loop that runs each unfinished row, keeps the finished ones in a
JSON-lines file and rewrites OUT/table.md after each."""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aibo_core.atomic import atomic_write, read_jsonl, write_jsonl  # noqa: E402

#: Where the tests and studies find MRCLAM Dataset 7 (never copied into the repository).
DATA = ROOT / ".." / "shared" / "data" / "mrclam7"


def mrclam_parser(doc: str, out: str) -> argparse.ArgumentParser:
    """A parser described by the script's docstring's first line, with DATA, ``--out`` (default ``out``) and
    ``--robots``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(DATA))
    ap.add_argument("--out", default=out)
    ap.add_argument("--robots", default="1,2,3,4,5", help="comma-separated robot numbers (default 1,2,3,4,5)")
    return ap


def add_diagnose_options(ap: argparse.ArgumentParser) -> None:
    """``--candidates`` and ``--rounds``, passed on to ``aibo diagnose`` (default: the command's own)."""
    ap.add_argument("--candidates", default=None, help="aibo diagnose --candidates (default: its default candidates)")
    ap.add_argument("--rounds", type=int, default=None, help="aibo diagnose --rounds (default: its default)")


def diagnose_options(args: argparse.Namespace) -> list[str]:
    """The ``aibo diagnose`` arguments of ``add_diagnose_options``' options that were given."""
    return ((["--candidates", args.candidates] if args.candidates else [])
            + (["--rounds", str(args.rounds)] if args.rounds else []))


def robots(arg: str) -> list[int]:
    """The robot numbers of ``--robots``."""
    return [int(x) for x in arg.split(",")]


def data_folder(script: str, data: str) -> Path | None:
    """The dataset folder, or None after one line on stderr naming ``script`` when there is none."""
    path = Path(data)
    if not path.is_dir():
        print(f"{script}: no MRCLAM data at {path}", file=sys.stderr)
        return None
    return path


def run_aibo(args: list[str]) -> tuple[float, subprocess.CompletedProcess]:
    """``python -m aibo.cli ARGS`` as a user runs it: (wall seconds, the finished process)."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "aibo.cli", *args], capture_output=True, text=True)
    return time.perf_counter() - t0, done


def resume(out: Path, rows_file: str, keys: list[dict[str, Any]], run: Callable[[dict[str, Any]], dict[str, Any]],
           table: Callable[[list[dict[str, Any]]], str],
           progress: Callable[[dict[str, Any], str], None] | None = None) -> list[dict[str, Any]]:
    """Every row of ``keys`` (each a dict its row holds, e.g. ``{"robot": 1}``): the finished ones read from
    OUT/``rows_file``, the others made by ``run(key)`` in order, each appended and written at once (atomically), then
    OUT/table.md rewritten from ``table(rows)`` and ``progress(row, table)`` called. Returns every row."""
    out.mkdir(parents=True, exist_ok=True)
    rows = read_jsonl(out / rows_file)
    for key in keys:
        if any(all(r.get(k) == v for k, v in key.items()) for r in rows):
            continue
        rows.append(run(key))
        write_jsonl(out / rows_file, rows)
        md = table(rows)
        atomic_write(out / "table.md", lambda f: f.write(md.encode()))
        if progress is not None:
            progress(rows[-1], md)
    return rows


def noise_cell(scores: dict) -> str:
    """A table cell of ``learners.scoring.motion_noise_scores``: forward / lateral / heading error over the model's sd;
    "?" for a record kept before the motion noise was."""
    from learners.scoring import NOISE_KEYS

    return " / ".join(f"{scores[k]:.2f}" for k in NOISE_KEYS) if all(k in scores for k in NOISE_KEYS) else "?"
