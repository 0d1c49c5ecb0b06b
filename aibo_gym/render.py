"""Top-down rendering of ``AiboBeacons-v0`` with a small pure-NumPy rasterizer (headless, fast).

Drawn: the field (green, white outline and centre line), the beacons (coloured disks; the one
sighted this frame gets a white ring), the camera's recognition zone (the sector within
``fov/2`` of heading + pan and within ``range_mm``, shaded), the robot (disk with heading line
in black and head direction in yellow) and its trail (last 3000 poses). The image spans the field, the
beacons and a fixed ``start_pose`` (with ``walls="open"`` it may be off the field), plus 250 mm. Scale:
0.1 px/mm, or less so that the image's long side stays within ``MAX_IMAGE_PX`` (a large field or far
beacons give a coarser image, never a huge one).

``render_mode="human"`` shows the same image with matplotlib when a display is available;
headless (no ``DISPLAY``/``WAYLAND_DISPLAY`` on Linux, or a non-interactive backend) it warns
once and shows nothing.
"""

from __future__ import annotations

import math
import os
import sys
import warnings
from collections import deque
from typing import Any

import numpy as np

SCALE_PX_PER_MM = 0.1  # the scale of a field that fits in MAX_IMAGE_PX, px/mm
MAX_IMAGE_PX = 1280  # the rendered image's longest side at most, px (a coarser scale beyond)
MIN_DISK_PX = 3.0  # beacons and the robot are drawn at least this radius, px
PAD_MM = 250.0  # margin drawn around the field, the beacons and the start, mm
TRAIL_LEN = 3000
BEACON_COLORS = [(230, 40, 40), (40, 90, 230), (240, 200, 20), (200, 60, 220), (30, 200, 220), (250, 130, 20)]
FIELD = (40, 130, 60)
OUTSIDE = (25, 70, 35)


