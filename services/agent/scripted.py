"""Scripted reference policies: the competent rule-based pair that calibrates the game.

- `circle` (bait): circles inside the activation region, sidestepping shells about to hit it, and
  leaves the region while the fortress is down so that it can respawn.
- `mirror` (shooter): holds the point opposite the bait just outside the region, moving along the
  circle rather than through the region, faces the fortress and fires into the open rear when the
  missile will arrive inside the vulnerability window.
- `idle`: never acts (a lone-ship baseline for the other seat).
All read the world-view observation (services/sim/observation.py).
"""

from __future__ import annotations

import math

import numpy as np

from services.agent.policy import RulePolicy, UniformPolicy, turn_toward
from services.sim import observation as ob
from shared.game import GameConfig

_DEFAULTS = GameConfig()


def _ship(obs: np.ndarray, block: int) -> tuple[float, float, float, float]:
    """Position (px) and velocity (px/frame) of the ship block starting at `block`."""
    p, v = ob.POSITION_SCALE, ob.VELOCITY_SCALE
    return (
        float(obs[block + ob.X]) * p,
        float(obs[block + ob.Y]) * p,
        float(obs[block + ob.VX]) * v,
        float(obs[block + ob.VY]) * v,
    )


def seek(obs: np.ndarray, dvx: float, dvy: float, tolerance: float = 0.3) -> tuple[int, int] | None:
    """(turn, thrust) that bring the own velocity toward (dvx, dvy); None when already there."""
    _, _, vx, vy = _ship(obs, ob.SELF)
    ex, ey = dvx - vx, dvy - vy
    if math.hypot(ex, ey) < tolerance:
        return None
    cos_h, sin_h = float(obs[ob.SELF + ob.COS]), float(obs[ob.SELF + ob.SIN])
    want = math.atan2(ey, ex)
    turn = turn_toward(cos_h, sin_h, want)
    aligned = cos_h * math.cos(want) + sin_h * math.sin(want) > math.cos(math.radians(40))
    return turn, int(aligned)


def orbit_velocity(
    x: float, y: float, radius: float, tangential: float, gain: float = 0.05, max_radial: float = 1.0
) -> tuple[float, float]:
    """Velocity that moves along the circle of `radius` about the fortress (ccw for tangential > 0)
    and pulls back onto it gently (a slow radial pull keeps thrust-only ships from overshooting)."""
    r = math.hypot(x, y) or 1.0
    ux, uy = x / r, y / r
    radial = max(-max_radial, min(max_radial, gain * (radius - r)))
    return ux * radial - uy * tangential, uy * radial + ux * tangential


class Idle(RulePolicy):
    """Does nothing, in either seat."""

    key = "idle"

    def __init__(self, role: str = "bait", epsilon: float = RulePolicy.EPSILON) -> None:
        super().__init__(epsilon)
        self.role = role

    def choose(self, obs: np.ndarray) -> tuple[int, int, int]:
        return 0, 0, 0


class CircleBait(RulePolicy):
    """Circles the fortress inside the activation region, dodging shells."""

    key = "circle"
    role = "bait"

    def __init__(
        self,
        radius: float = 110.0,
        speed: float = 2.0,
        outside: float = 235.0,
        epsilon: float = RulePolicy.EPSILON,
    ) -> None:
        super().__init__(epsilon)
        self.radius, self.speed, self.outside = radius, speed, outside

    def choose(self, obs: np.ndarray) -> tuple[int, int, int]:
        x, y, _, _ = _ship(obs, ob.SELF)
        if obs[ob.FORTRESS + ob.F_ALIVE] > 0.5:
            dvx, dvy = orbit_velocity(x, y, self.radius, self.speed)
        else:  # leave the region so the fortress can respawn
            dvx, dvy = orbit_velocity(x, y, self.outside, 0.0, gain=0.1)
        ex, ey = self._evade(obs, x, y)
        steer = seek(obs, dvx + ex, dvy + ey)
        return (*steer, 0) if steer else (0, 0, 0)

    @staticmethod
    def _evade(obs: np.ndarray, x: float, y: float) -> tuple[float, float]:
        """Sidestep the nearest shell if it will pass within 25 px in the next 20 frames."""
        base = ob.SHELLS
        if obs[base + 4] < 0.5:
            return 0.0, 0.0
        sx, sy, svx, svy = _ship(obs, base)
        rx, ry = x - sx, y - sy
        speed2 = svx * svx + svy * svy or 1.0
        t = (rx * svx + ry * svy) / speed2  # frames until closest approach
        if not 0.0 <= t <= 20.0:
            return 0.0, 0.0
        mx, my = rx - svx * t, ry - svy * t  # miss vector at closest approach
        miss = math.hypot(mx, my)
        if miss > 25.0:
            return 0.0, 0.0
        if miss < 1e-6:  # dead on: sidestep to the left of the shell's path
            mx, my, miss = -svy, svx, math.sqrt(speed2)
        return 3.0 * mx / miss, 3.0 * my / miss


