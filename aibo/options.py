"""Types of the command-line options: each bad value is refused up front, naming the option.

argparse adds the option's name (``argument --gate: must be a finite number >= 0, got nan``); the
parser prints it as one line ``aibo: error: ...`` with exit status 2, before any work.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from typing import Callable

#: Peak memory of ``aibo collect`` per simulated frame (bytes; measured: 160 B/frame at 200k-800k frames).
COLLECT_BYTES_PER_FRAME = 160
#: Most frames one ``aibo collect`` run may simulate: 10^8 frames are 926 hours of robot time at
#: 30 Hz (a real log is about 27,000), about 16 GB while simulating and 15 minutes of CPU.
MAX_STEPS = 10**8
#: Largest JSON file an option (``--config FILE``) may name.
MAX_JSON_FILE_BYTES = 16 * 2**20


def replica_count(text: str) -> int:
    """An option type: 0 (no calibrated-simulator check) or at least ``experiments.calibrated.MIN_REPLICAS``
    (fewer replicas cannot reject anything: their threshold is infinite)."""
    from experiments.calibrated import MIN_REPLICAS

    value = integer(0, MAX_REPLICAS, "each replica simulates the whole log and fits it")(text)
    if 0 < value < MIN_REPLICAS:
        raise argparse.ArgumentTypeError(f"must be 0 (no check) or at least {MIN_REPLICAS} (with fewer the replicas' "
                                         f"spread cannot reject any statistic), got {value}")
    return value


def integer(least: int, most: int | None = None, why: str = "") -> Callable[[str], int]:
    """An option type: an integer >= ``least`` (and <= ``most``, ``why`` saying why)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be >= {least}, got {value}")
        if most is not None and value > most:
            raise argparse.ArgumentTypeError(f"must be <= {most:,d} ({why}), got {value:,d}")
        return value

    return parse


#: Most EM starts one fit screens: each runs 15 EM iterations, and beyond the five fixed distance factors the
#: rest are seeded draws from the same range [0.1, 3]; 64 of them already cost more than the fit.
MAX_STARTS = 64
#: Most calibrated-simulator replicas: each is a simulation of the whole log and a fit.
MAX_REPLICAS = 1000
#: Most seeds per policy and length in a sweep (each is a collect -> learn -> score run).
MAX_SEEDS = 10_000


#: Most worker processes per CPU an option may ask for: each worker is a Python process with NumPy and the
#: compiled kernels loaded (~200 MB), so a thousand of them exhaust memory before any work.
MAX_WORKERS_PER_CPU = 4


def workers(text: str) -> int:
    """An option type: a number of worker processes, 1 .. ``MAX_WORKERS_PER_CPU`` x this machine's CPUs."""
    value = integer(1)(text)
    limit = MAX_WORKERS_PER_CPU * (os.cpu_count() or 1)
    if value > limit:
        raise argparse.ArgumentTypeError(f"{value} worker processes on {os.cpu_count() or 1} CPUs: at most {limit} "
                                         f"({MAX_WORKERS_PER_CPU} per CPU; each holds its own NumPy and kernels)")
    return value


