"""``aibo import csv``: a folder of CSV files (``aibo_core.csv_import``) as an aibo-trajectory/2 log."""

from __future__ import annotations

import time
from pathlib import Path

from aibo.commands.import_log import summary
from aibo.errors import CLIError
from aibo.paths import check_files, declared_inputs
from aibo_core import trajectory
from aibo_core.csv_import import FILES, import_folder
from aibo_core.timed_log import LogSourceError, sensor_from_option


def run(args) -> int:
    files = [("CSV file", Path(args.folder) / f"{name}.csv") for name in FILES]
    check_files(inputs=declared_inputs(args, files), outputs=[("--out", args.out)])
    t0 = time.perf_counter()
    try:
        tr = import_folder(args.folder, args.dt, sensor_from_option(args.sensor_pose))
    except LogSourceError as exc:
        raise CLIError(str(exc)) from None
    trajectory.save(tr, args.out)
    print(summary(args.out, tr, time.perf_counter() - t0))
    return 0
