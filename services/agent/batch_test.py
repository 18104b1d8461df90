"""Batched inference: every policy's probs over a batch equal its probs row by row, and batched
sampling follows those distributions."""

from __future__ import annotations

import numpy as np
import pytest

from services.agent.library import keys
from services.agent.networks import LearnedPolicy
from services.agent.seats import policy_for
from services.sim.engine import Game
from services.sim.observation import observe
from services.sim.play import play
from services.sim.sampling import batch_act, batch_probs, lane_uniforms, sample
from shared.game import N_ACTIONS, ROLES


def observations(view: str, role: str, games: int = 2) -> np.ndarray:
    """Observations of real library games (kills, deaths, resets), every third frame."""
    rows: list[np.ndarray] = []

    def trace(game: Game, bait: int, shooter: int) -> None:
        if game.frame % 3 == 0:
            rows.append(observe(game, role, view))

    for seed in range(games):
        play(policy_for("B5", "bait"), policy_for("S5", "shooter"), seed, trace=trace)
    return np.stack(rows)


ALL = [(key, role) for role in ROLES for key in (*keys(role), "idle", "random")]
ALL += [("circle", "bait"), ("mirror", "shooter")]


@pytest.mark.parametrize(("key", "role"), ALL)
def test_batched_probs_are_the_row_by_row_probs(key: str, role: str) -> None:
    """Rules give the very same bits; a network's matrix product over a batch rounds a little
    differently from one row's (BLAS picks other kernels), so learned heads agree to 1e-12."""
    policy = policy_for(key, role)
    obs = observations(policy.view, role)
    expected = np.stack([policy.probs(row) for row in obs])
    if isinstance(policy, LearnedPolicy):
        np.testing.assert_allclose(batch_probs(policy, obs), expected, rtol=1e-12, atol=0)
    else:
        np.testing.assert_array_equal(batch_probs(policy, obs), expected)


def test_sampling_follows_the_distribution() -> None:
    probs = np.random.default_rng(0).dirichlet(np.ones(N_ACTIONS), size=4)
    uniforms = lane_uniforms(np.arange(80_000), stream=0, frame=7)
    draws = sample(np.repeat(probs, 20_000, axis=0), uniforms).reshape(4, 20_000)
    for row, p in zip(draws, probs, strict=True):
        counts = np.bincount(row, minlength=N_ACTIONS) / row.size
        assert np.abs(counts - p).max() < 0.015


def test_batched_actions_are_valid_and_the_rule_choice_mostly() -> None:
    policy = policy_for("mirror", "shooter")
    obs = observations("world", "shooter", games=1)
    actions = batch_act(policy, obs, lane_uniforms(np.arange(len(obs)), stream=1, frame=0))
    best = batch_probs(policy, obs).argmax(axis=1)
    assert actions.min() >= 0 and actions.max() < N_ACTIONS
    assert (actions == best).mean() > 0.9  # the rule's choice has probability 0.99^3


def test_lane_uniforms_are_uniform_and_depend_on_seed_stream_and_frame_only() -> None:
    seeds = np.arange(50_000)
    u = lane_uniforms(seeds, stream=0, frame=0)
    assert u.min() >= 0.0 and u.max() < 1.0
    assert abs(u.mean() - 0.5) < 0.005 and abs(u.var() - 1 / 12) < 0.002
    assert np.array_equal(lane_uniforms(seeds[::-1], 0, 0), u[::-1])  # no dependence on the batch
    others = [lane_uniforms(seeds, 1, 0), lane_uniforms(seeds, 0, 1), lane_uniforms(seeds + 1, 0, 0)]
    for other in others:
        assert abs(np.corrcoef(u, other)[0, 1]) < 0.02
