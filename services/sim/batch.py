"""The bulk engine: N independent games of TSF advanced together, as arrays.

Training, sweeps and evaluation need millions of frames; the scalar `Game` (engine.py, pymunk) is
the live engine and the reference, and this one plays the same games in bulk (a live sim does not
run it with one lane: docs/architecture.md, "Two engines"). Each lane is one
game with its own seed, actions, resets, counters and events; the state is a struct of arrays and
one numba-compiled loop advances every lane by a frame.

It is the same game, not a look-alike: every formula is the scalar engine's, written in the same
order with the same float64 operations (numba calls the C library's trigonometry, as CPython's
`math` does), the hexagon point queries repeat pymunk's arithmetic (Chipmunk's
`cpPolyShapePointQuery` on the transformed planes), and the spawn draws come from each lane's own
`random.Random(seed)`, drawn ahead in Python. `batch_test.py` checks per-frame `state_hash()`
equality against the scalar engine, and docs/rules.md says how it stays the same game.
"""

from __future__ import annotations

import math
import random
from typing import NamedTuple

import numpy as np

from services.sim.engine import Event, fortress_turn, hash_values, hexagon, in_rear_arc, steer
from services.sim.jit import njit
from shared.game import DEATH_CAUSES, EVENT_KINDS, N_ACTIONS, ROLES, GameConfig, split_action

KILL, DEATH, SHIELD_HIT, MISSILE, SHELL, LOCK, FORTRESS_RESPAWN, RESET, RESPAWN = (
    EVENT_KINDS.index(kind)
    for kind in ("kill", "death", "shield_hit", "missile", "shell", "lock", "fortress_respawn")
    + ("reset", "respawn")
)
BORDER, SHIELD, SHELL_HIT = (DEATH_CAUSES.index(cause) for cause in ("border", "shield", "shell"))
DRAWS_PER_SPAWN = 3  # random.uniform calls in a spawn: angle, distance, heading jitter
_REFILL = 64  # spawns' worth of draws taken from a lane's generator at a time


class Rules(NamedTuple):
    """The numbers of a GameConfig that the compiled loop reads, plus the derived constants the
    scalar engine computes in Python (so that both use the very same bits)."""

    arena_x: float
    arena_y: float
    shield_radius: float
    region_radius: float
    fortress_turn: float
    fortress_aim_tolerance: float
    fortress_fire_interval: int
    vulnerable_frames: int
    rear_arc: float
    kill_distance: float
    ship_radius: float
    ship_turn: float
    ship_thrust: float
    ship_drag: float
    ship_max_speed: float
    missile_speed: float
    missile_radius: float
    missiles_in_flight: int
    missile_cooldown: int
    shell_speed: float
    shell_hit_distance: float
    respawn_delay: int
    spawn_x: np.ndarray  # per role
    spawn_y: np.ndarray
    spawn_heading: np.ndarray
    spawn_jitter_px: float
    spawn_jitter_deg: float
    points_kill: int
    points_death: int
    points_shield_hit: int
    cos30: float
    two_pi: float
    shield_planes: np.ndarray  # (6, 4): the hexagon's vertices and edge normals, body frame
    region_planes: np.ndarray
    heads: np.ndarray  # (N_ACTIONS, 3): split_action of every action, for the compiled loop

    @classmethod
    def of(cls, c: GameConfig) -> Rules:
        spawns = np.array([c.bait_spawn, c.shooter_spawn], dtype=np.float64)
        return cls(
            c.arena_x, c.arena_y, c.shield_radius, c.region_radius, c.fortress_turn,
            c.fortress_aim_tolerance, c.fortress_fire_interval, c.vulnerable_frames, c.rear_arc,
            c.kill_distance, c.ship_radius, c.ship_turn, c.ship_thrust, c.ship_drag, c.ship_max_speed,
            c.missile_speed, c.missile_radius, c.missiles_in_flight, c.missile_cooldown, c.shell_speed,
            c.shell_hit_distance, c.respawn_delay, spawns[:, 0].copy(), spawns[:, 1].copy(),
            spawns[:, 2].copy(), c.spawn_jitter_px, c.spawn_jitter_deg, c.points_kill, c.points_death,
            c.points_shield_hit, math.cos(math.radians(30)), 2.0 * math.pi,
            _planes(c.shield_radius), _planes(c.region_radius),
            np.array([split_action(a) for a in range(N_ACTIONS)], dtype=np.int64),
        )  # fmt: skip


