"""Stalled rounds: with its partner dead, every agent seat ends the round, so the team plays on."""

from __future__ import annotations

import numpy as np
import pytest

from services.agent import library, networks
from services.agent.policy import end_round_batch, end_round_choice, rule_probs, stalled
from services.agent.scripted import CircleBait, Idle, MirrorShooter, OrbitBait
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
        OrbitBait(place=1.0),
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


def _states(seeds: range = range(1), frames: int = 240) -> dict[str, np.ndarray]:
    """Observations of both views from games of B5 and S5, stalled rounds among them."""
    rows = {"role": [], "world": []}
    for seed in seeds:
        game = Game(seed=seed)
        b5, s5 = networks.load("B5"), networks.load("S5")
        for _ in range(frames):
            for view in rows:
                rows[view].append(observe(game, "bait", view))
            game.step(b5.act(observe(game, "bait", b5.view)), s5.act(observe(game, "shooter", s5.view)))
    return {view: np.array(r, np.float32) for view, r in rows.items()}


def test_stacked_policies_give_each_policys_own_distributions():
    """A stack (many learned policies of one shape as one batched pass; many rules of one kind as
    one) gives every member exactly the distribution its own scalar probs() gives, row by row."""
    from services.agent.policy import RuleStack, rule_stack_key
    from services.agent.seats import policy_for

    observed = _states()
    members = [policy_for(k, "bait") for k in ("PB01a", "PB01b", "PB02c", "PB06a")]
    rules = [CircleBait(radius=r, speed=s) for r, s in ((80, 1.5), (140, 2.5), (170, 3.5))]
    assert len({networks.stack_key(p) for p in members}) == 1 and len({rule_stack_key(p) for p in rules}) == 1
    assert networks.stack_key(rules[0]) is None and rule_stack_key(members[0]) is None
    for stack, policies in ((networks.Stack(members), members), (RuleStack(rules), rules)):
        obs = observed[policies[0].view]
        stacked = stack(obs)
        assert stacked.shape == (len(policies), len(obs), N_ACTIONS)
        for policy, probs in zip(policies, stacked, strict=True):
            alone = np.array([policy.probs(o) for o in obs])  # the scalar path, a row at a time
            np.testing.assert_allclose(probs, alone, rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(probs.sum(axis=1), 1.0)
        assert len({probs.tobytes() for probs in stacked}) == len(policies)  # not one policy's, copied
    with pytest.raises(ValueError, match="do not stack"):
        networks.Stack([members[0], networks.load("B5")])
