"""A software picture of one game state, numpy only: for env.render(), videos and quick looks.

No window and no drawing library, so it runs headless on any training machine. The image spans
the arena exactly (world x right, y up; row = (arena_y - y) * scale). Lines are 1 px wide per
unit of scale and are drawn by sampling points along each segment, all segments of one colour
in one numpy call.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from services.sim.engine import Game

BACKGROUND = (12, 14, 28)
BORDER = (110, 110, 140)
REGION = (50, 110, 60)
SHIELD = (80, 140, 255)
OPENING = (255, 60, 200)  # the shield's rear arc while the fortress is vulnerable
FORTRESS = (200, 200, 215)
FACING = (255, 215, 0)
SHIP_COLOURS = {"bait": (255, 150, 40), "shooter": (60, 220, 255)}
NOSE = (255, 255, 255)
MISSILE = (255, 255, 140)
SHELL = (255, 70, 70)
DOT_RADIUS = 2.0  # px at scale 1, for missiles and shells


def render(game: Game, scale: float = 1.0) -> np.ndarray:
    """The game as an (H, W, 3) uint8 RGB image, `scale` pixels per world pixel."""
    c = game.config
    canvas = _Canvas(_arena(c.arena_x, c.arena_y, scale).copy(), c.arena_x, c.arena_y, scale)
    canvas.segments(_hexagon(game.facing, c.region_radius), REGION, closed=True)
    shield = _hexagon(game.facing, c.shield_radius)  # vertex 3 is the rear
    if game.vulnerable > 0:
        canvas.segments(shield[4:] + shield[:3], SHIELD)
        canvas.segments(shield[2:5], OPENING)
    else:
        canvas.segments(shield, SHIELD, closed=True)
    if game.fortress_alive:
        canvas.disc(0.0, 0.0, c.fortress_radius, FORTRESS)
        canvas.segments([(0.0, 0.0), _polar(game.facing, c.fortress_radius + 10.0)], FACING)
    for x, y, *_ in game.missiles:
        canvas.disc(x, y, DOT_RADIUS, MISSILE)
    for x, y, *_ in game.shells:
        canvas.disc(x, y, DOT_RADIUS, SHELL)
    for ship in game.ships:
        if ship.alive:
            canvas.disc(ship.x, ship.y, c.ship_radius, SHIP_COLOURS[ship.role])
            nose = _polar(ship.heading, c.ship_radius), _polar(ship.heading, c.ship_radius + 8.0)
            canvas.segments([(ship.x + dx, ship.y + dy) for dx, dy in nose], NOSE)
    return canvas.image


@functools.lru_cache(maxsize=8)
def _arena(arena_x: float, arena_y: float, scale: float) -> np.ndarray:
    """Background and border, made once per size: filling a fresh image costs more than the rest."""
    width, height = round(2 * arena_x * scale) + 1, round(2 * arena_y * scale) + 1
    canvas = _Canvas(np.empty((height, width, 3), np.uint8), arena_x, arena_y, scale)
    canvas.image[:] = BACKGROUND
    corners = [(-arena_x, -arena_y), (arena_x, -arena_y), (arena_x, arena_y), (-arena_x, arena_y)]
    canvas.segments(corners, BORDER, closed=True)
    canvas.image.flags.writeable = False
    return canvas.image


def _polar(degrees: float, radius: float) -> tuple[float, float]:
    rad = math.radians(degrees)
    return radius * math.cos(rad), radius * math.sin(rad)


def _hexagon(facing: float, radius: float) -> list[tuple[float, float]]:
    """Vertices of the fortress hexagon of this circumradius, vertex 0 on the facing, ccw."""
    return [_polar(facing + 60.0 * k, radius) for k in range(6)]


class _Canvas:
    """An image plus the world-to-pixel mapping."""

    def __init__(self, image: np.ndarray, arena_x: float, arena_y: float, scale: float) -> None:
        self.image, self.arena_x, self.arena_y, self.scale = image, arena_x, arena_y, scale
        self.width = max(1, round(scale))

    def _pixels(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (self.arena_y - y) * self.scale, (x + self.arena_x) * self.scale

    def segments(
        self, points: list[tuple[float, float]], colour: tuple[int, int, int], closed: bool = False
    ) -> None:
        """The polyline through world `points` (back to the first when closed)."""
        p = np.asarray(points, dtype=np.float64)
        ends = np.roll(p, -1, axis=0) if closed else p[1:]
        starts = p if closed else p[:-1]
        rows0, cols0 = self._pixels(starts[:, 0], starts[:, 1])
        rows1, cols1 = self._pixels(ends[:, 0], ends[:, 1])
        n = int(np.ceil(np.max(np.hypot(rows1 - rows0, cols1 - cols0)) * 2)) + 2
        t = np.linspace(0.0, 1.0, n)[None, :]
        rows = rows0[:, None] + t * (rows1 - rows0)[:, None]
        cols = cols0[:, None] + t * (cols1 - cols0)[:, None]
        rows, cols = np.rint(rows).astype(np.intp).ravel(), np.rint(cols).astype(np.intp).ravel()
        height, width = self.image.shape[:2]
        lo = -(self.width // 2)
        for dr in range(lo, lo + self.width):
            for dc in range(lo, lo + self.width):
                r, q = rows + dr, cols + dc
                inside = (r >= 0) & (r < height) & (q >= 0) & (q < width)
                self.image[r[inside], q[inside]] = colour

    def disc(self, x: float, y: float, radius: float, colour: tuple[int, int, int]) -> None:
        """A filled disc of world `radius` (at least one pixel) centred on world (x, y)."""
        row, col = self._pixels(x, y)
        r = max(radius * self.scale, 0.75)  # reaches the nearest pixel
        height, width = self.image.shape[:2]
        top, bottom = max(math.floor(row - r), 0), min(math.ceil(row + r) + 1, height)
        left, right = max(math.floor(col - r), 0), min(math.ceil(col + r) + 1, width)
        if top >= bottom or left >= right:
            return
        dr = np.arange(top, bottom)[:, None] - row
        dc = np.arange(left, right)[None, :] - col
        self.image[top:bottom, left:right][dr * dr + dc * dc <= r * r] = colour