def _planes(radius: float) -> np.ndarray:
    """pymunk's splitting planes of the hexagon (body frame): vertex b and the unit outward normal
    of the edge a->b ending at it, normalised as Chipmunk's cpvnormalize does."""
    verts = hexagon(radius)
    out = np.empty((len(verts), 4))
    for i, (bx, by) in enumerate(verts):
        ax, ay = verts[i - 1]
        nx, ny = by - ay, -(bx - ax)  # cpvrperp(b - a)
        inv = 1.0 / (math.sqrt(nx * nx + ny * ny) + 2.2250738585072014e-308)
        out[i] = bx, by, nx * inv, ny * inv
    return out


def capacities(c: GameConfig) -> tuple[int, int, int]:
    """Room per lane for missiles, shells and one frame's events, from the rules: both ships' full
    salvos; the shells fired over the longest flight out of the arena (one per fire interval);
    a frame's events (two launches, every missile hitting the shield, two deaths, one fortress
    action, two respawns and a reset)."""
    missiles = 2 * c.missiles_in_flight
    flight = math.hypot(c.arena_x, c.arena_y) / c.shell_speed
    shells = math.ceil(flight / max(c.fortress_fire_interval, 1)) + 2
    return missiles, shells, missiles + 10


class State(NamedTuple):
    """Every lane's game as arrays, lane first; a ship's arrays are (lane, seat) in ROLES order.
    The fields mirror the scalar Game's attributes and its ships' and counters' fields."""

    frame: np.ndarray
    facing: np.ndarray
    fortress_alive: np.ndarray
    lock: np.ndarray
    since_shell: np.ndarray
    vulnerable: np.ndarray
    down_frames: np.ndarray
    reset_in: np.ndarray
    kills: np.ndarray
    points: np.ndarray
    spawns: np.ndarray
    x: np.ndarray
    y: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    heading: np.ndarray
    alive: np.ndarray
    in_region: np.ndarray
    cooldown: np.ndarray
    ship_kills: np.ndarray  # Counters.kills
    missiles_fired: np.ndarray
    shield_hits: np.ndarray
    frames_in_region: np.ndarray
    frames_locked: np.ndarray
    deaths: np.ndarray  # (lane, seat, cause in DEATH_CAUSES order)
    missiles: np.ndarray  # (lane, slot, [x, y, vx, vy, owner]) in launch order, as Game.missiles
    n_missiles: np.ndarray
    shells: np.ndarray  # (lane, slot, [x, y, vx, vy])
    n_shells: np.ndarray
    events: np.ndarray  # the last frame's (lane, k, [kind index, seat or -1, death cause or -1])
    n_events: np.ndarray
    draws: np.ndarray  # spawn draws: the lane's random.Random(seed).random() stream, drawn ahead
    used: np.ndarray  # draws consumed

    @classmethod
    def zeros(cls, n: int, config: GameConfig) -> State:
        m_cap, s_cap, e_cap = capacities(config)
        lane, ship, events = (n,), (n, 2), (n, e_cap, 3)
        f64, i64, flag = np.float64, np.int64, np.bool_
        spec = {
            "frame": (lane, i64), "facing": (lane, f64), "fortress_alive": (lane, flag),
            "lock": (lane, i64), "since_shell": (lane, i64), "vulnerable": (lane, i64),
            "down_frames": (lane, i64), "reset_in": (lane, i64), "kills": (lane, i64),
            "points": (lane, i64), "spawns": (lane, i64),
            "x": (ship, f64), "y": (ship, f64), "vx": (ship, f64), "vy": (ship, f64),
            "heading": (ship, f64), "alive": (ship, flag), "in_region": (ship, flag),
            "cooldown": (ship, i64), "ship_kills": (ship, i64), "missiles_fired": (ship, i64),
            "shield_hits": (ship, i64), "frames_in_region": (ship, i64), "frames_locked": (ship, i64),
            "deaths": ((n, 2, len(DEATH_CAUSES)), i64),
            "missiles": ((n, m_cap, 5), f64), "n_missiles": (lane, i64),
            "shells": ((n, s_cap, 4), f64), "n_shells": (lane, i64),
            "events": (events, np.int8), "n_events": (lane, i64),
            "draws": ((n, DRAWS_PER_SPAWN * (_REFILL + 2)), f64), "used": (lane, i64),
        }  # fmt: skip
        return cls(**{name: np.zeros(shape, dtype) for name, (shape, dtype) in spec.items()})


