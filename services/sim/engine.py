"""The live engine: one game of TSF, a pure, deterministic function of config, seed and two
action streams. A live match's sim runs it (it needs no compiler, so a sim starts in half a
second), and it is the reference the batched engine (batch.py, the bulk engine) is tested
against, frame by frame (batch_test.py; docs/architecture.md, "Two engines").

pymunk holds the bodies: the two ships (kinematic circles it integrates each frame) and the
fortress, whose shield and activation hexagons are pymunk polygons on the fortress body, so they
rotate with its facing and answer the point queries. Missiles and shells are constant-velocity
points created and dropped several times a second; they live in plain lists, which keeps the
engine above 20,000 frames/s (bench/engine.py). No bus code here.
"""

from __future__ import annotations

import hashlib
import math
import numbers
import random
import struct
from dataclasses import dataclass, field
from typing import NamedTuple

import pymunk

from services.sim.jit import jitable
from shared.game import DEATH_CAUSES, N_ACTIONS, ROLES, GameConfig, split_action


class Event(NamedTuple):
    """Something that happened in a frame. `role` is the ship concerned, or '' for the fortress."""

    frame: int
    kind: str  # one of shared.game.EVENT_KINDS
    role: str = ""
    detail: str = ""  # death cause, or the locked role


@dataclass
class Counters:
    """Per-player counters of one game."""

    kills: int = 0
    deaths: dict[str, int] = field(default_factory=lambda: dict.fromkeys(DEATH_CAUSES, 0))
    missiles_fired: int = 0
    shield_hits: int = 0
    frames_in_region: int = 0
    frames_locked: int = 0

    def to_dict(self) -> dict:
        return {
            "kills": self.kills,
            "deaths": dict(self.deaths),
            "missiles_fired": self.missiles_fired,
            "shield_hits": self.shield_hits,
            "frames_in_region": self.frames_in_region,
            "frames_locked": self.frames_locked,
        }


class Ship:
    """One player's ship: a kinematic pymunk body plus what the rules track about it."""

    __slots__ = ("role", "body", "vx", "vy", "heading", "alive", "cooldown", "in_region", "counters")

    def __init__(self, role: str, space: pymunk.Space, radius: float) -> None:
        self.role = role
        self.body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        space.add(self.body, pymunk.Circle(self.body, radius))
        self.vx = self.vy = 0.0
        self.heading = 0.0  # degrees, ccw from +x
        self.alive = True
        self.cooldown = 0  # frames until this ship may launch again
        self.in_region = False
        self.counters = Counters()

    @property
    def x(self) -> float:
        return self.body.position.x

    @property
    def y(self) -> float:
        return self.body.position.y


def hexagon(radius: float) -> list[tuple[float, float]]:
    """Regular hexagon with a vertex on the body's +x axis: the facing and the rear are vertices."""
    return [
        (radius * math.cos(math.radians(60 * k)), radius * math.sin(math.radians(60 * k))) for k in range(6)
    ]


# The formulas below are shared with the batched engine (batch.py), which compiles the same source.


@jitable
def angle_diff(a: float, b: float) -> float:
    """Signed smallest difference a - b in degrees, in [-180, 180)."""
    return (a - b + 180.0) % 360.0 - 180.0


@jitable
def steer(
    heading: float,
    vx: float,
    vy: float,
    turn: int,
    thrust: int,
    c_turn: float,
    c_thrust: float,
    drag: float,
    cap: float,
) -> tuple[float, float, float, float, float]:
    """One frame of a ship's turn, thrust, drag and speed cap: (heading, vx, vy, cos, sin of heading)."""
    if turn == 1:
        heading = (heading + c_turn) % 360.0
    elif turn == 2:
        heading = (heading - c_turn) % 360.0
    rad = math.radians(heading)
    cos_h, sin_h = math.cos(rad), math.sin(rad)
    if thrust:
        vx += c_thrust * cos_h
        vy += c_thrust * sin_h
    vx *= drag
    vy *= drag
    speed2 = vx * vx + vy * vy
    if speed2 > cap * cap:
        scale = cap / math.sqrt(speed2)
        vx *= scale
        vy *= scale
    return heading, vx, vy, cos_h, sin_h


@jitable
def in_rear_arc(facing: float, x: float, y: float, rear_arc: float) -> bool:
    """Whether the bearing of (x, y) lies in the open arc centred opposite the facing."""
    rear = facing + 180.0
    bearing = math.degrees(math.atan2(y, x))
    return abs(angle_diff(bearing, rear)) <= rear_arc / 2.0


