"""``aibo import mrclam``: one robot of the UTIAS MRCLAM dataset as an aibo-trajectory/2 log."""

from __future__ import annotations

import time

from aibo.errors import CLIError
from aibo.paths import check_files, declared_inputs
from aibo_core import trajectory
from aibo_core.mrclam import MRCLAMError, dataset_files, import_robot


def run(args) -> int:
    check_files(inputs=declared_inputs(args, [("dataset file", p) for p in dataset_files(args.folder)]), outputs=[("--out", args.out)])
    t0 = time.perf_counter()
    try:
        tr = import_robot(args.folder, args.robot, dt=args.dt, start_s=args.start, seconds=args.seconds, lag_s=args.lag)
    except MRCLAMError as exc:
        raise CLIError(str(exc)) from None
    trajectory.save(tr, args.out)
    m = tr.meta
    dropped = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in m["dropped"].items() if isinstance(v, int) and v)
    print(f"wrote {args.out}: robot {args.robot}, {tr.n_frames} frames of {tr.dt:g} s ({tr.n_frames * tr.dt / 60:.1f} min), "
          f"{tr.n_sightings} landmark sightings; dropped: {dropped or 'nothing'}; {_truth(tr, args.robot)}; "
          f"{time.perf_counter() - t0:.1f} s")
    return 0


def _truth(tr, robot: int) -> str:
    """What the import line says of the ground truth: its gaps, or that there is none."""
    gaps = tr.meta.get("pose_gaps")
    if gaps is None:
        return f"no ground truth (no Robot{robot}_Groundtruth.dat): the log has no pose to score against"
    return (f"ground-truth gaps > {gaps['threshold_s']:g} s: {gaps['count']} (longest {gaps['longest_s']:.2f} s, "
            f"{gaps['poses_flagged']} poses flagged)" + (f"; {gaps['poses_outside_groundtruth']} poses outside the "
                                                         "ground truth's span flagged"
                                                         if gaps["poses_outside_groundtruth"] else ""))
