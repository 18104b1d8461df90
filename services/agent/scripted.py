"""Scripted reference policies: the competent rule-based pair that calibrates the game.

- `circle` (bait): circles inside the activation region, sidestepping shells about to hit it, and
  leaves the region while the fortress is down so that it can respawn.
- `orbit` (bait): holds a radius about the fortress with feedback on the radial error, kept inside
  the activation hexagon as it turns (the region's edge at the ship's bearing, less a margin), and
  can steer its bearing toward the point opposite the shooter (plus a lead angle); while the
  fortress is down it orbits just outside the hexagon rather than leaving.
- `mirror` (shooter): holds the point opposite the bait just outside the region, moving along the
  circle rather than through the region, faces the fortress and fires into the open rear when the
  missile will arrive inside the vulnerability window.
- `idle`: never acts (a lone-ship baseline for the other seat).
All read the world-view observation (services/sim/observation.py).

The rules are plain functions of the observation and numbers (`jitable`): the scalar policies run
them as Python, and `choose_batch` runs the very same source compiled over a batch of rows.
"""

from __future__ import annotations

import math

import numpy as np

from services.agent.policy import RulePolicy, UniformPolicy, seek, ship, turn_toward
from services.sim import observation as ob
from services.sim.jit import compiled, jitable
from shared.game import GameConfig

_DEFAULTS = GameConfig()


@jitable
def orbit_velocity(
    x: float, y: float, radius: float, tangential: float, gain: float = 0.05, max_radial: float = 1.0
) -> tuple[float, float]:
    """Velocity that moves along the circle of `radius` about the fortress (ccw for tangential > 0)
    and pulls back onto it gently (a slow radial pull keeps thrust-only ships from overshooting)."""
    r = math.hypot(x, y)
    r = r if r != 0.0 else 1.0
    ux, uy = x / r, y / r
    radial = max(-max_radial, min(max_radial, gain * (radius - r)))
    return ux * radial - uy * tangential, uy * radial + ux * tangential


class Idle(RulePolicy):
    """Does nothing, in either seat, even in a stalled round: the lone-ship baseline."""

    key = "idle"
    ends_stalled_rounds = False

    def __init__(self, role: str = "bait", epsilon: float = RulePolicy.EPSILON) -> None:
        super().__init__(epsilon)
        self.role = role

    def choose(self, obs: np.ndarray) -> tuple[int, int, int]:
        return 0, 0, 0

    def choose_batch(self, observations: np.ndarray) -> np.ndarray:
        return np.zeros((len(observations), 3), np.int64)


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
        return circle_choice(obs, self.radius, self.speed, self.outside)

    def choose_batch(self, observations: np.ndarray) -> np.ndarray:
        out = np.empty((len(observations), 3), np.int64)
        _circle_rows(observations, self.radius, self.speed, self.outside, out)
        return out


@jitable
def circle_choice(obs: np.ndarray, radius: float, speed: float, outside: float) -> tuple[int, int, int]:
    """CircleBait's rule: orbit at `radius` while the fortress is up, else leave past `outside`."""
    x, y, _, _ = ship(obs, ob.SELF)
    if obs[ob.FORTRESS + ob.F_ALIVE] > 0.5:
        dvx, dvy = orbit_velocity(x, y, radius, speed)
    else:  # leave the region so the fortress can respawn
        dvx, dvy = orbit_velocity(x, y, outside, 0.0, 0.1)
    ex, ey = evade(obs, x, y)
    needed, turn, thrust = seek(obs, dvx + ex, dvy + ey)
    return (turn, thrust, 0) if needed else (0, 0, 0)


@jitable
def evade(obs: np.ndarray, x: float, y: float) -> tuple[float, float]:
    """Sidestep the nearest shell if it will pass within 25 px in the next 20 frames."""
    base = ob.SHELLS
    if obs[base + 4] < 0.5:
        return 0.0, 0.0
    sx, sy, svx, svy = ship(obs, base)
    rx, ry = x - sx, y - sy
    speed2 = svx * svx + svy * svy
    speed2 = speed2 if speed2 != 0.0 else 1.0
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


