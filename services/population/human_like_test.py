"""Human-like partners: seeded, one game is one lane, keys held as a hand holds them, a forward
model that knows the game, and skill and practice where the grammar names them."""

from __future__ import annotations

import numpy as np
import pytest

from services.agent import networks
from services.population.human_like import SESSION_TRIALS, SKILLS, HumanLike, predict
from services.population.partners import kind_of, make_partner, population
from services.sim.engine import Game
from services.sim.observation import observe
from services.sim.play import policy_seed
from shared.errors import UsageError
from shared.game import split_action

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


def test_a_restarted_lane_plays_the_single_game_of_its_new_seed_while_the_others_play_on():
    """A training env restarts its lanes one by one: after `restart_lanes`, the lane's actions are
    those of a fresh single game of the new seed, and the other lane goes on as it was."""
    lanes, first, fresh = (make_partner("human(B5,skill=novice)", "bait") for _ in range(3))
    lanes.reset_lanes(SEEDS[:2])
    first.reset(SEEDS[0])
    games, shooter = [Game(None, s) for s in SEEDS[:2]], networks.load("S5")
    shooter.reset(0)
    mismatches = []
    for frame in range(300):
        if frame == 100:
            lanes.restart_lanes(np.array([1]), [SEEDS[2]])
            fresh.reset(SEEDS[2])
            games[1] = Game(None, SEEDS[2])
        obs = np.stack([observe(g, "bait", lanes.view) for g in games])
        together = lanes.act_lanes(obs)
        mismatches.append(together[0] != first.act(obs[0]))
        if frame >= 100:
            mismatches.append(together[1] != fresh.act(obs[1]))
        for game, action in zip(games, together, strict=True):
            game.step(int(action), shooter.act(observe(game, "shooter", "world")))
    assert not any(mismatches)


