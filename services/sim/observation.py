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
"""

from __future__ import annotations

import math

import numpy as np

from services.sim.engine import Game
from shared.game import ROLES, check_role, other

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


def observe(game: Game, role: str, view: str = "world") -> np.ndarray:
    """The observation vector of `role` (bait or shooter) in the given view."""
    return as_observation(world_values(game, role), view)


def as_observation(values: list[float], view: str = "world") -> np.ndarray:
    """World-frame values (as the sim publishes them) -> the float32 vector a policy reads.

    The role view is computed from the float64 world values here, in-process and on the bus alike,
    so that a policy sees bit-identical input either way."""
    if view == "role":
        values = to_role_view(values)
    elif view != "world":
        raise ValueError(f"unknown observation view {view!r}; expected one of {VIEWS}")
    return np.array(values, dtype=np.float32)


def world_values(game: Game, role: str) -> list[float]:
    """The observation of `role` in the world view, as float64 values in the documented layout."""
    me, them = ROLES.index(check_role(role)), ROLES.index(other(role))
    ship, partner = game.ships[me], game.ships[them]
    sx, sy = ship.body.position
    p, v = 1.0 / POSITION_SCALE, 1.0 / VELOCITY_SCALE
    out: list[float] = []
    for s in (ship, partner):
        x, y = s.body.position
        h = math.radians(s.heading)
        out += [
            x * p,
            y * p,
            s.vx * v,
            s.vy * v,
            math.cos(h),
            math.sin(h),
            float(s.alive),
            float(s.in_region),
        ]
    c = game.config
    f = math.radians(game.facing)
    out += [
        math.cos(f),
        math.sin(f),
        float(game.fortress_alive),
        game.vulnerable / c.vulnerable_frames,
        float(game.lock == me),
        float(game.lock == them),
        min(game.since_shell / c.fortress_fire_interval, 1.0),
    ]
    shells = sorted(game.shells, key=lambda s: (s[0] - sx) ** 2 + (s[1] - sy) ** 2)[:N_SHELLS]
    missiles = sorted(game.missiles, key=lambda m: m[0] * m[0] + m[1] * m[1])[:N_MISSILES]
    for group, size in ((shells, N_SHELLS), (missiles, N_MISSILES)):
        for x, y, vx, vy, *_ in group:
            out += [x * p, y * p, vx * v, vy * v, 1.0]
        out += [0.0] * (PROJECTILE_SIZE * (size - len(group)))
    out.append(1.0 - game.frame / c.frames)
    return out


# Offsets of every (x, y)-like pair that turns with the frame: positions, velocities, headings.
_PAIRS = [
    *(block + field for block in (SELF, PARTNER) for field in (X, VX, COS)),
    FORTRESS + F_COS,
    *(SHELLS + i * PROJECTILE_SIZE + field for i in range(N_SHELLS + N_MISSILES) for field in (X, VX)),
]


def to_role_view(values: list[float]) -> list[float]:
    """Rotate world-view values about the fortress so that +y passes through the observing ship."""
    rot = math.pi / 2 - math.atan2(values[SELF + Y], values[SELF + X])
    cr, sr = math.cos(rot), math.sin(rot)
    out = list(values)
    for i in _PAIRS:
        x, y = values[i], values[i + 1]
        out[i] = x * cr - y * sr
        out[i + 1] = x * sr + y * cr
    return out