@compiled
def _circle_rows(observations, radius, speed, outside, out):
    for i in range(observations.shape[0]):
        out[i] = circle_choice(observations[i], radius, speed, outside)


class OrbitBait(RulePolicy):
    """Orbits the fortress at a held radius inside the turning activation hexagon, placing itself
    by the shooter: circle's orbit, with the radius error fed back at a searched gain and the
    orbit's speed raised or lowered to bring its bearing opposite the shooter (plus `lead`). While
    the fortress is down it orbits on, just outside the hexagon (`clear` px beyond its edge), so
    that the fortress respawns without the bait's leaving and coming back from far out."""

    key = "orbit"
    role = "bait"

    def __init__(
        self,
        radius: float = 190.0,
        speed: float = 1.5,
        gain: float = 0.1,
        damping: float = 10.0,
        margin: float = 10.0,
        place: float = 0.0,
        lead: float = 0.0,
        clear: float = 10.0,
        epsilon: float = RulePolicy.EPSILON,
    ) -> None:
        super().__init__(epsilon)
        self.radius, self.speed, self.gain, self.damping = radius, speed, gain, damping
        self.margin, self.place, self.lead, self.clear = margin, place, lead, clear

    def choose(self, obs: np.ndarray) -> tuple[int, int, int]:
        return orbit_choice(obs, *self._numbers())

    def choose_batch(self, observations: np.ndarray) -> np.ndarray:
        out = np.empty((len(observations), 3), np.int64)
        _orbit_rows(observations, self._numbers(), out)
        return out

    def _numbers(self) -> tuple[float, ...]:
        """orbit_choice's numbers after the observation."""
        return (
            *(self.radius, self.speed, self.gain, self.damping),
            *(self.margin, self.place, self.lead, self.clear),
        )


ORBIT_MAX_SPEED = 6.0  # px/frame: the most the placement may ask along the orbit
ORBIT_MAX_RADIAL = 2.0  # px/frame: the most the radius feedback may ask across it
REGION_RADIUS = _DEFAULTS.region_radius  # the hexagon's circumradius, a plain number for the compiled loop


@jitable
def region_edge(x: float, y: float, facing: float) -> float:
    """The activation hexagon's edge (px from the centre) on the ship's bearing: the hexagon's
    vertices lie on the fortress's facing and every 60 degrees from it (docs/rules.md)."""
    off = (math.atan2(y, x) - facing) % (math.pi / 3)
    return REGION_RADIUS * math.cos(math.pi / 6) / math.cos(off - math.pi / 6)


@jitable
def orbit_choice(
    obs: np.ndarray,
    radius: float,
    speed: float,
    gain: float,
    damping: float,
    margin: float,
    place: float,
    lead: float,
    clear: float,
) -> tuple[int, int, int]:
    """OrbitBait's rule. Along the orbit: `speed` plus `place` px/frame per radian that the bearing
    lags the point opposite the shooter turned by `lead` degrees. Across it: `gain` times the radius
    error `damping` frames ahead (a PD controller: the lookahead damps the overshoot of a ship that
    must turn to brake). The target radius: while the fortress is up, `radius` or the hexagon's
    edge less `margin` where that is nearer; while it is down, the edge plus `clear`."""
    x, y, vx, vy = ship(obs, ob.SELF)
    facing = math.atan2(float(obs[ob.FORTRESS + ob.F_SIN]), float(obs[ob.FORTRESS + ob.F_COS]))
    edge = region_edge(x, y, facing)
    target = min(radius, edge - margin) if obs[ob.FORTRESS + ob.F_ALIVE] > 0.5 else edge + clear
    sx, sy, _, _ = ship(obs, ob.PARTNER)
    gap = (math.atan2(-sy, -sx) + math.radians(lead) - math.atan2(y, x) + math.pi) % (2 * math.pi) - math.pi
    tangential = max(-ORBIT_MAX_SPEED, min(ORBIT_MAX_SPEED, speed + place * gap))
    r = max(math.hypot(x, y), 1.0)
    ahead = r + damping * (x * vx + y * vy) / r  # the radius `damping` frames on: the D term
    radial = max(-ORBIT_MAX_RADIAL, min(ORBIT_MAX_RADIAL, gain * (target - ahead)))
    dvx, dvy = x / r * radial - y / r * tangential, y / r * radial + x / r * tangential
    ex, ey = evade(obs, x, y)
    needed, turn, thrust = seek(obs, dvx + ex, dvy + ey)
    return (turn, thrust, 0) if needed else (0, 0, 0)


