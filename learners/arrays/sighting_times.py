"""Sightings made between frame ends, each predicted at its own time rather than at its frame's end.

A real robot's camera does not fire at the frame boundaries. An importer puts each sighting at the frame whose end
is nearest its time (``aibo_core.timed_log``) and keeps that time from the end, tau (s, within +-dt / 2; the log's
``sighting_time``, ``Batch.sight_time``). Over tau the robot moves on with its frame's mean motion, so a sighting's
prediction at the end pose is moved, to first order, by tau times the measurement's rate of change there:

    bearing:  d beta / dt = -omega + (v_x sin beta - v_y cos beta) / r
    range:    d r / dt    = -(v_x cos beta + v_y sin beta)

(v_x, v_y, omega) the frame's lowered displacement over dt (mm/s, mm/s, rad/s; the world-frame offset's turn
included), beta and r the sighting's own bearing (rad) and range (mm). The measured values stand in for the predicted
ones in the rate: their noise moves the correction by tau x (v / r) x their relative error, well under a mrad. A size
sensor (``height_px``) measures no range: its bearing gets the turn's term alone, and its size nothing.

The turn's term is the large one: at 0.3 rad/s a sighting 50 ms before its frame's end is 15 mrad off in bearing, as
much as a camera's noise (MRCLAM: the bearing error against Vicon 4.3-4.4 mrad RMS from this alone on robots 3 and 5;
docs/results.md, "Sightings between frames"). Logs without ``sighting_time`` (every simulator here) are unchanged.
The correction is a function of the model's own motion (its lag and effects included) and enters every computation
through ``Lowered.bearing_offset`` and ``size_offset``: no kernel knows of it. EM's M-steps take it as given in each
iteration, as they take every offset.
"""

from __future__ import annotations

import numpy as np

from .batch import Batch
from .lowered import Lowered


def at_sighting_times(lo: Lowered, batch: Batch, range_sensor: bool) -> None:
    """Move ``lo``'s predictions of ``batch``'s sightings from their frames' ends to their own times (module
    docstring): adds to ``lo.bearing_offset`` (rad) and, for a range sensor, to ``lo.size_offset`` (mm; through the
    curve's slope and the sighting's ``size_scale``). Replaces the arrays, never writes into them."""
    if batch.sight_time is None or batch.n_sightings == 0:
        return
    tau = batch.sight_time
    frame = batch.sight_frame
    vx, vy = lo.disp[frame, 0] / batch.dt, lo.disp[frame, 1] / batch.dt
    omega = (lo.disp[frame, 2] + lo.offset[frame, 2]) / batch.dt
    beta = batch.sight_value[:, 1]
    bearing_rate = -omega
    if range_sensor:
        r = np.maximum(batch.sight_value[:, 0], 1.0)
        bearing_rate = bearing_rate + (vx * np.sin(beta) - vy * np.cos(beta)) / r
        range_rate = -(vx * np.cos(beta) + vy * np.sin(beta))
        lo.size_offset = lo.size_offset + lo.size_scale * lo.curve(r)[1] * range_rate * tau
    lo.bearing_offset = lo.bearing_offset + bearing_rate * tau