class BatchGame:
    """N games of TSF under one GameConfig. `step(bait_actions, shooter_actions)` advances every
    lane one frame; `reset(lanes, seeds)` starts new games in some lanes (the others go on)."""

    def __init__(self, n: int, config: GameConfig | None = None, seeds: object = None) -> None:
        if n < 1:
            raise ValueError(f"a batch needs at least one lane, got {n}")
        self.n = n
        self.config = config or GameConfig()
        self.rules = Rules.of(self.config)
        self.state = State.zeros(n, self.config)
        self.seeds = np.zeros(n, np.int64)
        self._rngs: list[random.Random] = [random.Random(0)] * n
        self._drawn = np.zeros(n, np.int64)  # valid draws in each lane's buffer
        self.reset(np.arange(n), np.arange(n) if seeds is None else seeds)

    # ------------------------------------------------------------------ games

    def reset(self, lanes: object, seeds: object) -> None:
        """New games in `lanes`, seeded as `Game(config, seed)` would be."""
        lanes = np.asarray(lanes, dtype=np.int64).reshape(-1)
        seeds = np.broadcast_to(np.asarray(seeds), lanes.shape)
        if lanes.size and (lanes.min() < 0 or lanes.max() >= self.n):
            raise ValueError(f"lanes must be in 0..{self.n - 1}, got {lanes.tolist()}")
        for lane, seed in zip(lanes.tolist(), seeds.tolist(), strict=True):
            self.seeds[lane] = seed
            self._rngs[lane] = random.Random(seed)
            self._drawn[lane] = self.state.used[lane] = 0
            self._draw(lane)
        _reset_lanes(self.state, self.rules, lanes)

    def step(self, bait_actions: object, shooter_actions: object) -> None:
        """Advance every lane one frame. Invalid input raises before any lane changes."""
        actions = np.stack([self._check(bait_actions, 0), self._check(shooter_actions, 1)], axis=1)
        over = np.flatnonzero(self.done)
        if over.size:
            raise ValueError(f"lane {over[0]}: game is over after {self.config.frames} frames")
        for lane in np.flatnonzero(self._drawn - self.state.used < 2 * DRAWS_PER_SPAWN).tolist():
            self._draw(lane)
        _step(self.state, self.rules, actions)

    def _check(self, actions: object, seat: int) -> np.ndarray:
        role = ROLES[seat]
        a = np.asarray(actions)
        if a.shape != (self.n,):
            raise ValueError(f"{role} actions: expected shape ({self.n},), got {a.shape}")
        if a.dtype.kind not in "iu":
            raise ValueError(f"{role} actions: expected integers 0..{N_ACTIONS - 1}, got dtype {a.dtype}")
        bad = np.flatnonzero((a < 0) | (a >= N_ACTIONS))
        if bad.size:
            lane = int(bad[0])
            value, accepted = a[lane].item(), f"an integer 0..{N_ACTIONS - 1}"
            raise ValueError(f"invalid action for {role} in lane {lane}: {value!r} (expected {accepted})")
        return a.astype(np.int64, copy=False)

    def _draw(self, lane: int) -> None:
        """Move the lane's unused draws to the front and fill up from its generator."""
        draws, used = self.state.draws, self.state.used
        left = draws[lane, used[lane] : self._drawn[lane]].copy()
        rng = self._rngs[lane]
        draws[lane] = np.concatenate([left, [rng.random() for _ in range(draws.shape[1] - left.size)]])
        self._drawn[lane], used[lane] = draws.shape[1], 0

    # ------------------------------------------------------------------ reading one lane

    @property
    def done(self) -> np.ndarray:
        return self.state.frame >= self.config.frames

    def events(self, lane: int) -> list[Event]:
        """The lane's events of its last frame, as the scalar engine reports them."""
        frame, n = int(self.state.frame[lane]), self.state.n_events[lane]
        return [
            Event(
                frame,
                EVENT_KINDS[kind],
                ROLES[seat] if seat >= 0 else "",
                DEATH_CAUSES[cause] if cause >= 0 else "",
            )
            for kind, seat, cause in self.state.events[lane, :n].tolist()
        ]

    def event_counts(self, kind: str, seat: int | None = None) -> np.ndarray:
        """Each lane's number of `kind` events in its last frame (of one seat's ship, if given)."""
        events, n = self.state.events, self.state.n_events
        hits = (events[:, :, 0] == EVENT_KINDS.index(kind)) & (np.arange(events.shape[1]) < n[:, None])
        if seat is not None:
            hits &= events[:, :, 1] == seat
        return hits.sum(axis=1)

    def state_values(self, lane: int) -> list[float]:
        """The lane's full state in `Game.state_values()` order."""
        s, i = self.state, lane
        values = [
            s.frame[i], s.facing[i], s.fortress_alive[i], s.lock[i], s.since_shell[i], s.vulnerable[i],
            s.down_frames[i], s.reset_in[i], s.kills[i], s.points[i], s.spawns[i],
        ]  # fmt: skip
        for k in range(2):
            values += [s.x[i, k], s.y[i, k], s.vx[i, k], s.vy[i, k], s.heading[i, k], s.alive[i, k]]
            values.append(s.cooldown[i, k])
        values += s.missiles[i, : s.n_missiles[i]].ravel().tolist()
        values.append(-1.0)
        values += s.shells[i, : s.n_shells[i]].ravel().tolist()
        return [float(v) for v in values]

    def state_hash(self, lane: int) -> str:
        return hash_values(self.state_values(lane))

    def counters(self, lane: int) -> dict[str, dict]:
        """The lane's per-player counters, as `Game.counters()`."""
        s = self.state
        return {
            role: {
                "kills": int(s.ship_kills[lane, k]),
                "deaths": {cause: int(s.deaths[lane, k, c]) for c, cause in enumerate(DEATH_CAUSES)},
                "missiles_fired": int(s.missiles_fired[lane, k]),
                "shield_hits": int(s.shield_hits[lane, k]),
                "frames_in_region": int(s.frames_in_region[lane, k]),
                "frames_locked": int(s.frames_locked[lane, k]),
            }
            for k, role in enumerate(ROLES)
        }

    def kills_per_minute(self) -> np.ndarray:
        minutes = self.state.frame / (self.config.fps * 60.0)
        return np.divide(self.state.kills, minutes, out=np.zeros(self.n), where=minutes > 0)


