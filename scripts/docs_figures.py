"""The figures and headline numbers the docs quote that a command produces, from that command.

    python scripts/docs_figures.py                    # aibo reproduce + the reproducibility rows (~3 min, 2 cores)
    python scripts/docs_figures.py --no-portability   # aibo reproduce only (~30 s)

Runs ``aibo reproduce`` (seed 1, the default recipe, the command as a user runs it) and copies its
``sensor_model.png`` and ``velocity_error.png`` to ``docs/img/``; with the portability rows (default) it reruns
the same command under the four numba / OpenBLAS settings of docs/reproducibility.md. Everything is written to
``docs/img/numbers.json``:

- ``reproduce.table``: the error table exactly as ``aibo reproduce`` prints it (docs/results.md quotes it
  verbatim), ``reproduce.numbers``: its EM and oracle errors, iterations and error / bound ratios;
- ``portability``: one row per setting (iterations, vx / vy / vtheta RMS, EM wall s, ms per iteration) and
  ``repeat_identical``: whether two runs of the default setting wrote the same ``model_em.json``, byte for byte.

``tests/test_docs.py`` checks that the docs quote these numbers (and that every image a doc links exists); its
slow test reruns ``aibo reproduce`` and compares with this file. Rerun this script after a change that moves the
numbers, look at the figures, and update the quoted text.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aibo_core.atomic import atomic_write, write_json  # noqa: E402

IMG = ROOT / "docs" / "img"
NUMBERS = IMG / "numbers.json"
FIGURES = ("sensor_model.png", "velocity_error.png")
#: docs/reproducibility.md's rows: (numba code, OpenBLAS kernels, extra environment)
SETTINGS = (
    ("native (default)", "auto (default)", {}),
    ("`NUMBA_CPU_NAME=generic`", "auto (default)", {"NUMBA_CPU_NAME": "generic"}),
    ("native", "`OPENBLAS_CORETYPE=Prescott`", {"OPENBLAS_CORETYPE": "Prescott"}),
    ("`NUMBA_CPU_NAME=generic`", "`OPENBLAS_CORETYPE=Prescott`",
     {"NUMBA_CPU_NAME": "generic", "OPENBLAS_CORETYPE": "Prescott"}),
)
TABLE_START = re.compile(r"^\s+paper\s+EM\s+oracle\s*$")


def run_reproduce(out: Path, env_extra: dict[str, str] | None = None, cache: Path | None = None) -> tuple[str, dict]:
    """Run ``aibo reproduce --out OUT`` in a fresh process (this checkout's code); its stdout and report.json.
    ``cache``: a numba cache folder of its own (the generic settings must never share the host's)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), **(env_extra or {}))
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    proc = subprocess.run([sys.executable, "-m", "aibo.cli", "reproduce", "--out", str(out)], cwd=ROOT, env=env,
                          capture_output=True, text=True, check=False)
    if not (out / "report.json").exists():  # a missed bar may exit non-zero, but it writes its report
        raise SystemExit(f"aibo reproduce failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return proc.stdout, json.loads((out / "report.json").read_text())


def printed_table(stdout: str) -> str:
    """The error table of ``aibo reproduce``'s output: from its header line through the 'iterations' row."""
    lines = stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if TABLE_START.match(line))
    end = next(i for i in range(start, len(lines)) if lines[i].startswith("iterations"))
    return "\n".join(lines[start:end + 1])


def headline(report: dict) -> dict[str, Any]:
    """The numbers the docs quote from one ``aibo reproduce`` report (rounded as the docs print them)."""
    em, oracle, bound = report["em"], report["oracle"], report["bound"] or {}
    out: dict[str, Any] = {"iterations": report["iterations"], "best_iteration": report["best_iteration"],
                           "converged": report["converged"], "bar_met": all(report["bar"].values())}
    for key in ("vx_rms", "vy_rms"):
        out[f"em_{key}"], out[f"oracle_{key}"] = round(em[key], 2), round(oracle[key], 2)
    out["em_vtheta_rms"], out["oracle_vtheta_rms"] = round(em["vtheta_rms"], 4), round(oracle["vtheta_rms"], 4)
    for key in ("vx_rel", "vy_rel", "vtheta_rel", "sigma_height_rel", "sigma_angle_rel"):
        out[f"em_{key}_pct"], out[f"oracle_{key}_pct"] = round(100 * em[key], 2), round(100 * oracle[key], 2)
    out["em_sensor_rms_px"], out["oracle_sensor_rms_px"] = round(em["sensor_rms_px"], 3), round(oracle["sensor_rms_px"], 3)
    for axis in ("vx", "vy", "vtheta"):
        if f"{axis}_bound" in bound:
            out[f"{axis}_bound_pct"] = round(100 * bound[f"{axis}_bound"], 2)
            out[f"{axis}_error_over_bound"] = round(em[f"{axis}_rel"] / bound[f"{axis}_bound"], 2)
            out[f"{axis}_bound_over_oracle"] = round(bound[f"{axis}_bound"] / oracle[f"{axis}_rel"], 1)
    return out


def portability_row(label: tuple[str, str], report: dict, model: Path) -> dict[str, Any]:
    """One row of docs/reproducibility.md's table; ``model_sha256``: the first 16 hex digits of the model file's
    digest (equal digests: the same model, bit for bit)."""
    em = report["em"]
    return {"numba": label[0], "openblas": label[1], "iterations": report["iterations"],
            "model_sha256": hashlib.sha256(model.read_bytes()).hexdigest()[:16],
            "vx_rms": round(em["vx_rms"], 4), "vy_rms": round(em["vy_rms"], 4), "vtheta_rms": round(em["vtheta_rms"], 6),
            "em_wall_s": round(report["wall_seconds"], 1), "ms_per_iteration": round(1000 * report["seconds_per_iteration"], 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--no-portability", action="store_true",
                    help="skip the reruns under the four numba / OpenBLAS settings (docs/reproducibility.md)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="aibo-docs-") as tmp:
        run = Path(tmp) / "reproduce"
        stdout, report = run_reproduce(run)
        numbers: dict[str, Any] = {"command": "aibo reproduce (seed 1, default recipe)",
                                   "reproduce": {"table": printed_table(stdout), "numbers": headline(report)}}
        IMG.mkdir(parents=True, exist_ok=True)
        for name in FIGURES:
            data = (run / name).read_bytes()
            atomic_write(IMG / name, lambda f, data=data: f.write(data))
        if not args.no_portability:
            rows = []
            for i, (numba, blas, extra) in enumerate(SETTINGS):
                out = Path(tmp) / f"setting{i}"
                cache = Path(tmp) / "numba-generic" if "NUMBA_CPU_NAME" in extra else None
                rows.append(portability_row((numba, blas), run_reproduce(out, extra, cache)[1], out / "model_em.json"))
                print(f"{numba} / {blas}: {rows[-1]}")
            same = (run / "model_em.json").read_bytes() == (Path(tmp) / "setting0" / "model_em.json").read_bytes()
            numbers["portability"] = {"rows": rows, "repeat_identical": same}
        elif NUMBERS.exists():  # keep the last portability rows
            old = json.loads(NUMBERS.read_text())
            if "portability" in old:
                numbers["portability"] = old["portability"]
    write_json(NUMBERS, numbers)
    print(numbers["reproduce"]["table"])
    print(f"wrote {NUMBERS.relative_to(ROOT)} and docs/img/{', docs/img/'.join(FIGURES)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
