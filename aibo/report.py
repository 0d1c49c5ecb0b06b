"""Text output shared by the commands: EM progress lines and the paper-style error table."""

from __future__ import annotations

import shutil
import sys
import textwrap
import time

from learners.base import IterationRecord
from learners.metrics import PAPER_SIM, ModelErrors


class Progress:
    """Prints EM progress to stderr: a line every ``every`` iterations (every one on a terminal)."""

    def __init__(self, label: str = "EM", every: int | None = None, stream=None):
        self.label = label
        self.stream = stream or sys.stderr
        self.every = every if every is not None else (1 if self.stream.isatty() else 25)
        self.best = float("-inf")
        self.best_it = 0
        self.t0 = time.perf_counter()

    def __call__(self, rec: IterationRecord) -> None:
        if rec.loglik > self.best:
            self.best, self.best_it = rec.loglik, rec.iteration
        if rec.iteration == 1 or rec.iteration % self.every == 0:
            end = "\r" if self.stream.isatty() else "\n"
            self.stream.write(f"{self.label} iter {rec.iteration:5d}  loglik {rec.loglik:14.3f}  "
                              f"best {self.best:14.3f} (iter {self.best_it})  {1000 * rec.seconds:6.1f} ms/iter{end}")
            self.stream.flush()

    def close(self) -> None:
        if self.stream.isatty():
            self.stream.write("\n")


def for_terminal(text: str, stream=None) -> str:
    """``text`` as printed to ``stream`` (stdout): on a terminal each line longer than its width wrapped at words, the
    continuation indented 4 spaces past the line's own indent (a reading of 700-900 characters is a paragraph); to a
    pipe or file as it is, one line per line (scripts and tests read it)."""
    stream = stream or sys.stdout
    if not stream.isatty():
        return text
    width = max(60, shutil.get_terminal_size().columns - 1)
    out = []
    for line in text.split("\n"):
        indent = " " * (len(line) - len(line.lstrip(" ")))
        out.append(textwrap.fill(line, width, subsequent_indent=indent + "    ", break_on_hyphens=False,
                                 break_long_words=False) if len(line) > width else line)
    return "\n".join(out)


ROWS = [
    ("vx RMS (mm/s)", "vx_rms", "{:.2f}"),
    ("vx RMS / range", "vx_rel", "{:.2%}"),
    ("vy RMS (mm/s)", "vy_rms", "{:.2f}"),
    ("vy RMS / range", "vy_rel", "{:.2%}"),
    ("vtheta RMS (rad/s)", "vtheta_rms", "{:.4f}"),
    ("vtheta RMS / range", "vtheta_rel", "{:.2%}"),
    ("sigma_height error", "sigma_height_rel", "{:.2%}"),
    ("sigma_angle error", "sigma_angle_rel", "{:.2%}"),
    ("sensor RMS (px)", "sensor_rms_px", "{:.3f}"),
]


def error_table(columns: dict[str, ModelErrors | dict], with_paper: bool = True) -> str:
    """Rows of errors, one column per model, optionally beside the paper's section IV-B values."""
    cols = {"paper": PAPER_SIM} if with_paper else {}
    cols.update({k: (v.as_dict() if isinstance(v, ModelErrors) else v) for k, v in columns.items()})
    width = max(12, *(len(c) + 2 for c in cols))
    lines = [f"{'':22s}" + "".join(f"{c:>{width}s}" for c in cols)]
    for label, key, fmt in ROWS:
        cells = [fmt.format(c[key]) if key in c else "-" for c in cols.values()]
        lines.append(f"{label:22s}" + "".join(f"{s:>{width}s}" for s in cells))
    return "\n".join(lines)