# ---------------------------------------------------------------------- the compiled loop
# One frame is a sequence of phases, each over every lane, in the scalar `Game.step`'s order; the
# functions repeat the scalar engine's methods of the same names line for line. Lanes never
# interact, so phase by phase over all lanes plays every lane exactly as frame by frame would.


@njit
def _step(a, r, actions):
    _steer_ships(a, r, actions)
    _move_projectiles(r, a.missiles, a.n_missiles)
    _move_projectiles(r, a.shells, a.n_shells)
    _ship_collisions(a, r)
    killed_by = _resolve_missiles(a, r)
    _resolve_shells(a, r)
    planes, radius, cos30 = r.region_planes, r.region_radius, r.cos30
    for i in range(a.frame.shape[0]):
        for s in range(2):
            inside = _in_hexagon(planes, radius, cos30, a.facing[i], a.x[i, s], a.y[i, s])
            a.in_region[i, s] = a.alive[i, s] and inside
    _fortress(a, r, killed_by)
    _both_dead_reset(a, r)
    for i in range(a.frame.shape[0]):
        for s in range(2):
            if a.in_region[i, s]:
                a.frames_in_region[i, s] += 1
        if a.lock[i] >= 0:
            a.frames_locked[i, a.lock[i]] += 1


@njit
def _reset_lanes(a, r, lanes):
    """A new game in each of `lanes`: Game.__init__."""
    for i in lanes:
        a.frame[i] = a.kills[i] = a.points[i] = a.spawns[i] = 0
        a.n_missiles[i] = a.n_shells[i] = a.n_events[i] = 0
        for s in range(2):
            a.ship_kills[i, s] = a.missiles_fired[i, s] = a.shield_hits[i, s] = 0
            a.frames_in_region[i, s] = a.frames_locked[i, s] = 0
            a.deaths[i, s, :] = 0
        _reset_fortress(a, i, True)
        for s in range(2):
            _spawn(a, r, i, s)