class Renderer:
    """Draws one env's state into an RGB uint8 array (H, W, 3)."""

    def __init__(self, env: Any) -> None:
        self.env = env
        cfg = env.config
        points = [list(b) for b in cfg["beacons"]]
        if isinstance(cfg["start_pose"], list):
            points.append(cfg["start_pose"][:2])
        bx = [p[0] for p in points]
        by = [p[1] for p in points]
        hl, hw = cfg["field"][0] / 2, cfg["field"][1] / 2
        self.x0, self.x1 = min(-hl, *bx) - PAD_MM, max(hl, *bx) + PAD_MM
        self.y0, self.y1 = min(-hw, *by) - PAD_MM, max(hw, *by) + PAD_MM
        self.s = min(SCALE_PX_PER_MM, MAX_IMAGE_PX / max(self.x1 - self.x0, self.y1 - self.y0))
        self.w = min(int(math.ceil((self.x1 - self.x0) * self.s)), MAX_IMAGE_PX)
        self.h = min(int(math.ceil((self.y1 - self.y0) * self.s)), MAX_IMAGE_PX)
        # world coordinates (mm) of every pixel centre
        self.wx = (self.x0 + (np.arange(self.w) + 0.5) / self.s).astype(np.float32)
        self.wy = (self.y1 - (np.arange(self.h) + 0.5) / self.s).astype(np.float32)
        self.trail: deque[tuple[float, float]] = deque(maxlen=TRAIL_LEN)
        self.background = self._background()
        self._fig = None
        self._img = None
        self._warned = False

    # ---------------------------------------------------------------- geometry
    def to_px(self, x: float, y: float) -> tuple[float, float]:
        """World (mm) to pixel (column, row) as floats."""
        return (x - self.x0) * self.s, (self.y1 - y) * self.s

    def _disk(self, img: np.ndarray, x: float, y: float, r_mm: float, color, ring: bool = False) -> None:
        r = max(r_mm, MIN_DISK_PX / self.s)  # still visible in a coarse image
        c0 = max(int((x - r - self.x0) * self.s), 0)
        c1 = min(int((x + r - self.x0) * self.s) + 2, self.w)
        r0 = max(int((self.y1 - y - r) * self.s), 0)
        r1 = min(int((self.y1 - y + r) * self.s) + 2, self.h)
        if c0 >= c1 or r0 >= r1:
            return
        dx = self.wx[c0:c1][None, :] - x
        dy = self.wy[r0:r1][:, None] - y
        d2 = dx * dx + dy * dy
        mask = (d2 <= r * r) & (d2 >= max(r - 3 / self.s, 0.0) ** 2) if ring else d2 <= r * r
        img[r0:r1, c0:c1][mask] = color

    def _line(self, img: np.ndarray, x0: float, y0: float, x1: float, y1: float, color, width_px: int = 1) -> None:
        (c0, r0), (c1, r1) = self.to_px(x0, y0), self.to_px(x1, y1)
        n = int(max(abs(c1 - c0), abs(r1 - r0)) * 2) + 2
        t = np.linspace(0.0, 1.0, n)
        cols = np.round(c0 + (c1 - c0) * t).astype(int)
        rows = np.round(r0 + (r1 - r0) * t).astype(int)
        for oc in range(-(width_px // 2), width_px - width_px // 2):
            for orow in range(-(width_px // 2), width_px - width_px // 2):
                self._points(img, cols + oc, rows + orow, color)

    def _points(self, img: np.ndarray, cols: np.ndarray, rows: np.ndarray, color) -> None:
        ok = (cols >= 0) & (cols < self.w) & (rows >= 0) & (rows < self.h)
        img[rows[ok], cols[ok]] = color

    # ---------------------------------------------------------------- layers
    def _background(self) -> np.ndarray:
        cfg = self.env.config
        img = np.empty((self.h, self.w, 3), dtype=np.uint8)
        img[:] = OUTSIDE
        hl, hw = cfg["field"][0] / 2, cfg["field"][1] / 2
        inside_x = np.abs(self.wx) <= hl
        inside_y = np.abs(self.wy) <= hw
        img[np.ix_(inside_y, inside_x)] = FIELD
        white = (235, 235, 235)
        for (ax, ay), (bx, by) in [((-hl, -hw), (hl, -hw)), ((hl, -hw), (hl, hw)), ((hl, hw), (-hl, hw)), ((-hl, hw), (-hl, -hw))]:
            self._line(img, ax, ay, bx, by, white, 2)
        self._line(img, 0.0, -hw, 0.0, hw, white, 1)
        for i, (bx, by) in enumerate(cfg["beacons"]):
            self._disk(img, bx, by, 110.0, BEACON_COLORS[i % len(BEACON_COLORS)])
        return img

    def _camera_zone(self, img: np.ndarray, x: float, y: float, direction: float) -> None:
        cfg = self.env.config
        rmin, rmax = cfg["range_mm"]
        cos_half = math.cos(0.5 * cfg["fov"])
        dx = self.wx[None, :] - x
        dy = self.wy[:, None] - y
        d2 = dx * dx + dy * dy
        dot = dx * math.cos(direction) + dy * math.sin(direction)
        mask = (d2 >= rmin * rmin) & (d2 <= rmax * rmax) & (dot >= np.sqrt(d2) * cos_half)
        img[mask] = (0.6 * img[mask] + 0.4 * 255).astype(np.uint8)

    def draw(self) -> np.ndarray:
        """The current frame as an RGB uint8 array (H, W, 3)."""
        env = self.env
        img = self.background.copy()
        x, y, th = env.pose
        self._camera_zone(img, x, y, th + env.head_pan)
        for sighting in env.last_sightings:
            if not sighting.spurious:
                bx, by = env.config["beacons"][sighting.beacon]
                self._disk(img, bx, by, 170.0, (255, 255, 255), ring=True)
        if self.trail:
            pts = np.array(self.trail)
            cols = np.round((pts[:, 0] - self.x0) * self.s).astype(int)
            rows = np.round((self.y1 - pts[:, 1]) * self.s).astype(int)
            self._points(img, cols, rows, (250, 250, 160))
        self._disk(img, x, y, 150.0, (20, 20, 20))
        self._line(img, x, y, x + 300 * math.cos(th), y + 300 * math.sin(th), (20, 20, 20), 3)
        hd = th + env.head_pan
        self._line(img, x, y, x + 250 * math.cos(hd), y + 250 * math.sin(hd), (255, 220, 0), 2)
        return img

    # ---------------------------------------------------------------- state
    def reset(self) -> None:
        self.trail.clear()

    def record(self, pose) -> None:
        self.trail.append((float(pose[0]), float(pose[1])))

    # ---------------------------------------------------------------- human mode
    def show(self) -> None:
        """Show the frame in a matplotlib window (warns once and does nothing when headless)."""
        import matplotlib

        headless = sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
        backend = matplotlib.get_backend().lower()
        if headless or backend in ("agg", "pdf", "ps", "svg", "cairo", "template"):
            if not self._warned:
                warnings.warn(
                    "render_mode='human' needs a display and an interactive matplotlib backend; "
                    "nothing is shown. Use render_mode='rgb_array' headless.",
                    stacklevel=3,
                )
                self._warned = True
            return
        import matplotlib.pyplot as plt

        frame = self.draw()
        if self._fig is None:
            plt.ion()
            self._fig, ax = plt.subplots()
            ax.set_axis_off()
            self._img = ax.imshow(frame)
        else:
            self._img.set_data(frame)
        plt.pause(1.0 / self.env.metadata["render_fps"])

    def close(self) -> None:
        if self._fig is not None:
            import matplotlib.pyplot as plt

            plt.close(self._fig)
            self._fig = None
