"""Observations: the full numeric state as one fixed-length vector per role.

Layout (OBS_SIZE = 64 float32, documented in docs/observation.md; the offsets below are the contract):

    [0:8)    self      x, y, vx, vy, cos heading, sin heading, alive, in region
    [8:16)   partner   same fields as self
    [16:23)  fortress  cos facing, sin facing, alive, vulnerable (fraction of the window left),
                       locked on self, locked on partner, frames since shell / fire interval (<= 1)
    [23:43)  shells    4 nearest to self, each x, y, vx, vy, present (nearest first; zeros if absent)
    [43:63)  missiles  4 nearest to the fortress, each x, y, vx, vy, present
    [63]     time left, as a fraction of the game

Positions are in units of POSITION_SCALE px, velocities of VELOCITY_SCALE px/frame, so values stay
within a few units for learning. Two views: "world" (fortress-centred, y up) and "role" (the same
picture rotated so that +y passes through the observing ship, as the original bait policies saw
it). The fortress is the origin in both.

One function observes one game and many: it is written for lanes (the batched engine's arrays),
and a scalar `Game` is one lane. Each step is written once: numba compiles it for a batch
(`compiled`, `jitable`), and for a Game or a bus message Python runs the same source over one
lane (lists and memoryviews), so a live sim or agent never loads numba. Both do the same float64
operations in the same order: the values are bit-identical (batch_test.py).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from services.sim.engine import Game
from services.sim.jit import compiled, jitable
from shared.game import OBS_SIZE, ROLES, check_role

if TYPE_CHECKING:
    from services.sim.batch import BatchGame

POSITION_SCALE = 100.0
VELOCITY_SCALE = 10.0
N_SHELLS = 4
N_MISSILES = 4
SHIP_SIZE = 8
PROJECTILE_SIZE = 5

SELF = 0
PARTNER = SELF + SHIP_SIZE
FORTRESS = PARTNER + SHIP_SIZE
SHELLS = FORTRESS + 7
MISSILES = SHELLS + N_SHELLS * PROJECTILE_SIZE
TIME = MISSILES + N_MISSILES * PROJECTILE_SIZE

# Field offsets inside a ship block and inside the fortress block.
X, Y, VX, VY, COS, SIN, ALIVE, IN_REGION = range(SHIP_SIZE)
F_COS, F_SIN, F_ALIVE, F_VULNERABLE, F_LOCK_SELF, F_LOCK_PARTNER, F_SINCE_SHELL = range(7)

VIEWS = ("world", "role")  # the observation's coordinates (a "frame" is a time step)

# Offsets of every (x, y)-like pair that turns with the frame: positions, velocities, headings.
_PAIRS = np.array(
    [
        *(block + field for block in (SELF, PARTNER) for field in (X, VX, COS)),
        FORTRESS + F_COS,
        *(SHELLS + i * PROJECTILE_SIZE + field for i in range(N_SHELLS + N_MISSILES) for field in (X, VX)),
    ],
    dtype=np.int64,
)


def observe(game: Game | BatchGame, role: str, view: str = "world") -> np.ndarray:
    """The float32 observations of `role` (bait or shooter) in the given view: (lanes, 64) for a
    BatchGame; for a Game, its one lane's (64,)."""
    rows = _world_rows(game, role)
    _check_view(view)
    if isinstance(game, Game):
        if view == "role":
            _rotate(memoryview(rows))
        return rows[0].astype(np.float32)
    if view == "role":
        to_role_view(rows)
    return rows.astype(np.float32)


def world_values(game: Game, role: str) -> list[float]:
    """One game's observation of `role` in the world view, as the float64 values the sim publishes."""
    return _world_rows(game, role)[0].tolist()


def world_views(game: Game) -> dict[str, list[float]]:
    """Each seat's `world_values`, reading the game once for both (the sim's state, every frame)."""
    lane, rows = _Lane.of(game), np.empty((len(ROLES), OBS_SIZE), np.float64)
    for me, role in enumerate(ROLES):
        _world_values(lane, *_settings(game, role), memoryview(rows[me : me + 1]))
    return dict(zip(ROLES, rows.tolist(), strict=True))


def as_observation(values: list[float], view: str = "world") -> np.ndarray:
    """World-view values (as the sim publishes them) -> the float32 vector a policy reads.

    The role view is computed from the float64 world values here, in-process and on the bus alike,
    so that a policy sees bit-identical input either way."""
    _check_view(view)
    rows = np.array([values], dtype=np.float64)
    if view == "role":
        _rotate(memoryview(rows))
    return rows[0].astype(np.float32)


def _check_view(view: str) -> None:
    if view not in VIEWS:
        raise ValueError(f"unknown observation view {view!r}; expected one of {VIEWS}")


class _Lane(NamedTuple):
    """A Game as one lane: the fields of the batched engine's `State` that an observation reads,
    as lists and memoryviews (their items are Python numbers, quick to read in Python)."""

    frame: list
    facing: list
    fortress_alive: list
    lock: list
    since_shell: list
    vulnerable: list
    x: memoryview
    y: memoryview
    vx: memoryview
    vy: memoryview
    heading: memoryview
    alive: memoryview
    in_region: memoryview
    missiles: memoryview
    n_missiles: list
    shells: memoryview
    n_shells: list

    @classmethod
    def of(cls, game: Game) -> _Lane:
        fields = [[s.x, s.y, s.vx, s.vy, s.heading, s.alive, s.in_region] for s in game.ships]
        ships = np.array(fields, dtype=np.float64).T.reshape(7, 1, 2).copy()
        missiles = np.array(game.missiles, dtype=np.float64).reshape(1, -1, 5)
        shells = np.array(game.shells, dtype=np.float64).reshape(1, -1, 4)
        return cls(
            [game.frame], [game.facing], [game.fortress_alive], [game.lock], [game.since_shell],
            [game.vulnerable], *map(memoryview, ships),
            memoryview(missiles), [len(game.missiles)], memoryview(shells), [len(game.shells)],
        )  # fmt: skip


