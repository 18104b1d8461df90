"""The guard of the `-guard` strategies: safe adaptation against what the table promised.

The table P promises a kill rate for our adapted policy with the estimated partner type. A partner
that no library type explains (a person, a slow hand) can make that promise false, and then the
adapted policy may do worse than the best static one. The guard watches the team's realised
performance from the states the adapter already reads (the fortress going down is a kill, its
shield opening is an opening, a ship's alive flag falling is a death) since our agent took up the
adapted policy; once `min_frames` have passed and the kills are improbably few for the promised
rate (a one-sided Poisson test at level `p`), it falls back to the best static policy for the rest
of the game. So a game adds at most one switch, and the best static policy is never left again.
"""

from __future__ import annotations

import math

import numpy as np

from services.sim import observation as ob
from shared.game import FPS

FRAMES_PER_MINUTE = 60 * FPS
GUARD_FRAMES = 15 * FPS  # 15 s under the adapted policy before it is judged
GUARD_P = 0.05


def poisson_cdf(k: int, mean: float) -> float:
    """P(X <= k) for X ~ Poisson(mean)."""
    term = total = math.exp(-mean)
    for i in range(1, k + 1):
        term *= mean / i
        total += term
    return min(total, 1.0)


class Guard:
    """Counts kills, openings and deaths under the adapted policy in each of n games (lanes; one
    game is one lane) and says where to fall back. Policies are indices into the payoff's ours; no
    promise is NaN."""

    def __init__(self, fallback: int, lanes: int, min_frames: int = GUARD_FRAMES, p: float = GUARD_P) -> None:
        self.fallback, self.min_frames, self.p = fallback, min_frames, p
        self.tripped = np.zeros(lanes, bool)
        self.promise = np.full(lanes, np.nan)  # kills/min the table promised for the adapted policy
        self.frames, self.kills = np.zeros(lanes, np.int64), np.zeros(lanes, np.int64)
        self.openings, self.deaths = np.zeros(lanes, np.int64), np.zeros(lanes, np.int64)
        self.last: np.ndarray | None = None

    def start(self, lanes: np.ndarray, policies: np.ndarray, promises: np.ndarray) -> None:
        """`lanes` now play `policies`, which the table promised `promises` kills/min for."""
        self.promise[lanes] = np.where(policies == self.fallback, np.nan, promises)
        for count in (self.frames, self.kills, self.openings, self.deaths):
            count[lanes] = 0

    def watch(self, values: np.ndarray) -> None:
        """One frame's world-view state of every lane, (n, D) (either seat's: kills, openings and
        deaths are the team's)."""
        last, self.last = self.last, np.asarray(values, np.float64)
        self.frames += 1
        if last is None:
            return
        now, f = self.last, ob.FORTRESS
        self.kills += (last[:, f + ob.F_ALIVE] > 0.5) & (now[:, f + ob.F_ALIVE] <= 0.5)
        self.openings += (last[:, f + ob.F_VULNERABLE] == 0.0) & (now[:, f + ob.F_VULNERABLE] > 0.0)
        for b in (ob.SELF, ob.PARTNER):
            self.deaths += (last[:, b + ob.ALIVE] > 0.5) & (now[:, b + ob.ALIVE] <= 0.5)

    def breached(self, asked: np.ndarray) -> np.ndarray:
        """Where `asked` (a mask), whether the adapted policy has fallen short of its promise (and
        the guard trips); False elsewhere."""
        judged = asked & ~self.tripped & ~np.isnan(self.promise) & (self.frames >= self.min_frames)
        for i in np.flatnonzero(judged).tolist():
            expected = float(self.promise[i]) * int(self.frames[i]) / FRAMES_PER_MINUTE
            self.tripped[i] = poisson_cdf(int(self.kills[i]), expected) < self.p
        return asked & self.tripped