# ---------------------------------------------------------------------- geometry


@njit
def _point_distance(planes, facing, px, py):
    """pymunk's Poly.point_query(p).distance for the hexagon on the fortress body at `facing`:
    Chipmunk's body transform (a = d = cos, b = sin, c = -sin, no translation) applied to the
    planes, then cpPolyShapePointQuery."""
    angle = math.radians(facing)
    ca, sa = math.cos(angle), math.sin(angle)
    count = planes.shape[0]
    v0x = ca * planes[count - 1, 0] + -sa * planes[count - 1, 1] + 0.0
    v0y = sa * planes[count - 1, 0] + ca * planes[count - 1, 1] + 0.0
    min_dist = np.inf
    outside = False
    for k in range(count):
        v1x = ca * planes[k, 0] + -sa * planes[k, 1] + 0.0
        v1y = sa * planes[k, 0] + ca * planes[k, 1] + 0.0
        nx = ca * planes[k, 2] + -sa * planes[k, 3]
        ny = sa * planes[k, 2] + ca * planes[k, 3]
        if nx * (px - v1x) + ny * (py - v1y) > 0.0:
            outside = True
        dx, dy = v0x - v1x, v0y - v1y  # cpClosetPointOnSegment(p, v0, v1)
        t = (dx * (px - v1x) + dy * (py - v1y)) / (dx * dx + dy * dy)
        t = 0.0 if not t > 0.0 else (t if t < 1.0 else 1.0)  # cpfclamp01
        ex, ey = px - (v1x + dx * t), py - (v1y + dy * t)
        dist = math.sqrt(ex * ex + ey * ey)
        if dist < min_dist:
            min_dist = dist
        v0x, v0y = v1x, v1y
    return min_dist if outside else -min_dist


@njit
def _in_hexagon(planes, radius, cos30, facing, x, y):
    d2 = x * x + y * y
    if d2 > radius * radius:
        return False
    apothem = radius * cos30
    if d2 <= apothem * apothem:
        return True
    return _point_distance(planes, facing, x, y) <= 0.0


# ---------------------------------------------------------------------- set-up and resets


@njit
def _event(events, n_events, i, kind, role, cause):
    k = n_events[i]
    events[i, k, 0] = kind
    events[i, k, 1] = role
    events[i, k, 2] = cause
    n_events[i] = k + 1


@njit
def _uniform(a, i, lo, hi):
    """random.uniform(lo, hi) from the lane's next draw."""
    u = a.draws[i, a.used[i]]
    a.used[i] += 1
    return lo + (hi - lo) * u


@njit
def _spawn(a, r, i, s):
    a.spawns[i] += 1
    angle = _uniform(a, i, 0.0, r.two_pi)
    dist = _uniform(a, i, 0.0, r.spawn_jitter_px)
    a.x[i, s] = r.spawn_x[s] + dist * math.cos(angle)
    a.y[i, s] = r.spawn_y[s] + dist * math.sin(angle)
    jitter = _uniform(a, i, -r.spawn_jitter_deg, r.spawn_jitter_deg)
    a.heading[i, s] = (r.spawn_heading[s] + jitter) % 360.0
    a.vx[i, s] = a.vy[i, s] = 0.0
    a.alive[i, s] = True
    a.cooldown[i, s] = 0
    planes, radius, cos30 = r.region_planes, r.region_radius, r.cos30
    a.in_region[i, s] = _in_hexagon(planes, radius, cos30, a.facing[i], a.x[i, s], a.y[i, s])


@njit
def _reset_fortress(a, i, full):
    if full:
        a.facing[i] = 0.0
    a.fortress_alive[i] = True
    a.lock[i] = -1
    a.since_shell[i] = a.vulnerable[i] = a.down_frames[i] = 0
    a.reset_in[i] = -1


@njit
def _respawn_dead(a, r, i):
    for s in range(2):
        if not a.alive[i, s]:
            _spawn(a, r, i, s)
            _event(a.events, a.n_events, i, RESPAWN, s, -1)


# ---------------------------------------------------------------------- the frame's phases


