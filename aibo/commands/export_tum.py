"""``aibo export tum``: a fitted model's smoothed poses of a log (and the log's truth) in the TUM format.

The smoothed track is the one ``aibo learn`` scores against ground truth (``learners.scoring.smoothed_poses``,
with the fit's outlier gate), so ``evo_ape tum GT.tum EST.tum`` gives the RMS position error ``aibo learn`` prints
as "smoothed pose RMS". The truth file leaves out the poses inside ground-truth gaps (``meta["pose_gaps"]``), as
the score does; evo pairs the two files by timestamp.
"""

from __future__ import annotations

from aibo.data_errors import naming_files
from aibo.errors import CLIError
from aibo.paths import check_files, declared_inputs
from aibo_core import trajectory
from aibo_core.timed_log import pose_valid
from aibo_core.tum import frame_times, write_tum


def run(args) -> int:
    from learners.em.learner import check_model_fits
    from learners.model.io import load_model
    from learners.scoring import pose_scores, smoothed_poses

    outputs = [("--out", args.out)] + ([("--truth", args.truth)] if args.truth else [])
    check_files(inputs=declared_inputs(args, [("log", args.log)]), outputs=outputs)
    tr = trajectory.load(args.log)
    if args.truth and tr.pose is None:
        raise CLIError(f"{args.log}: field 'pose': missing, so there is no truth for --truth (a log imported with truth has it)")
    model = load_model(args.model)
    with naming_files([args.log], args.model):
        check_model_fits(model, [tr])
    (track,), _ = smoothed_poses(model, [tr])
    t = frame_times(tr)
    note = f"smoothed poses of {args.log} under {args.model} (aibo export tum)"
    write_tum(args.out, t, track, note)
    line = f"wrote {args.out}: {len(t)} smoothed poses"
    if args.truth:
        ok = pose_valid(tr)
        write_tum(args.truth, t[ok], tr.pose[ok], f"ground truth of {args.log} (aibo export tum)")
        rms = pose_scores(model, [tr])["pose_rms"]
        line += f"; {args.truth}: {int(ok.sum())} true poses (smoothed pose RMS {rms:.1f} mm, as aibo learn scores it)"
    print(line)
    return 0