@compiled
def _orbit_rows(observations, numbers, out):
    for i in range(observations.shape[0]):
        out[i] = orbit_choice(observations[i], *numbers)


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
        return mirror_choice(obs, *self._numbers())

    def choose_batch(self, observations: np.ndarray) -> np.ndarray:
        out = np.empty((len(observations), 3), np.int64)
        _mirror_rows(observations, self._numbers(), out)
        return out

    def _numbers(self) -> tuple[float, ...]:
        """mirror_choice's numbers after the observation: this shooter's and the rules'."""
        c = self.config
        placed = -1.0 if self.placed_distance is None else self.placed_distance
        return (
            *(self.radius, self.max_speed, self.aim_tolerance, self.rear_tolerance, placed),
            *(c.arena_x, c.arena_y, c.kill_distance, c.missile_speed, float(c.vulnerable_frames)),
        )


@jitable
def mirror_choice(
    obs: np.ndarray,
    radius: float,
    max_speed: float,
    aim_tolerance: float,
    rear_tolerance: float,
    placed_distance: float,
    arena_x: float,
    arena_y: float,
    kill_distance: float,
    missile_speed: float,
    vulnerable_frames: float,
) -> tuple[int, int, int]:
    """MirrorShooter's rule. A negative `placed_distance` means placed on its circle (within 20
    degrees and 25 px), else within that distance of the mirror point."""
    x, y, _, _ = ship(obs, ob.SELF)
    bx, by, bvx, bvy = ship(obs, ob.PARTNER)
    me = math.atan2(y, x)
    mirror = math.atan2(-by, -bx)
    gap = (mirror - me + math.pi) % (2 * math.pi) - math.pi
    bait_turn_rate = (bx * bvy - by * bvx) / max(bx * bx + by * by, 1.0)  # rad/frame about the fortress
    tangential = (bait_turn_rate + 0.05 * gap) * radius
    tangential = max(-max_speed, min(max_speed, tangential))
    dvx, dvy = orbit_velocity(x, y, radius, tangential, 0.08)
    _, _, vx, vy = ship(obs, ob.SELF)
    if abs(x + 12 * vx) > arena_x - 25 or abs(y + 12 * vy) > arena_y - 25:
        dvx, dvy = -0.02 * x, -0.02 * y  # heading for the border: pull back toward the centre
    needed, turn, thrust = seek(obs, dvx, dvy, 0.6)
    if placed_distance < 0.0:
        placed = abs(gap) < math.radians(20) and abs(math.hypot(x, y) - radius) < 25.0
    else:
        mx, my = radius * math.cos(mirror), radius * math.sin(mirror)
        placed = math.hypot(x - mx, y - my) < placed_distance
    if needed and not placed:
        return turn, thrust, 0
    cos_h, sin_h = float(obs[ob.SELF + ob.COS]), float(obs[ob.SELF + ob.SIN])
    turn = turn_toward(cos_h, sin_h, math.atan2(-y, -x), aim_tolerance / 2)
    shot = good_shot_at(obs, kill_distance, missile_speed, vulnerable_frames, aim_tolerance, rear_tolerance)
    return turn, 0, int(shot)