def finite(least: float) -> Callable[[str], float]:
    """An option type: a finite number >= ``least`` (no nan, no inf)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value) or value < least:
            raise argparse.ArgumentTypeError(f"must be a finite number >= {least:g}, got {text}")
        return value

    return parse


#: Farthest a sensor may sit from the robot's origin (m) in ``--sensor-pose``: beyond it the value is no mount on a
#: robot (millimetres given as metres, most likely).
MAX_SENSOR_OFFSET_M = 10.0


#: What ``sensor_pose``'s error adds: only ``aibo import bag`` takes ``tf``.
TF_TOO = "; or tf, for a bag, to read it from the bag's /tf_static"


#: Largest sensor heading (rad) in ``--sensor-pose``: beyond a full turn the value is degrees, most likely.
MAX_SENSOR_YAW_RAD = 2.0 * math.pi


def _x_y_yaw(text: str, tf_too: str) -> tuple[float, float, float]:
    """``sensor_pose``'s parse; ``tf_too``: what its first error adds (``TF_TOO`` for a bag's option)."""
    parts = text.split(",")
    try:
        values = tuple(float(v) for v in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected X,Y,YAW (metres, metres, radians: three finite numbers{tf_too}), "
                                         f"got {text!r}")
    if math.hypot(values[0], values[1]) > MAX_SENSOR_OFFSET_M:
        raise argparse.ArgumentTypeError(f"the sensor {math.hypot(values[0], values[1]):g} m from the robot's origin: at "
                                         f"most {MAX_SENSOR_OFFSET_M:g} m (X and Y are metres), got {text!r}")
    if abs(values[2]) > MAX_SENSOR_YAW_RAD:
        raise argparse.ArgumentTypeError(f"the sensor's heading {values[2]:g} rad is more than a full turn (YAW is "
                                         f"radians, not degrees), got {text!r}")
    return values  # type: ignore[return-value]


def sensor_pose(text: str) -> tuple[float, float, float]:
    """An option type: ``X,Y,YAW``, the sensor's position (m, forward and left of the robot's origin) and heading
    (rad, counter-clockwise of the robot's), each finite, the position within ``MAX_SENSOR_OFFSET_M``, the heading
    within ``MAX_SENSOR_YAW_RAD``. A value that begins with a minus sign (a sensor behind the origin) is taken after
    a space too (``NEGATIVE_VALUED``)."""
    return _x_y_yaw(text, "")


def bag_sensor_pose(text: str) -> tuple[float, float, float] | str:
    """An option type: ``sensor_pose``'s X,Y,YAW, or ``tf`` (the bag's static transforms place the sensor)."""
    return "tf" if text == "tf" else _x_y_yaw(text, TF_TOO)


#: Options whose value may begin with a minus sign (``--sensor-pose -0.1,0,0``: a sensor behind the robot's origin).
#: argparse takes such a value for an option unless it is one plain negative number; ``joined_negative_values`` joins it.
NEGATIVE_VALUED = ("--sensor-pose",)


def joined_negative_values(argv: list[str]) -> list[str]:
    """``argv`` with each ``NEGATIVE_VALUED`` option followed by a value that begins with a minus sign and a digit or a
    point written as one ``--option=value`` argument, which argparse reads as the option's value."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        arg = argv[i]
        nxt = argv[i + 1] if i + 1 < len(argv) else ""
        if arg in NEGATIVE_VALUED and len(nxt) > 1 and nxt[0] == "-" and (nxt[1].isdigit() or nxt[1] == "."):
            out.append(f"{arg}={nxt}")
            i += 2
            continue
        out.append(arg)
        i += 1
    return out


def path(text: str) -> str:
    """An option type: a file or folder name, not empty (an empty one was taken as the current folder, or
    ignored, and some commands failed only after all their work)."""
    if not text:
        raise argparse.ArgumentTypeError("an empty name; give a file or folder")
    return text


def max_steps() -> int:
    """The largest ``--steps``: ``MAX_STEPS``, or fewer when half this machine's memory holds fewer."""
    try:
        memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return MAX_STEPS
    return min(MAX_STEPS, memory // 2 // COLLECT_BYTES_PER_FRAME)


def steps(text: str) -> int:
    """An option type: frames to simulate, 1 .. ``max_steps()``."""
    value = integer(1)(text)
    limit = max_steps()
    if value > limit:
        why = (f"the cap of {MAX_STEPS:,d} frames ({MAX_STEPS / 30 / 3600:,.0f} hours at 30 Hz)" if limit == MAX_STEPS
               else f"what half of this machine's memory holds at {COLLECT_BYTES_PER_FRAME} bytes per frame")
        raise argparse.ArgumentTypeError(f"{value:,d} frames is more than {limit:,d}, {why}; "
                                         "collect several logs and learn from them together")
    return value


class JSONFile(dict):
    """A JSON object read from a file; ``path`` is that file (an input no output may replace)."""

    path: str = ""


def json_object(text: str) -> dict:
    """An option type: a JSON object of finite values (NaN and Infinity are refused), given inline
    (``'{"noise": "aibo"}'``) or as the path of a file holding one (anything not starting with ``{``)."""

    def refuse(constant: str):
        raise ValueError(f"non-finite number {constant}")

    source, path = "inline JSON", ""
    if not text.lstrip().startswith(("{", "[")):
        source, path = f"file {text}", text
        try:
            with open(text, encoding="utf-8") as f:
                text = f.read(MAX_JSON_FILE_BYTES + 1)
        except OSError as exc:
            raise argparse.ArgumentTypeError(f"{text!r} is neither inline JSON (it does not start with '{{') nor a "
                                             f"readable file ({exc.strerror})") from None
        except UnicodeDecodeError:
            raise argparse.ArgumentTypeError(f"{source}: not UTF-8 text") from None
        if len(text) > MAX_JSON_FILE_BYTES:
            raise argparse.ArgumentTypeError(f"{source}: larger than {MAX_JSON_FILE_BYTES // 2**20} MiB")
    try:
        value = json.loads(text, parse_constant=refuse)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"{source}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    except (ValueError, RecursionError) as exc:
        raise argparse.ArgumentTypeError(f"{source}: {exc} (only finite numbers)") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"{source}: must be a JSON object")
    if path:
        value = JSONFile(value)
        value.path = path
    return value
