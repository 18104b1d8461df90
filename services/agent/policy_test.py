"""Stalled rounds: with its partner dead, every agent seat ends the round, so the team plays on."""

from __future__ import annotations

import numpy as np
import pytest

from services.agent import library, networks
from services.agent.policy import end_round_batch, end_round_choice, rule_probs, stalled
from services.agent.scripted import CircleBait, Idle, MirrorShooter
from services.sim import observation as ob
from services.sim.batch_play import play_batch
from services.sim.engine import Game
from services.sim.observation import observe
from services.table.table import DEFAULT_TABLE, Table
from shared.game import N_ACTIONS

EARLY = 150  # frames: the novice partner dives into the shield for the first 5 s
SEEDS = list(range(8))
KEYS = library.keys()


class Novice:
    """A partner that flies into the shield (or the border) for its first EARLY frames, dying at
    least once, and then plays a library policy: it dies early and then plays normally."""

    def __init__(self, inner) -> None:
        self.inner, self.key, self.role, self.view = inner, f"novice({inner.key})", inner.role, inner.view

    def reset(self, seed=None) -> None:
        self.inner.reset(seed)

    def probs_batch(self, observations: np.ndarray) -> np.ndarray:
        probs = self.inner.probs_batch(observations)
        early = observations[:, ob.TIME] > 1.0 - EARLY / 1800
        world = self.view == "world"
        dives = np.array([end_round_choice(o, world) for o in observations[early]], np.int64).reshape(-1, 3)
        probs[early] = rule_probs(dives, 0.01)
        return probs


def _best_partner(key: str) -> str:
    table = Table.load(DEFAULT_TABLE)
    return table.best_bait(key) if library.registry()[key].role == "shooter" else table.best_shooter(key)


@pytest.mark.parametrize(
    "key", [pytest.param(k, marks=[] if k in ("B5", "S5") else pytest.mark.slow) for k in KEYS]
)
def test_a_partner_who_dies_early_still_scores_with_every_library_policy(key):
    policy, partner = networks.load(key), Novice(networks.load(_best_partner(key)))
    pair = (partner, policy) if policy.role == "shooter" else (policy, partner)
    results = play_batch(*pair, SEEDS)
    assert all(sum(r.counters[partner.role]["deaths"].values()) >= 1 for r in results)  # it did die early
    assert sum(r.kills for r in results) > 0


def observations(view: str) -> list[np.ndarray]:
    game, rng, out = Game(None, 5), np.random.default_rng(1), []
    for _ in range(1800):
        game.step(int(rng.integers(N_ACTIONS)), int(rng.integers(N_ACTIONS)))
        out += [observe(game, "bait", view), observe(game, "shooter", view)]
    return out


@pytest.mark.parametrize("view", ["world", "role"])
def test_stalled_rows_play_the_end_round_rule_in_probs_and_in_bulk(view):
    obs = np.stack(observations(view))
    mask, choices = end_round_batch(obs, view)
    assert mask.any() and not mask.all()
    assert mask.tolist() == [stalled(o) for o in obs]
    assert all(
        tuple(c) == end_round_choice(o, view == "world")
        for o, c in zip(obs[mask], choices[mask], strict=True)
    )
    ending = rule_probs(choices[mask], 0.01)
    for policy in [
        networks.load("B5"),
        networks.load("S1"),
        networks.load("S5"),
        CircleBait(),
        MirrorShooter(),
    ]:
        if policy.view != view:
            continue
        batch = policy.probs_batch(obs)
        np.testing.assert_allclose(batch[mask], ending, atol=1e-12)
        np.testing.assert_allclose([policy.probs(o) for o in obs[mask]], ending, atol=1e-12)


def test_idle_stays_idle_in_a_stalled_round():
    obs = np.stack(observations("world"))
    mask, _ = end_round_batch(obs, "world")
    assert (Idle("shooter").rule_batch(obs[mask]) == 0).all()