class MirrorShooter(RulePolicy):
    """Holds the point opposite the bait just outside the region and fires into the opening.

    It stops moving to aim once placed: by default within 20 degrees and 25 px of its circle
    opposite the bait; with `placed_distance`, within that many px of the mirror point itself
    (the knob that makes the library's S4-S7)."""

    key = "mirror"
    role = "shooter"

    def __init__(
        self,
        radius: float = 250.0,
        max_speed: float = 7.0,
        aim_tolerance: float = 4.0,
        rear_tolerance: float = 40.0,
        placed_distance: float | None = None,
        epsilon: float = RulePolicy.EPSILON,
        config: GameConfig = _DEFAULTS,
    ) -> None:
        super().__init__(epsilon)
        self.radius, self.max_speed, self.placed_distance = radius, max_speed, placed_distance
        self.aim_tolerance, self.rear_tolerance = aim_tolerance, rear_tolerance
        self.config = config

    def choose(self, obs: np.ndarray) -> tuple[int, int, int]:
        c = self.config
        x, y, _, _ = _ship(obs, ob.SELF)
        bx, by, bvx, bvy = _ship(obs, ob.PARTNER)
        me = math.atan2(y, x)
        mirror = math.atan2(-by, -bx)
        gap = (mirror - me + math.pi) % (2 * math.pi) - math.pi
        bait_turn_rate = (bx * bvy - by * bvx) / max(bx * bx + by * by, 1.0)  # rad/frame about the fortress
        tangential = (bait_turn_rate + 0.05 * gap) * self.radius
        tangential = max(-self.max_speed, min(self.max_speed, tangential))
        dvx, dvy = orbit_velocity(x, y, self.radius, tangential, gain=0.08)
        _, _, vx, vy = _ship(obs, ob.SELF)
        if abs(x + 12 * vx) > c.arena_x - 25 or abs(y + 12 * vy) > c.arena_y - 25:
            dvx, dvy = -0.02 * x, -0.02 * y  # heading for the border: pull back toward the centre
        steer = seek(obs, dvx, dvy, tolerance=0.6)
        if self.placed_distance is None:
            placed = abs(gap) < math.radians(20) and abs(math.hypot(x, y) - self.radius) < 25.0
        else:
            mx, my = self.radius * math.cos(mirror), self.radius * math.sin(mirror)
            placed = math.hypot(x - mx, y - my) < self.placed_distance
        if steer is not None and not placed:
            return (*steer, 0)
        cos_h, sin_h = float(obs[ob.SELF + ob.COS]), float(obs[ob.SELF + ob.SIN])
        turn = turn_toward(cos_h, sin_h, math.atan2(-y, -x), deadband=self.aim_tolerance / 2)
        return turn, 0, int(good_shot(obs, c, self.aim_tolerance, self.rear_tolerance))


def good_shot(obs: np.ndarray, config: GameConfig, aim_tolerance: float, rear_tolerance: float) -> bool:
    """Whether a missile fired now flies into the open rear before the vulnerability window shuts:
    the ship faces the fortress within `aim_tolerance` and sits within `rear_tolerance` of the
    rear (degrees). Works in either observation view."""
    x, y, _, _ = _ship(obs, ob.SELF)
    cos_h, sin_h = float(obs[ob.SELF + ob.COS]), float(obs[ob.SELF + ob.SIN])
    to_fortress = math.atan2(-y, -x)
    aim = math.degrees(
        math.acos(max(-1.0, min(1.0, cos_h * math.cos(to_fortress) + sin_h * math.sin(to_fortress))))
    )
    f = ob.FORTRESS
    rear = math.atan2(-float(obs[f + ob.F_SIN]), -float(obs[f + ob.F_COS]))
    rear_off = abs(math.degrees((math.atan2(y, x) - rear + math.pi) % (2 * math.pi) - math.pi))
    flight = (math.hypot(x, y) - config.kill_distance) / config.missile_speed
    window = float(obs[f + ob.F_VULNERABLE]) * config.vulnerable_frames
    return bool(
        obs[f + ob.F_ALIVE] > 0.5
        and aim <= aim_tolerance
        and rear_off <= rear_tolerance
        and window >= flight + 1.0
    )


SCRIPTED = {"circle": CircleBait, "mirror": MirrorShooter}


def scripted_policy(key: str, role: str) -> RulePolicy | UniformPolicy:
    """A scripted policy by key for a seat: circle, mirror, idle or random (any role)."""
    if key == "idle":
        return Idle(role)
    if key == "random":
        return UniformPolicy(role)
    if key in SCRIPTED:
        return SCRIPTED[key]()
    raise ValueError(
        f"unknown scripted policy {key!r}; expected one of {sorted([*SCRIPTED, 'idle', 'random'])}"
    )
