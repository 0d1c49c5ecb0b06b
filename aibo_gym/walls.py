"""What happens at the field edge (config key ``walls``).

* ``"clamp"``: the position is clamped to the field; the robot cannot leave.
* ``"pymunk"``: the robot is a pymunk dynamic circle (``robot_radius`` mm) inside four static,
  frictionless segment walls. Each frame its velocity is set so that it would reach the target
  displacement in ``dt``; the space is stepped with ``pymunk_substeps`` fixed substeps
  (deterministic) and the position read back. Pushing into a wall slides along it. As a final
  guarantee the centre is clamped to the field shrunk by the radius.
* ``"none"``: no walls; leaving the field ends the episode (``terminated=True``).
* ``"open"``: no walls, and the episode goes on off the field: the world of a motion model that
  knows no walls (a calibrated simulator of a model without ``wall_contact``).

Heading is never changed by the walls (the circle has infinite moment of inertia).
"""

from __future__ import annotations

from typing import Any

import pymunk


class Walls:
    """Base class: ``move`` returns the new (x, y) mm and whether the robot is off the field."""

    def __init__(self, cfg: dict[str, Any]) -> None:
        self.half_l = 0.5 * cfg["field"][0]
        self.half_w = 0.5 * cfg["field"][1]

    def reset(self, x: float, y: float) -> tuple[float, float]:
        """Place the robot at a start position (mm); returns the position actually used."""
        return self.clamp(x, y)

    def clamp(self, x: float, y: float) -> tuple[float, float]:
        """(x, y) clamped to the field, mm."""
        return min(max(x, -self.half_l), self.half_l), min(max(y, -self.half_w), self.half_w)

    def outside(self, x: float, y: float) -> bool:
        """True when (x, y) mm is off the field."""
        return abs(x) > self.half_l or abs(y) > self.half_w

    def move(self, x: float, y: float, nx: float, ny: float, dt: float) -> tuple[float, float, bool]:
        """From (x, y) toward the target (nx, ny) in one frame of ``dt`` s: (x', y', left_field)."""
        raise NotImplementedError


class ClampWalls(Walls):
    def move(self, x: float, y: float, nx: float, ny: float, dt: float) -> tuple[float, float, bool]:
        cx, cy = self.clamp(nx, ny)
        return cx, cy, False


class NoWalls(Walls):
    def reset(self, x: float, y: float) -> tuple[float, float]:
        return x, y

    def move(self, x: float, y: float, nx: float, ny: float, dt: float) -> tuple[float, float, bool]:
        return nx, ny, self.outside(nx, ny)


class OpenWalls(NoWalls):
    def move(self, x: float, y: float, nx: float, ny: float, dt: float) -> tuple[float, float, bool]:
        return nx, ny, False


class PymunkWalls(Walls):
    WALL_THICKNESS_MM = 200.0

    def __init__(self, cfg: dict[str, Any]) -> None:
        super().__init__(cfg)
        self.radius = float(cfg["robot_radius"])
        self.substeps = int(cfg["pymunk_substeps"])
        self.space: pymunk.Space | None = None
        self.body: pymunk.Body | None = None

    def clamp(self, x: float, y: float) -> tuple[float, float]:
        lx, ly = self.half_l - self.radius, self.half_w - self.radius
        return min(max(x, -lx), lx), min(max(y, -ly), ly)

    def _build(self) -> None:
        """A fresh space (no cached contacts), so every episode is deterministic."""
        space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        t = self.WALL_THICKNESS_MM
        hl, hw = self.half_l + t, self.half_w + t  # segment centre lines, so inner faces are the field edge
        corners = [(-hl, -hw), (hl, -hw), (hl, hw), (-hl, hw)]
        for a, b in zip(corners, corners[1:] + corners[:1]):
            seg = pymunk.Segment(space.static_body, a, b, t)
            seg.friction, seg.elasticity = 0.0, 0.0
            space.add(seg)
        body = pymunk.Body(1.0, float("inf"))
        circle = pymunk.Circle(body, self.radius)
        circle.friction, circle.elasticity = 0.0, 0.0
        space.add(body, circle)
        self.space, self.body = space, body

    def reset(self, x: float, y: float) -> tuple[float, float]:
        self._build()
        x, y = self.clamp(x, y)
        self.body.position = (x, y)
        self.body.velocity = (0.0, 0.0)
        self.space.reindex_shapes_for_body(self.body)
        return x, y

    def move(self, x: float, y: float, nx: float, ny: float, dt: float) -> tuple[float, float, bool]:
        body = self.body
        body.velocity = ((nx - x) / dt, (ny - y) / dt)
        h = dt / self.substeps
        for _ in range(self.substeps):
            self.space.step(h)
        px, py = body.position
        cx, cy = self.clamp(px, py)
        if cx != px or cy != py:
            body.position = (cx, cy)
        return cx, cy, False


WALLS = {"clamp": ClampWalls, "pymunk": PymunkWalls, "none": NoWalls, "open": OpenWalls}


def make_walls(cfg: dict[str, Any]) -> Walls:
    """The wall model named by ``cfg["walls"]``."""
    return WALLS[cfg["walls"]](cfg)