@jitable
def fortress_turn(facing: float, bearing: float, max_turn: float) -> tuple[float, float]:
    """(turn, aim error before it): the fortress turns toward the bearing by at most max_turn."""
    error = angle_diff(bearing, facing)
    low = error if error < max_turn else max_turn  # min(max_turn, error)
    return (low if low > -max_turn else -max_turn), error  # max(-max_turn, low)


class Game:
    """One game of TSF. `step(bait_action, shooter_action)` advances one frame."""

    def __init__(self, config: GameConfig | None = None, seed: int = 0) -> None:
        self.config = c = config or GameConfig()
        self.seed = seed
        self.rng = random.Random(seed)
        self.space = pymunk.Space()
        self.fortress = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        self.shield = pymunk.Poly(self.fortress, hexagon(c.shield_radius))
        self.region = pymunk.Poly(self.fortress, hexagon(c.region_radius))
        self.space.add(self.fortress, self.shield, self.region)
        self.ships = [Ship(role, self.space, c.ship_radius) for role in ROLES]
        self.bait, self.shooter = self.ships
        # Distances below which a point is surely inside a hexagon (the apothem) or beyond which
        # it is surely outside (the circumradius): pymunk is asked only in the band between.
        self._cos30 = math.cos(math.radians(30))
        self.missiles: list[list] = []  # [x, y, vx, vy, owner index]
        self.shells: list[list[float]] = []  # [x, y, vx, vy]
        self.frame = 0
        self.kills = 0
        self.points = 0
        self.events: list[Event] = []  # events of the last frame
        self.spawns = 0
        self._reset_fortress(full=True)
        for ship in self.ships:
            self._spawn(ship)

    # ------------------------------------------------------------------ set-up and resets

    def _spawn(self, ship: Ship) -> None:
        c = self.config
        self.spawns += 1
        x, y, heading = c.bait_spawn if ship.role == "bait" else c.shooter_spawn
        angle = self.rng.uniform(0.0, 2.0 * math.pi)
        dist = self.rng.uniform(0.0, c.spawn_jitter_px)
        ship.body.position = (x + dist * math.cos(angle), y + dist * math.sin(angle))
        ship.heading = (heading + self.rng.uniform(-c.spawn_jitter_deg, c.spawn_jitter_deg)) % 360.0
        ship.vx = ship.vy = 0.0
        ship.body.velocity = (0.0, 0.0)
        ship.alive = True
        ship.cooldown = 0
        ship.in_region = self._in_hexagon(self.region, c.region_radius, ship.x, ship.y)

    def _reset_fortress(self, full: bool) -> None:
        """Timers cleared and shield closed; a full reset (both ships dead) also resets facing."""
        if full:
            self.facing = 0.0
            self._set_facing(0.0)
        self.fortress_alive = True
        self.lock = -1  # index into self.ships, or -1
        self.since_shell = 0  # frames since the last shell or since the lock was taken
        self.vulnerable = 0  # frames of vulnerability left
        self.down_frames = 0  # frames since the fortress was destroyed
        self.reset_in = -1  # frames until the both-dead reset, or -1

    def _set_facing(self, facing: float) -> None:
        self.facing = facing % 360.0
        self.fortress.angle = math.radians(self.facing)
        self.shield.cache_bb()  # re-transform the hexagons now, not at the next space step
        self.region.cache_bb()

    def _in_hexagon(self, poly: pymunk.Poly, radius: float, x: float, y: float) -> bool:
        d2 = x * x + y * y
        if d2 > radius * radius:
            return False
        apothem = radius * self._cos30
        if d2 <= apothem * apothem:
            return True
        return poly.point_query((x, y)).distance <= 0.0

    # ------------------------------------------------------------------ the frame

    def step(self, bait_action: int, shooter_action: int) -> list[Event]:
        """Advance one frame; returns its events. Invalid actions raise before anything changes."""
        _check_action("bait", bait_action)
        _check_action("shooter", shooter_action)
        if self.done:
            raise ValueError(f"game is over after {self.config.frames} frames")
        c = self.config
        self.frame += 1
        self.events = events = []
        for ship, action in ((self.bait, bait_action), (self.shooter, shooter_action)):
            if ship.alive:
                self._steer(ship, int(action))
        self.space.step(1.0)
        self._move_projectiles()
        for ship in self.ships:
            if ship.alive:
                x, y = ship.body.position
                if abs(x) > c.arena_x or abs(y) > c.arena_y:
                    self._kill_ship(ship, "border")
                elif self.fortress_alive and self._in_hexagon(self.shield, c.shield_radius, x, y):
                    self._kill_ship(ship, "shield")
        killed_by = self._resolve_missiles() if self.fortress_alive else -1
        self._resolve_shells()
        for ship in self.ships:
            ship.in_region = ship.alive and self._in_hexagon(
                self.region, c.region_radius, *ship.body.position
            )
        if killed_by >= 0:
            self._fortress_destroyed(killed_by)
        elif self.fortress_alive:
            self._fortress_act()
        else:
            self._fortress_down()
        self._both_dead_reset()
        for ship in self.ships:
            if ship.in_region:
                ship.counters.frames_in_region += 1
        if self.lock >= 0:
            self.ships[self.lock].counters.frames_locked += 1
        return events

    @property
    def done(self) -> bool:
        return self.frame >= self.config.frames

    def _steer(self, ship: Ship, action: int) -> None:
        c = self.config
        turn, thrust, fire = split_action(action)
        ship.heading, vx, vy, cos_h, sin_h = steer(
            ship.heading,
            ship.vx,
            ship.vy,
            turn,
            thrust,
            c.ship_turn,
            c.ship_thrust,
            c.ship_drag,
            c.ship_max_speed,
        )
        ship.vx, ship.vy = vx, vy
        ship.body.velocity = (vx, vy)
        if ship.cooldown > 0:
            ship.cooldown -= 1
        if fire and ship.cooldown == 0:
            index = 0 if ship is self.bait else 1
            if sum(1 for m in self.missiles if m[4] == index) < c.missiles_in_flight:
                x, y = ship.body.position
                self.missiles.append(
                    [
                        x + c.ship_radius * cos_h,
                        y + c.ship_radius * sin_h,
                        c.missile_speed * cos_h,
                        c.missile_speed * sin_h,
                        index,
                    ]
                )
                ship.cooldown = c.missile_cooldown
                ship.counters.missiles_fired += 1
                self.events.append(Event(self.frame, "missile", ship.role))

    def _move_projectiles(self) -> None:
        ax, ay = self.config.arena_x, self.config.arena_y
        for group in (self.missiles, self.shells):
            kept = []
            for p in group:
                p[0] += p[2]
                p[1] += p[3]
                if -ax <= p[0] <= ax and -ay <= p[1] <= ay:
                    kept.append(p)
            group[:] = kept

    def _resolve_missiles(self) -> int:
        """Missiles against shield and fortress; returns the killer's index, or -1."""
        c = self.config
        reach = c.shield_radius + c.missile_radius
        kept = []
        killer = -1
        for m in self.missiles:
            x, y = m[0], m[1]
            d2 = x * x + y * y
            if d2 > reach * reach:
                kept.append(m)
                continue
            through_opening = self.vulnerable > 0 and in_rear_arc(self.facing, x, y, self.config.rear_arc)
            if d2 <= c.kill_distance * c.kill_distance and through_opening:
                if killer < 0:
                    killer = m[4]
                continue
            if through_opening or self.shield.point_query((x, y)).distance > c.missile_radius:
                kept.append(m)  # in the opening, or not yet touching the shield
                continue
            owner = self.ships[m[4]]
            owner.counters.shield_hits += 1
            self.points += c.points_shield_hit
            self.events.append(Event(self.frame, "shield_hit", owner.role))
        self.missiles = kept
        return killer

    def _resolve_shells(self) -> None:
        c = self.config
        hit2 = c.shell_hit_distance * c.shell_hit_distance
        kept = []
        for s in self.shells:
            for ship in self.ships:
                if ship.alive:
                    x, y = ship.body.position
                    if (s[0] - x) ** 2 + (s[1] - y) ** 2 <= hit2:
                        self._kill_ship(ship, "shell")
                        break
            else:
                kept.append(s)
        self.shells = kept

    def _kill_ship(self, ship: Ship, cause: str) -> None:
        ship.alive = False
        ship.vx = ship.vy = 0.0
        ship.body.velocity = (0.0, 0.0)
        ship.in_region = False
        ship.counters.deaths[cause] += 1
        self.points += self.config.points_death
        self.events.append(Event(self.frame, "death", ship.role, cause))

    # ------------------------------------------------------------------ the fortress

    def _fortress_act(self) -> None:
        """Lock, turn toward the target, fire when aimed and the interval has passed."""
        c = self.config
        if self.lock >= 0 and not self.ships[self.lock].in_region:
            self.lock = -1
        if self.lock < 0:
            # The other ship first if the locked one just left; at game start, the bait on ties.
            for index, ship in enumerate(self.ships):
                if ship.in_region:
                    self.lock = index
                    self.since_shell = 0
                    self.events.append(Event(self.frame, "lock", ship.role))
                    break
        else:
            self.since_shell += 1
        if self.vulnerable > 0:
            self.vulnerable -= 1
        if self.lock < 0:
            return
        target = self.ships[self.lock]
        tx, ty = target.body.position
        bearing = math.degrees(math.atan2(ty, tx))
        turn, error = fortress_turn(self.facing, bearing, c.fortress_turn)
        if turn:
            self._set_facing(self.facing + turn)
            error -= turn
        if abs(error) <= c.fortress_aim_tolerance and self.since_shell >= c.fortress_fire_interval:
            rad = math.radians(bearing)
            self.shells.append([0.0, 0.0, c.shell_speed * math.cos(rad), c.shell_speed * math.sin(rad)])
            self.since_shell = 0
            self.vulnerable = c.vulnerable_frames
            self.events.append(Event(self.frame, "shell", target.role))

    def _fortress_destroyed(self, killer: int) -> None:
        c = self.config
        self.kills += 1
        self.points += c.points_kill
        self.ships[killer].counters.kills += 1
        self.events.append(Event(self.frame, "kill", self.ships[killer].role))
        self.fortress_alive = False
        self.lock = -1
        self.vulnerable = 0
        self.down_frames = 0
        self.reset_in = -1
        self.missiles.clear()
        self.shells.clear()
        self._respawn_dead()

    def _respawn_dead(self) -> None:
        for ship in self.ships:
            if not ship.alive:
                self._spawn(ship)
                self.events.append(Event(self.frame, "respawn", ship.role))

    def _fortress_down(self) -> None:
        """A ship that died while the fortress was down comes back with it: a new round starts."""
        self.down_frames += 1
        if self.down_frames >= self.config.respawn_delay and not any(ship.in_region for ship in self.ships):
            self._reset_fortress(full=False)
            self._respawn_dead()
            self.events.append(Event(self.frame, "fortress_respawn"))

    def _both_dead_reset(self) -> None:
        if self.bait.alive or self.shooter.alive:
            return
        if self.reset_in < 0:
            self.reset_in = self.config.respawn_delay
            return
        self.reset_in -= 1
        if self.reset_in == 0:
            self._reset_fortress(full=True)
            self.missiles.clear()
            self.shells.clear()
            for ship in self.ships:
                self._spawn(ship)
            self.events.append(Event(self.frame, "reset"))

    # ------------------------------------------------------------------ reading the state

    def state_values(self) -> list[float]:
        """The full state as numbers, in a fixed order: what the state hash covers."""
        values: list[float] = [
            self.frame,
            self.facing,
            self.fortress_alive,
            self.lock,
            self.since_shell,
            self.vulnerable,
            self.down_frames,
            self.reset_in,
            self.kills,
            self.points,
            self.spawns,  # how far the seeded generator has been drawn
        ]
        for ship in self.ships:
            x, y = ship.body.position
            values += [x, y, ship.vx, ship.vy, ship.heading, ship.alive, ship.cooldown]
        for m in self.missiles:
            values += m
        values.append(-1.0)
        for s in self.shells:
            values += s
        return values

    def state_hash(self) -> str:
        return hash_values(self.state_values())

    def counters(self) -> dict[str, dict]:
        return {ship.role: ship.counters.to_dict() for ship in self.ships}

    def kills_per_minute(self) -> float:
        minutes = self.frame / (self.config.fps * 60.0)
        return self.kills / minutes if minutes else 0.0


def hash_values(values: list[float]) -> str:
    """16 hex digits over the exact bits of a state's values; equal states give equal hashes."""
    packed = struct.pack(f"<{len(values)}d", *values)
    return hashlib.blake2b(packed, digest_size=8).hexdigest()


def _check_action(role: str, action: object) -> None:
    """Reject anything but an integer 0..11 with a message that names the player and the value."""
    if not isinstance(action, numbers.Integral) or isinstance(action, bool) or not 0 <= action < N_ACTIONS:
        raise ValueError(f"invalid action for {role}: {action!r} (expected an integer 0..{N_ACTIONS - 1})")
