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

from services.sim import observation as ob

FRAMES_PER_MINUTE = 1800  # 30 frames per second
GUARD_FRAMES = 450  # 15 s under the adapted policy before it is judged
GUARD_P = 0.05


def poisson_cdf(k: int, mean: float) -> float:
    """P(X <= k) for X ~ Poisson(mean)."""
    term = total = math.exp(-mean)
    for i in range(1, k + 1):
        term *= mean / i
        total += term
    return min(total, 1.0)


class Guard:
    """Counts kills, openings and deaths under the adapted policy and says when to fall back."""

    def __init__(self, fallback: str, min_frames: int = GUARD_FRAMES, p: float = GUARD_P) -> None:
        self.fallback, self.min_frames, self.p = fallback, min_frames, p
        self.tripped = False
        self.promise: float | None = None  # kills/min the table promised for the adapted policy
        self.frames = self.kills = self.openings = self.deaths = 0
        self.last: list[float] | None = None

    def start(self, policy: str, promise: float) -> None:
        """Our agent now plays `policy`, which the table promised `promise` kills/min for."""
        self.promise = None if policy == self.fallback else promise
        self.frames = self.kills = self.openings = self.deaths = 0

    def watch(self, values: list[float] | object) -> None:
        """One frame's world-view state (either seat's: kills, openings and deaths are the team's)."""
        last, self.last = self.last, [float(v) for v in values]  # type: ignore[union-attr]
        self.frames += 1
        if last is None:
            return
        now, f = self.last, ob.FORTRESS
        self.kills += last[f + ob.F_ALIVE] > 0.5 >= now[f + ob.F_ALIVE]
        self.openings += last[f + ob.F_VULNERABLE] == 0.0 < now[f + ob.F_VULNERABLE]
        self.deaths += sum(last[b + ob.ALIVE] > 0.5 >= now[b + ob.ALIVE] for b in (ob.SELF, ob.PARTNER))

    def breached(self) -> bool:
        """Whether the adapted policy has fallen short of its promise (and the guard trips)."""
        if self.tripped or self.promise is None or self.frames < self.min_frames:
            return self.tripped
        expected = self.promise * self.frames / FRAMES_PER_MINUTE
        self.tripped = poisson_cdf(self.kills, expected) < self.p
        return self.tripped