def _world_rows(game: Game | BatchGame, role: str) -> np.ndarray:
    """The (lanes, 64) float64 world-view values of `role`: compiled for a batch, Python for a Game."""
    settings = _settings(game, role)
    if isinstance(game, Game):
        rows = np.empty((1, OBS_SIZE), np.float64)
        _world_values(_Lane.of(game), *settings, memoryview(rows))
    else:
        rows = np.empty((game.n, OBS_SIZE), np.float64)
        _world_lanes(game.state, *settings, rows)
    return rows


def _settings(game: Game | BatchGame, role: str) -> tuple[int, int, int, int]:
    """The arguments of `_world_values` after the lane: the seat and the config it reads."""
    c = game.config
    return ROLES.index(check_role(role)), c.vulnerable_frames, c.fortress_fire_interval, c.frames


def _world_values(a, me, vulnerable_frames, fire_interval, frames, out):
    """Each row of `out`: its lane's world-view observation of seat `me`."""
    p, v = 1.0 / POSITION_SCALE, 1.0 / VELOCITY_SCALE
    room = max(a.shells.shape[1], a.missiles.shape[1])
    scratch = np.empty(max(N_SHELLS, N_MISSILES), np.int64), np.empty(room), np.empty(room, np.bool_)
    for i in range(out.shape[0]):
        for block, s in ((SELF, me), (PARTNER, 1 - me)):
            h = math.radians(a.heading[i, s])
            out[i, block + X] = a.x[i, s] * p
            out[i, block + Y] = a.y[i, s] * p
            out[i, block + VX] = a.vx[i, s] * v
            out[i, block + VY] = a.vy[i, s] * v
            out[i, block + COS] = math.cos(h)
            out[i, block + SIN] = math.sin(h)
            out[i, block + ALIVE] = _flag(a.alive[i, s])
            out[i, block + IN_REGION] = _flag(a.in_region[i, s])
        f = math.radians(a.facing[i])
        out[i, FORTRESS + F_COS] = math.cos(f)
        out[i, FORTRESS + F_SIN] = math.sin(f)
        out[i, FORTRESS + F_ALIVE] = _flag(a.fortress_alive[i])
        out[i, FORTRESS + F_VULNERABLE] = a.vulnerable[i] / vulnerable_frames
        out[i, FORTRESS + F_LOCK_SELF] = _flag(a.lock[i] == me)
        out[i, FORTRESS + F_LOCK_PARTNER] = _flag(a.lock[i] == 1 - me)
        since = a.since_shell[i] / fire_interval
        out[i, FORTRESS + F_SINCE_SHELL] = 1.0 if since > 1.0 else since  # min(since, 1.0)
        _projectiles(a.shells, a.n_shells[i], i, a.x[i, me], a.y[i, me], N_SHELLS, scratch, out, SHELLS)
        _projectiles(a.missiles, a.n_missiles[i], i, 0.0, 0.0, N_MISSILES, scratch, out, MISSILES)
        out[i, TIME] = 1.0 - a.frame[i] / frames


def _rotate(rows):
    """Rotate world-view rows about the fortress, in place, so that +y passes through the observing
    ship."""
    for i in range(rows.shape[0]):
        rot = math.pi / 2 - math.atan2(rows[i, SELF + Y], rows[i, SELF + X])
        cr, sr = math.cos(rot), math.sin(rot)
        for j in _PAIRS:
            x, y = rows[i, j], rows[i, j + 1]
            rows[i, j] = x * cr - y * sr
            rows[i, j + 1] = x * sr + y * cr


# The bulk forms: the same functions compiled, for a batch's lanes.
_world_lanes = compiled(_world_values)
to_role_view = compiled(_rotate)


@jitable
def _flag(value):
    return 1.0 if value else 0.0


@jitable
def _projectiles(group, count, i, cx, cy, size, scratch, out, block):
    """Row i's `block` of lane i's projectiles nearest (cx, cy), up to `size`: x, y, vx, vy, present
    each; zeros after."""
    p, v = 1.0 / POSITION_SCALE, 1.0 / VELOCITY_SCALE
    found = _nearest(group, count, i, cx, cy, size, scratch)
    picks = scratch[0]
    for j in range(size * PROJECTILE_SIZE):
        out[i, block + j] = 0.0
    for j in range(found):
        k, at = picks[j], block + j * PROJECTILE_SIZE
        out[i, at] = group[i, k, 0] * p
        out[i, at + 1] = group[i, k, 1] * p
        out[i, at + 2] = group[i, k, 2] * v
        out[i, at + 3] = group[i, k, 3] * v
        out[i, at + 4] = 1.0


@jitable
def _nearest(group, count, i, cx, cy, size, scratch):
    """Into scratch's picks: the indices of lane i's up to `size` projectiles nearest (cx, cy),
    nearest first, ties in launch order (as a stable sort orders them); returns how many."""
    picks, d2, taken = scratch
    for k in range(count):
        dx, dy = group[i, k, 0] - cx, group[i, k, 1] - cy
        d2[k] = dx * dx + dy * dy
        taken[k] = False
    n = min(count, size)
    for j in range(n):
        best = -1
        for k in range(count):
            if not taken[k] and (best < 0 or d2[k] < d2[best]):
                best = k
        taken[best] = True
        picks[j] = best
    return n
