"""Human-like partners: seeded, the same in one game or in lanes, and as slow and sticky as a hand."""

from __future__ import annotations

import numpy as np
import pytest

from services.adapter.human_like import HOLD_MIN, SESSION_TRIALS, HumanLike
from services.adapter.partners import group_of, make_partner, population
from services.agent import networks
from services.sim.engine import Game
from services.sim.observation import observe
from services.sim.play import policy_seed

SEEDS = [3, 4, 5]


def play(partner_name: str, seeds: list[int], frames: int = 450) -> tuple[np.ndarray, np.ndarray]:
    """(frames, lanes) actions of the partner as lanes and as single games, on the lanes' states."""
    lanes = make_partner(partner_name, "bait")
    lanes.reset_lanes(seeds)
    singles = [make_partner(partner_name, "bait") for _ in seeds]
    for partner, seed in zip(singles, seeds, strict=True):
        partner.reset(seed)
    games, shooter = [Game(None, s) for s in seeds], networks.load("S5")
    shooter.reset(0)
    together, alone = [], []
    for _ in range(frames):
        obs = np.stack([observe(g, "bait", lanes.view) for g in games])
        together.append(lanes.act_lanes(obs))
        alone.append([p.act(o) for p, o in zip(singles, obs, strict=True)])
        for game, action in zip(games, together[-1], strict=True):
            game.step(int(action), shooter.act(observe(game, "shooter", "world")))
    return np.array(together), np.array(alone)


def test_lanes_act_as_single_games_and_a_seed_repeats_its_game():
    together, alone = play("human(B1,B5)", SEEDS)
    assert (together == alone).all()
    again, _ = play("human(B1,B5)", SEEDS)
    assert (again == together).all()
    other, _ = play("human(B1,B5)", [6, 7, 8])
    assert (other != together).any()


def test_keys_are_held_for_at_least_the_shortest_press():
    together, _ = play("human(B5)", SEEDS)
    for lane in together.T:
        changes = np.flatnonzero(np.diff(lane)) + 1
        runs = np.diff(np.concatenate([[0], changes, [len(lane)]]))
        assert runs[1:-1].min() >= HOLD_MIN  # the first and last runs are cut by the game's ends
        assert 3.0 < runs.mean() < 30.0  # held, but not frozen


def test_traits_are_a_persons_and_the_delay_a_games():
    partner = make_partner("human(B5)", "bait")
    games = list(range(SESSION_TRIALS + 1))  # one person's trials, and the next person's first
    partner.reset_lanes([policy_seed(game, "bait") for game in games])
    assert partner.trial.tolist() == [0, 1, 2, 0]
    assert len(set(partner.slip[:SESSION_TRIALS])) == 1 and partner.slip[SESSION_TRIALS] != partner.slip[0]
    assert len(set(partner.mu[:SESSION_TRIALS])) == SESSION_TRIALS  # drawn per game
    assert (partner.mu >= 120.0).all() and (partner.mu <= 400.0).all()


def test_grammar_population_and_group():
    assert isinstance(make_partner("human(B1,B5)", "bait"), HumanLike)
    assert make_partner("human(noisy(B5))", "bait").key == "human(noisy(B5))"
    assert group_of("human(B5)") == "human-like"
    humans = population("bait")["human-like"]
    assert "human(B9)" in humans and any("," in h for h in humans)
    with pytest.raises(ValueError, match="share role"):
        HumanLike(networks.load("B5"), networks.load("S5"))