def runs_of(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inner runs of one key's values (the first and last are cut by the game's ends), and
    whether each was a press (non-zero)."""
    changes = np.flatnonzero(np.diff(key)) + 1
    runs = np.diff(np.concatenate([[0], changes, [len(key)]]))
    return runs[1:-1], key[changes[:-1]] != 0


def test_each_key_is_held_at_least_the_persons_shortest_press():
    partner = make_partner("human(B5,skill=novice)", "bait")
    partner.reset_lanes(SEEDS)
    together, _ = play("human(B5,skill=novice)", SEEDS)
    for lane, hold in zip(together.T, partner.hold, strict=True):
        assert (hold == 3).all()
        for key in split_action(lane):
            assert runs_of(key)[0].min() >= 3
        assert 2.0 < np.mean(np.diff(lane) != 0) ** -1 < 30.0  # held, but not frozen


def test_named_parameters_fix_the_persons_traits_in_every_trial():
    """human(...)'s parameters replace what the person and their practice would draw: the
    reaction time (but for the game's own spread), looks, lapses, slips, foresight, and the holds,
    the fire key's burst and gap its own."""
    name = (
        "human(B5,reaction_ms=300,look_ms=200,hold_ms=100,fire_ms=300,fire_gap_ms=200,"
        "lapses=3,slip=0.1,foresight=0.5)"
    )
    partner = make_partner(name, "bait")
    assert partner.key == name and make_partner(partner.key, "bait").key == name
    partner.reset_lanes([policy_seed(g, "bait") for g in range(30)])
    assert abs(partner.mu.mean() - 300.0) < 10.0 and partner.mu.std() > 5.0
    assert (partner.look == 6.0).all() and (partner.slip == 0.1).all() and (partner.foresight == 0.5).all()
    assert np.allclose(partner.lapse, 3.0 / 1800.0 * 6.0)
    assert partner.hold[0].tolist() == [[3, 3], [3, 3], [6, 9]]
    together, _ = play(name, SEEDS)
    keys = [[runs_of(key) for key in split_action(lane)] for lane in together.T]
    turn, thrust, fire = (np.concatenate([lane[k][0] for lane in keys]) for k in range(3))
    pressed = np.concatenate([lane[2][1] for lane in keys])
    assert turn.min() >= 3 and thrust.min() >= 3 and len(fire) > 4
    assert fire[pressed].min() >= 9 and fire[~pressed].min() >= 6
    unchanged = make_partner("human(B5,skill=practised,slip=0.2)", "bait")
    practised = make_partner("human(B5,skill=practised)", "bait")
    for p in (unchanged, practised):
        p.reset_lanes([policy_seed(g, "bait") for g in range(6)])
    assert (unchanged.mu == practised.mu).all() and (unchanged.slip == 0.2).all()


def test_traits_are_a_persons_the_delay_a_games_and_practice_helps():
    partner = make_partner("human(B5)", "bait")
    games = list(range(SESSION_TRIALS + 1))  # one person's trials, and the next person's first
    partner.reset_lanes([policy_seed(game, "bait") for game in games])
    assert partner.trial.tolist() == [0, 1, 2, 0]
    assert len(set(partner.slip[:SESSION_TRIALS])) == SESSION_TRIALS  # practice lowers it
    assert partner.slip[0] > partner.slip[1] > partner.slip[2]
    assert partner.look[0] > partner.look[2] and partner.slip[SESSION_TRIALS] != partner.slip[0]
    assert len(set(partner.mu[:SESSION_TRIALS])) == SESSION_TRIALS  # drawn per game
    assert (partner.mu >= 120.0).all() and (partner.mu <= 450.0).all()
    novice, practised = (make_partner(f"human(B5,skill={s})", "bait") for s in ("novice", "practised"))
    for p in (novice, practised):
        p.reset_lanes([policy_seed(g, "bait") for g in range(30)])
    assert novice.mu.mean() > practised.mu.mean() + 40.0 and novice.look.mean() > practised.look.mean()
    assert novice.foresight.mean() < 0.3 < 0.8 < practised.foresight.mean()


def test_the_forward_model_moves_the_own_ship_by_its_keys_and_foresees_the_fortress():
    """Predicted from the state `lag` frames ago and the keys pressed since, the own ship is where
    it is now, and the fortress's facing and opening are as they are (it has one target here)."""
    game, bait, shooter = Game(None, 1), networks.load("B5"), networks.load("S4")
    bait.reset(1)
    shooter.reset(2)
    states, keys = [], np.zeros((1, 64), np.int64)
    lag, checked = 9, 0
    for t in range(600):
        states.append(observe(game, "shooter", "world"))
        if t >= lag and states[t - lag][16 + 2] > 0.5 and states[t][16 + 2] > 0.5:  # the fortress up
            rules = HumanLike(shooter).rules
            expected = predict(states[t - lag][None], np.array([lag]), np.array([lag]), keys, t, rules)[0]
            assert np.allclose(expected[:6], states[t][:6], atol=1e-5)
            assert np.allclose(expected[16:20], states[t][16:20], atol=0.06) or states[t][16 + 5] > 0.5
            checked += 1
        action = shooter.act(observe(game, "shooter", shooter.view))
        keys[0, t % 64] = action
        game.step(bait.act(observe(game, "bait", bait.view)), action)
    assert checked > 300


def test_grammar_population_and_kind():
    assert isinstance(make_partner("human(B1,B5)", "bait"), HumanLike)
    assert make_partner("human(noisy(B5))", "bait").key == "human(noisy(B5))"
    practised = make_partner("human(B1,B5, skill=practised, input_ms=40)", "bait")
    assert practised.skill == SKILLS["practised"] and practised.input_ms == 40.0
    assert practised.key == "human(B1,B5,skill=practised,input_ms=40)"
    assert make_partner(practised.key, "bait").key == practised.key
    assert make_partner("human(B5,skill=0.3)", "bait").key == "human(B5,skill=0.3)"
    assert make_partner("human(B5,skill=typical)", "bait").key == "human(B5)"
    assert kind_of("human(B5,skill=novice)") == "human-like"
    humans = population("bait")["human-like"]
    assert {"human(B1,skill=novice)", "human(B2)", "human(B3,skill=practised)"} <= set(humans)
    assert any(h.count(",") == 2 for h in humans)  # a drifting person, with a skill
    for wrong, problem in [
        ("human(B5,skill=expert)", "novice, typical, practised"),
        ("human(B5,skill=2)", "number in"),
        ("human(B5,input_ms=-1)", "outside"),
        ("human(B5,speed=3)", "skill=LEVEL"),
        ("human(B5,lapses=-1)", "outside"),
        ("human(B5,reaction_ms=fast)", "no number"),
        ("human(B5,session=2.5)", "no whole number"),
        ("human(B1,B2,B3)", "one or two"),
    ]:
        with pytest.raises(UsageError, match=problem):
            make_partner(wrong, "bait")
    with pytest.raises(ValueError, match="share a role"):
        HumanLike(networks.load("B5"), networks.load("S5"))