@njit
def _steer_ships(a, r, actions):
    """Frame count, each living ship's steer, then the pymunk space step: every body moves by its
    velocity (a dead ship's is zero)."""
    for i in range(actions.shape[0]):
        a.frame[i] += 1
        a.n_events[i] = 0
        for s in range(2):
            if not a.alive[i, s]:
                continue
            action = actions[i, s]
            turn, thrust, fire = r.heads[action]
            a.heading[i, s], vx, vy, cos_h, sin_h = steer(
                a.heading[i, s], a.vx[i, s], a.vy[i, s], turn, thrust,
                r.ship_turn, r.ship_thrust, r.ship_drag, r.ship_max_speed,
            )  # fmt: skip
            a.vx[i, s], a.vy[i, s] = vx, vy
            if a.cooldown[i, s] > 0:
                a.cooldown[i, s] -= 1
            if fire and a.cooldown[i, s] == 0:
                n = a.n_missiles[i]
                own = 0
                for k in range(n):
                    own += a.missiles[i, k, 4] == s
                if own < r.missiles_in_flight:
                    m = a.missiles[i, n]
                    m[0] = a.x[i, s] + r.ship_radius * cos_h
                    m[1] = a.y[i, s] + r.ship_radius * sin_h
                    m[2] = r.missile_speed * cos_h
                    m[3] = r.missile_speed * sin_h
                    m[4] = s
                    a.n_missiles[i] = n + 1
                    a.cooldown[i, s] = r.missile_cooldown
                    a.missiles_fired[i, s] += 1
                    _event(a.events, a.n_events, i, MISSILE, s, -1)
        for s in range(2):
            a.x[i, s] += a.vx[i, s]
            a.y[i, s] += a.vy[i, s]


@njit
def _move_projectiles(r, group, counts):
    """Move every missile (or shell) and drop those off the arena, keeping launch order."""
    for i in range(counts.shape[0]):
        kept = 0
        for k in range(counts[i]):
            group[i, k, 0] += group[i, k, 2]
            group[i, k, 1] += group[i, k, 3]
            if -r.arena_x <= group[i, k, 0] <= r.arena_x and -r.arena_y <= group[i, k, 1] <= r.arena_y:
                group[i, kept] = group[i, k]
                kept += 1
        counts[i] = kept


@njit
def _ship_collisions(a, r):
    for i in range(a.frame.shape[0]):
        for s in range(2):
            if a.alive[i, s]:
                x, y = a.x[i, s], a.y[i, s]
                if abs(x) > r.arena_x or abs(y) > r.arena_y:
                    _kill_ship(a, r, i, s, BORDER)
                elif a.fortress_alive[i] and _in_hexagon(
                    r.shield_planes, r.shield_radius, r.cos30, a.facing[i], x, y
                ):
                    _kill_ship(a, r, i, s, SHIELD)


@njit
def _kill_ship(a, r, i, s, cause):
    a.alive[i, s] = False
    a.vx[i, s] = a.vy[i, s] = 0.0
    a.in_region[i, s] = False
    a.deaths[i, s, cause] += 1
    a.points[i] += r.points_death
    _event(a.events, a.n_events, i, DEATH, s, cause)


@njit
def _resolve_missiles(a, r):
    """Missiles against shield and fortress, in lanes whose fortress is up; each lane's killer
    seat (its earliest-launched killing missile's owner), or -1."""
    killed_by = np.full(a.frame.shape[0], -1, np.int64)
    reach = r.shield_radius + r.missile_radius
    for i in range(a.frame.shape[0]):
        if not a.fortress_alive[i]:
            continue
        kept = 0
        for k in range(a.n_missiles[i]):
            x, y = a.missiles[i, k, 0], a.missiles[i, k, 1]
            d2 = x * x + y * y
            keep = True
            if d2 <= reach * reach:
                through_opening = a.vulnerable[i] > 0 and in_rear_arc(a.facing[i], x, y, r.rear_arc)
                if d2 <= r.kill_distance * r.kill_distance and through_opening:
                    if killed_by[i] < 0:
                        killed_by[i] = int(a.missiles[i, k, 4])
                    keep = False
                elif not (
                    through_opening or _point_distance(r.shield_planes, a.facing[i], x, y) > r.missile_radius
                ):
                    owner = int(a.missiles[i, k, 4])
                    a.shield_hits[i, owner] += 1
                    a.points[i] += r.points_shield_hit
                    _event(a.events, a.n_events, i, SHIELD_HIT, owner, -1)
                    keep = False
            if keep:
                a.missiles[i, kept] = a.missiles[i, k]
                kept += 1
        a.n_missiles[i] = kept
    return killed_by


