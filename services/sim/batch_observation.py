"""Observations of every lane of a batched game at once: `observe()` (observation.py) in bulk.

Bit-identical to the scalar `observe` for the same state: the world-view values are computed in
float64 with the same operations and order (nearest shells and missiles by a stable selection, as
`sorted` orders them), rotated into the role view the same way, then rounded to float32.
"""

from __future__ import annotations

import math

import numpy as np

from services.sim import observation as ob
from services.sim.batch import BatchGame
from services.sim.jit import njit
from shared.game import OBS_SIZE, ROLES

_PAIRS = np.array(ob._PAIRS, dtype=np.int64)


def observe(batch: BatchGame, role: str, view: str = "world") -> np.ndarray:
    """The (lanes, 64) float32 observations of `role` in every lane, in the given view."""
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r}; expected one of {ROLES}")
    if view not in ob.VIEWS:
        raise ValueError(f"unknown observation view {view!r}; expected one of {ob.VIEWS}")
    values = np.empty((batch.n, OBS_SIZE), np.float64)
    c = batch.config
    _world_values(
        batch.state, ROLES.index(role), c.vulnerable_frames, c.fortress_fire_interval, c.frames, values
    )
    if view == "role":
        to_role_view(values)
    return values.astype(np.float32)


@njit
def _flag(value):
    return 1.0 if value else 0.0


@njit
def _nearest(group, count, cx, cy, picks):
    """Indices of the up to len(picks) projectiles nearest (cx, cy), nearest first, ties in
    launch order (a stable sort's first entries); returns how many."""
    n = min(count, picks.shape[0])
    for j in range(n):
        best, best_d2 = -1, 0.0
        for k in range(count):
            taken = False
            for q in range(j):
                taken = taken or picks[q] == k
            if taken:
                continue
            d2 = (group[k, 0] - cx) ** 2 + (group[k, 1] - cy) ** 2
            if best < 0 or d2 < best_d2:
                best, best_d2 = k, d2
        picks[j] = best
    return n


@njit
def _world_values(a, me, vulnerable_frames, fire_interval, frames, out):
    p, v = 1.0 / ob.POSITION_SCALE, 1.0 / ob.VELOCITY_SCALE
    picks = np.empty(max(ob.N_SHELLS, ob.N_MISSILES), np.int64)
    for i in range(out.shape[0]):
        for block, s in ((ob.SELF, me), (ob.PARTNER, 1 - me)):
            h = math.radians(a.heading[i, s])
            out[i, block + ob.X] = a.x[i, s] * p
            out[i, block + ob.Y] = a.y[i, s] * p
            out[i, block + ob.VX] = a.vx[i, s] * v
            out[i, block + ob.VY] = a.vy[i, s] * v
            out[i, block + ob.COS] = math.cos(h)
            out[i, block + ob.SIN] = math.sin(h)
            out[i, block + ob.ALIVE] = _flag(a.alive[i, s])
            out[i, block + ob.IN_REGION] = _flag(a.in_region[i, s])
        f = math.radians(a.facing[i])
        fort = ob.FORTRESS
        out[i, fort + ob.F_COS] = math.cos(f)
        out[i, fort + ob.F_SIN] = math.sin(f)
        out[i, fort + ob.F_ALIVE] = _flag(a.fortress_alive[i])
        out[i, fort + ob.F_VULNERABLE] = a.vulnerable[i] / vulnerable_frames
        out[i, fort + ob.F_LOCK_SELF] = _flag(a.lock[i] == me)
        out[i, fort + ob.F_LOCK_PARTNER] = _flag(a.lock[i] == 1 - me)
        since = a.since_shell[i] / fire_interval
        out[i, fort + ob.F_SINCE_SHELL] = 1.0 if since > 1.0 else since  # min(since, 1.0)
        shells, missiles = out[i, ob.SHELLS : ob.MISSILES], out[i, ob.MISSILES : ob.TIME]
        _projectiles(a.shells[i], a.n_shells[i], a.x[i, me], a.y[i, me], picks[: ob.N_SHELLS], shells)
        _projectiles(a.missiles[i], a.n_missiles[i], 0.0, 0.0, picks[: ob.N_MISSILES], missiles)
        out[i, ob.TIME] = 1.0 - a.frame[i] / frames


@njit
def _projectiles(group, count, cx, cy, picks, out):
    """The block of the projectiles nearest (cx, cy): x, y, vx, vy, present each; zeros after."""
    p, v = 1.0 / ob.POSITION_SCALE, 1.0 / ob.VELOCITY_SCALE
    found = _nearest(group, count, cx, cy, picks)
    out[:] = 0.0
    for j in range(found):
        k, at = picks[j], j * ob.PROJECTILE_SIZE
        out[at] = group[k, 0] * p
        out[at + 1] = group[k, 1] * p
        out[at + 2] = group[k, 2] * v
        out[at + 3] = group[k, 3] * v
        out[at + 4] = 1.0


@njit
def to_role_view(values):
    """observation.to_role_view on every row, in place."""
    for i in range(values.shape[0]):
        rot = math.pi / 2 - math.atan2(values[i, ob.SELF + ob.Y], values[i, ob.SELF + ob.X])
        cr, sr = math.cos(rot), math.sin(rot)
        for j in _PAIRS:
            x, y = values[i, j], values[i, j + 1]
            values[i, j] = x * cr - y * sr
            values[i, j + 1] = x * sr + y * cr
