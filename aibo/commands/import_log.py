"""What ``aibo import bag`` and ``aibo import csv`` print about the log they wrote."""

from __future__ import annotations

from aibo_core.trajectory import Trajectory


def summary(out: str, tr: Trajectory, seconds: float) -> str:
    """One line: frames, sightings, truth, what was dropped (unknown ids named), the time taken."""
    m = tr.meta
    dropped = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in m["dropped"].items() if v)
    unknown = m.get("unknown_ids", [])
    if unknown:
        shown = ", ".join(str(i) for i in unknown[:10]) + (", ..." if len(unknown) > 10 else "")
        dropped += f" (ids not in the map: {shown})"
    truth = "no truth"
    if tr.pose is not None:
        gaps = m["pose_gaps"]
        truth = (f"truth with {gaps['count']} gaps > {gaps['threshold_s']:g} s ({gaps['poses_flagged']} poses flagged, "
                 f"{gaps['poses_outside_groundtruth']} outside it)")
    return (f"wrote {out}: {tr.n_frames} frames of {tr.dt:g} s ({tr.n_frames * tr.dt / 60:.1f} min), "
            f"{tr.n_sightings} landmark sightings of {len(tr.landmarks)} landmarks, {truth}; dropped: "
            f"{dropped or 'nothing'}; {seconds:.1f} s")
