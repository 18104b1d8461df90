"""Whole games in bulk: `play()` (play.py) for many seeds at once, as lanes of one batched engine.

Each seat's policy answers for every lane with one `probs_batch` call, and its actions are drawn
with `lane_uniforms` keyed by the game's seed, the seat and the frame: a game's result depends on
its seed and the two policies only, never on the batch it was played in or on the worker. The
draws are not the scalar policies' `random.Random` streams, so a batched game is not the scalar
game of the same seed; the two agree in distribution (bench/engine.py, docs/rules.md).

One batch may hold games of different pairs (`play_pairs`): a seat's lanes are grouped by their
policy, and each policy answers once per frame for all its lanes, so the cost of a frame grows
with the number of distinct policies, not of pairs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import cache, partial

import numpy as np

from services.sim.batch import BatchGame
from services.sim.observation import observe
from services.sim.play import GameResult, summarize
from services.sim.sampling import act_lanes, lane_uniforms
from shared.game import ROLES, GameConfig, Policy, bait_first

Observed = Callable[[str], np.ndarray]  # a seat's observation of every lane, in a view


class RoleLanes:
    """One seat in every lane of a batch: lane i plays `policies[choice[i]]` (a choice may change
    between frames), with draws from `lane_uniforms(keys, stream, frame)`; by default the keys are
    the games' seeds and the stream is the seat's index, as in `play_batch`."""

    def __init__(
        self, role: str, policies: Sequence[Policy], choice: object, keys: object, stream: int | None = None
    ) -> None:
        self.role, self.policies = role, list(policies)
        self.choice = np.array(choice, dtype=np.int64)
        self.keys = np.asarray(keys)
        self.stream = ROLES.index(role) if stream is None else stream

    def act(self, observed: Observed, frame: int) -> np.ndarray:
        """Every lane's action this frame: each policy in use asked once, for its lanes."""
        uniforms = lane_uniforms(self.keys, self.stream, frame)
        return act_lanes(self.policies, self.choice, observed, uniforms)


def play_lanes(
    batch: BatchGame,
    seats: Sequence,
    each_frame: Callable[[int, list[Observed], list[np.ndarray]], None] | None = None,
) -> None:
    """The one whole-game loop of bulk play: every frame, each seat (bait first; anything with
    `act(observed, frame)`: RoleLanes, the population's Partners) answers for every lane from its
    observations, each view observed once a frame, then `each_frame(frame, observed, actions)` (an
    adapter's update, a recording) sees them before the step; until the batch's games end."""
    while not batch.done[0]:
        frame = int(batch.state.frame[0])
        observed = [cache(partial(observe, batch, role)) for role in ROLES]
        actions = [seat.act(seen, frame) for seat, seen in zip(seats, observed, strict=True)]
        if each_frame is not None:
            each_frame(frame, observed, actions)
        batch.step(*actions)


def play_batch(
    bait: Policy, shooter: Policy, seeds: list[int], config: GameConfig | None = None
) -> list[GameResult]:
    """One full game per seed between two policies, all lanes of one batch."""
    zeros = np.zeros(len(seeds), np.int64)
    return play_pairs([bait], [shooter], zeros, zeros, seeds, config)


def play_pairs(
    baits: Sequence[Policy],
    shooters: Sequence[Policy],
    bait_of: object,
    shooter_of: object,
    seeds: list[int],
    config: GameConfig | None = None,
) -> list[GameResult]:
    """One full game per lane of `baits[bait_of[i]]` with `shooters[shooter_of[i]]` and seed
    `seeds[i]`, all lanes of one batch; each game is the one `play_batch` plays for its pair and seed."""
    batch = BatchGame(len(seeds), config, seeds)
    seats = [
        RoleLanes(role, policies, choice, seeds)
        for role, policies, choice in zip(ROLES, (baits, shooters), (bait_of, shooter_of), strict=True)
    ]
    play_lanes(batch, seats)
    return results(batch, seeds)


def results(batch: BatchGame, seeds: list[int]) -> list[GameResult]:
    """Every lane's finished game."""
    kpm = batch.kills_per_minute()
    return [
        GameResult(
            seed,
            int(batch.state.frame[lane]),
            int(batch.state.kills[lane]),
            float(kpm[lane]),
            int(batch.state.points[lane]),
            batch.counters(lane),
        )
        for lane, seed in enumerate(seeds)
    ]


def team_score(policy: Policy, partner: Policy, seeds: range, config: GameConfig | None = None) -> dict:
    """Kills/min of `policy` with `partner` over seeded games (lanes of one batch)."""
    s = summarize(play_batch(*bait_first(policy.role, policy, partner), list(seeds), config))
    return {"partner": partner.key, "games": s.games, "kills_per_minute": s.mean, "stderr": s.stderr}
