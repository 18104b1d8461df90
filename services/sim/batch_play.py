"""Whole games in bulk: `play()` (play.py) for many seeds at once, as lanes of one batched engine.

Each seat's policy answers for every lane with one `probs_batch` call, and its actions are drawn
with `lane_uniforms` keyed by the game's seed, the seat and the frame: a game's result depends on
its seed and the two policies only, never on the batch it was played in or on the worker. The
draws are not the scalar policies' `random.Random` streams, so a batched game is not the scalar
game of the same seed; the two agree in distribution (bench/engine.py, docs/rules.md).
"""

from __future__ import annotations

import numpy as np

from services.sim.batch import BatchGame
from services.sim.batch_observation import observe
from services.sim.play import GameResult
from services.sim.sampling import batch_act, lane_uniforms
from shared.game import ROLES, GameConfig, Policy


def play_batch(
    bait: Policy, shooter: Policy, seeds: list[int], config: GameConfig | None = None
) -> list[GameResult]:
    """One full game per seed between two policies, all lanes of one batch."""
    batch = BatchGame(len(seeds), config, seeds)
    keys = np.asarray(seeds)
    while not batch.done[0]:
        frame = batch.state.frame
        actions = [
            batch_act(policy, observe(batch, role, policy.view), lane_uniforms(keys, seat, frame))
            for seat, (role, policy) in enumerate(zip(ROLES, (bait, shooter), strict=True))
        ]
        batch.step(*actions)
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