@compiled
def _mirror_rows(observations, numbers, out):
    for i in range(observations.shape[0]):
        out[i] = mirror_choice(observations[i], *numbers)


def good_shot(obs: np.ndarray, config: GameConfig, aim_tolerance: float, rear_tolerance: float) -> bool:
    """Whether a missile fired now flies into the open rear before the vulnerability window shuts:
    the ship faces the fortress within `aim_tolerance` and sits within `rear_tolerance` of the
    rear (degrees). Works in either observation view."""
    c = config
    return good_shot_at(
        obs, c.kill_distance, c.missile_speed, float(c.vulnerable_frames), aim_tolerance, rear_tolerance
    )


def good_shot_batch(
    observations: np.ndarray, config: GameConfig, aim_tolerance: float, rear_tolerance: float
) -> np.ndarray:
    """good_shot() of every row."""
    c, out = config, np.empty(len(observations), np.bool_)
    numbers = (c.kill_distance, c.missile_speed, float(c.vulnerable_frames), aim_tolerance, rear_tolerance)
    _good_shot_rows(observations, numbers, out)
    return out


@jitable
def good_shot_at(
    obs: np.ndarray,
    kill_distance: float,
    missile_speed: float,
    vulnerable_frames: float,
    aim_tolerance: float,
    rear_tolerance: float,
) -> bool:
    """good_shot() with the rules' numbers spelled out."""
    x, y, _, _ = ship(obs, ob.SELF)
    cos_h, sin_h = float(obs[ob.SELF + ob.COS]), float(obs[ob.SELF + ob.SIN])
    to_fortress = math.atan2(-y, -x)
    aim = math.degrees(
        math.acos(max(-1.0, min(1.0, cos_h * math.cos(to_fortress) + sin_h * math.sin(to_fortress))))
    )
    f = ob.FORTRESS
    rear = math.atan2(-float(obs[f + ob.F_SIN]), -float(obs[f + ob.F_COS]))
    rear_off = abs(math.degrees((math.atan2(y, x) - rear + math.pi) % (2 * math.pi) - math.pi))
    flight = (math.hypot(x, y) - kill_distance) / missile_speed
    window = float(obs[f + ob.F_VULNERABLE]) * vulnerable_frames
    return bool(
        obs[f + ob.F_ALIVE] > 0.5
        and aim <= aim_tolerance
        and rear_off <= rear_tolerance
        and window >= flight + 1.0
    )


@compiled
def _good_shot_rows(observations, numbers, out):
    for i in range(observations.shape[0]):
        out[i] = good_shot_at(observations[i], *numbers)


SCRIPTED = {"circle": CircleBait, "orbit": OrbitBait, "mirror": MirrorShooter}
# The rule a learned policy of each role imitates in a warm start (training.algorithms.warm_start_fit;
# a recipe's `demonstrator` holds its settings): the families whose choices a network's heads can take.
DEMONSTRATOR = {"bait": "circle", "shooter": "mirror"}


def scripted_keys(role: str) -> list[str]:
    """The scripted keys that can play `role`'s seat: its own rule, and idle and random (any seat)."""
    return [*(k for k, policy in SCRIPTED.items() if policy.role == role), "idle", "random"]


def scripted_policy(key: str, role: str) -> RulePolicy | UniformPolicy:
    """A scripted policy by key for a seat: circle, orbit, mirror, idle or random (any role)."""
    if key == "idle":
        return Idle(role)
    if key == "random":
        return UniformPolicy(role)
    if key in SCRIPTED:
        return SCRIPTED[key]()
    raise ValueError(
        f"unknown scripted policy {key!r}; expected one of {sorted([*SCRIPTED, 'idle', 'random'])}"
    )
