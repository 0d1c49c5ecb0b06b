"""Figures of logs (matplotlib Agg, no display needed)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from aibo_core.atomic import atomic_write
from aibo_core.trajectory import Trajectory

BEACON_COLORS = ["tab:red", "tab:blue", "gold", "tab:purple", "tab:cyan", "tab:orange"]


def _draw_field(ax: Any, tr: Trajectory) -> None:
    if tr.field is not None:
        hl, hw = float(tr.field[0]) / 2, float(tr.field[1]) / 2
        ax.plot([-hl, hl, hl, -hl, -hl], [-hw, -hw, hw, hw, -hw], color="k", lw=1.5)
        ax.plot([0, 0], [-hw, hw], color="0.6", lw=0.8, ls="--")
    counts = np.bincount(tr.sighting_landmark, minlength=len(tr.landmarks))
    for i, (bx, by) in enumerate(tr.landmarks):
        color = BEACON_COLORS[i % len(BEACON_COLORS)]
        ax.scatter([bx], [by], s=160, color=color, edgecolor="k", zorder=5)
        ax.annotate(f"B{i} ({counts[i]} sightings)", (bx, by), textcoords="offset points",
                    xytext=(0, 10 if by >= 0 else -18), ha="center", fontsize=8)


def _draw_path(fig: Any, ax: Any, tr: Trajectory) -> None:
    from matplotlib.collections import LineCollection

    xy = tr.pose[:, :2]
    t = np.arange(len(xy) - 1) * tr.dt
    segs = np.stack([xy[:-1], xy[1:]], axis=1)
    lc = LineCollection(segs, cmap="viridis", linewidths=0.8)
    lc.set_array(t)
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="time (s)", fraction=0.035, pad=0.02)
    step = max(1, tr.n_sightings // 1500)  # keep the figure light
    frames, marks = tr.sighting_frame[::step], tr.sighting_landmark[::step]
    for i in range(len(tr.landmarks)):
        idx = frames[marks == i]
        ax.scatter(xy[idx + 1, 0], xy[idx + 1, 1], s=3, color=BEACON_COLORS[i % len(BEACON_COLORS)],
                   alpha=0.5, zorder=3, label=f"sighting of B{i}")
    ax.scatter([xy[0, 0]], [xy[0, 1]], marker="*", s=120, color="k", zorder=6)
    ax.annotate("start", (xy[0, 0], xy[0, 1]), textcoords="offset points", xytext=(6, 6), fontsize=8)


def plot_trajectory(tr: Trajectory, path: str | os.PathLike, title: str | None = None) -> None:
    """Write a PNG of the field (outline, labelled beacons), the true path coloured by time when
    ``tr.pose`` exists, and the sightings (dots at the robot's position, coloured by beacon).
    Written atomically. Units on the axes: mm."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 6.2), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    _draw_field(ax, tr)
    if tr.pose is not None:
        _draw_path(fig, ax, tr)
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=4, fontsize=7, markerscale=3, frameon=False)
    else:
        ax.text(0, 0, "no true pose in this log", ha="center", va="center", color="0.4")
    minutes = tr.n_frames * tr.dt / 60
    seen = float(np.mean(np.bincount(tr.sighting_frame, minlength=tr.n_frames) > 0))
    ax.set_title(title or f"{tr.n_frames} frames ({minutes:.1f} min), sighting in {seen:.0%} of frames", fontsize=10)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal")
    pad = 400.0
    extent = [] if tr.field is None else [-tr.field / 2, tr.field / 2]
    if tr.pose is not None:
        extent += [tr.pose[:, :2].min(axis=0), tr.pose[:, :2].max(axis=0)]
    xs, ys = np.concatenate([np.reshape(extent, (-1, 2)), tr.landmarks]).T
    ax.set_xlim(xs.min() - pad, xs.max() + pad)
    ax.set_ylim(ys.min() - pad, ys.max() + pad)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png"))
