"""``aibo import bag``: a ROS 1 or ROS 2 bag (or MCAP file) as an aibo-trajectory/2 log (``aibo_core.rosbag_import``)."""

from __future__ import annotations

import time

from aibo.commands.import_log import summary
from aibo.errors import CLIError
from aibo.paths import check_files, declared_inputs
from aibo_core import trajectory
from aibo_core.rosbag_import import BagOptions, import_bag
from aibo_core.timed_log import LogSourceError, SensorPose, sensor_from_option


def msg_defs(values: list[str] | None) -> tuple[tuple[str | None, str], ...]:
    """``--msg-def`` values, ``FILE.msg`` (the detections' type) or ``pkg/msg/Type=FILE.msg``, as (type, file)."""
    out = []
    for value in values or []:
        name, sep, file = value.rpartition("=")
        out.append((name if sep and name else None, file))
    return tuple(out)


def run(args) -> int:
    if args.base_frame != "base_link" and args.sensor_pose != "tf":
        raise CLIError(f"--base-frame {args.base_frame}: used only with --sensor-pose tf (the frame the static "
                       "transforms place the sensor under)")
    defs = msg_defs(args.msg_def)
    extra = [("bag", args.bag), ("--landmarks", args.landmarks)] + [("--msg-def", f) for _, f in defs]
    check_files(inputs=declared_inputs(args, extra), outputs=[("--out", args.out)])
    opts = BagOptions(detections=args.detections, commands=args.commands, odometry=args.odometry, truth=args.truth,
                      id_field=args.id_field, range_field=args.range_field, bearing_field=args.bearing_field,
                      marker_frame=args.marker_frame, time=args.time, msg_defs=defs,
                      sensor=SensorPose() if args.sensor_pose == "tf" else sensor_from_option(args.sensor_pose),
                      sensor_from_tf=args.sensor_pose == "tf", base_frame=args.base_frame)
    t0 = time.perf_counter()
    try:
        tr = import_bag(args.bag, args.landmarks, opts, args.dt)
    except LogSourceError as exc:
        raise CLIError(str(exc)) from None
    trajectory.save(tr, args.out)
    source = f"commands from {args.commands}" if args.commands else f"odometry {args.odometry} as the commands"
    print(summary(args.out, tr, time.perf_counter() - t0) + f"; {source}")
    return 0