@njit
def _resolve_shells(a, r):
    hit2 = r.shell_hit_distance * r.shell_hit_distance
    for i in range(a.frame.shape[0]):
        kept = 0
        for k in range(a.n_shells[i]):
            hit = False
            for s in range(2):
                if a.alive[i, s]:
                    dx, dy = a.shells[i, k, 0] - a.x[i, s], a.shells[i, k, 1] - a.y[i, s]
                    if dx * dx + dy * dy <= hit2:
                        _kill_ship(a, r, i, s, SHELL_HIT)
                        hit = True
                        break
            if not hit:
                a.shells[i, kept] = a.shells[i, k]
                kept += 1
        a.n_shells[i] = kept


# ---------------------------------------------------------------------- the fortress


@njit
def _fortress(a, r, killed_by):
    for i in range(a.frame.shape[0]):
        if killed_by[i] >= 0:
            _fortress_destroyed(a, r, i, killed_by[i])
        elif a.fortress_alive[i]:
            _fortress_act(a, r, i)
        else:
            _fortress_down(a, r, i)


@njit
def _fortress_act(a, r, i):
    """Lock, turn toward the target, fire when aimed and the interval has passed."""
    if a.lock[i] >= 0 and not a.in_region[i, a.lock[i]]:
        a.lock[i] = -1
    if a.lock[i] < 0:
        for s in range(2):
            if a.in_region[i, s]:
                a.lock[i] = s
                a.since_shell[i] = 0
                _event(a.events, a.n_events, i, LOCK, s, -1)
                break
    else:
        a.since_shell[i] += 1
    if a.vulnerable[i] > 0:
        a.vulnerable[i] -= 1
    target = a.lock[i]
    if target < 0:
        return
    bearing = math.degrees(math.atan2(a.y[i, target], a.x[i, target]))
    turn, error = fortress_turn(a.facing[i], bearing, r.fortress_turn)
    if turn != 0.0:
        a.facing[i] = (a.facing[i] + turn) % 360.0
        error -= turn
    if abs(error) <= r.fortress_aim_tolerance and a.since_shell[i] >= r.fortress_fire_interval:
        rad = math.radians(bearing)
        shell = a.shells[i, a.n_shells[i]]
        shell[0] = shell[1] = 0.0
        shell[2] = r.shell_speed * math.cos(rad)
        shell[3] = r.shell_speed * math.sin(rad)
        a.n_shells[i] += 1
        a.since_shell[i] = 0
        a.vulnerable[i] = r.vulnerable_frames
        _event(a.events, a.n_events, i, SHELL, target, -1)


@njit
def _fortress_destroyed(a, r, i, killer):
    a.kills[i] += 1
    a.points[i] += r.points_kill
    a.ship_kills[i, killer] += 1
    _event(a.events, a.n_events, i, KILL, killer, -1)
    a.fortress_alive[i] = False
    a.lock[i] = -1
    a.vulnerable[i] = a.down_frames[i] = 0
    a.reset_in[i] = -1
    a.n_missiles[i] = a.n_shells[i] = 0
    _respawn_dead(a, r, i)


@njit
def _fortress_down(a, r, i):
    """A ship that died while the fortress was down comes back with it: a new round starts."""
    a.down_frames[i] += 1
    if a.down_frames[i] >= r.respawn_delay and not (a.in_region[i, 0] or a.in_region[i, 1]):
        _reset_fortress(a, i, False)
        _respawn_dead(a, r, i)
        _event(a.events, a.n_events, i, FORTRESS_RESPAWN, -1, -1)


@njit
def _both_dead_reset(a, r):
    for i in range(a.frame.shape[0]):
        if a.alive[i, 0] or a.alive[i, 1]:
            continue
        if a.reset_in[i] < 0:
            a.reset_in[i] = r.respawn_delay
            continue
        a.reset_in[i] -= 1
        if a.reset_in[i] == 0:
            _reset_fortress(a, i, True)
            a.n_missiles[i] = a.n_shells[i] = 0
            for s in range(2):
                _spawn(a, r, i, s)
            _event(a.events, a.n_events, i, RESET, -1, -1)
