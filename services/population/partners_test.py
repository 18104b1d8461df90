"""Partners: the name grammar, that each wrapper changes play as it says, and that a game's
partner is the same whether it plays alone or among many lanes."""

from __future__ import annotations

import re

import numpy as np
import pytest

from services.population.human_like import HumanLike
from services.population.partners import (
    EachLane,
    HumanLanes,
    OneGame,
    Partner,
    Partners,
    PolicyLanes,
    kind_of,
    make_partner,
    population,
)
from services.population.seat import SeatSpec, seats_of
from services.population.wrappers import DELAY, SWITCH_AT, Delayed, Noisy, Sticky, Switching
from services.sim.batch import BatchGame
from services.sim.observation import observe
from services.sim.play import policy_seed
from shared.errors import UsageError
from shared.game import N_ACTIONS, GameConfig

HERE = "services.population.partners_test"
COUNTING, CONSTANT = f"{HERE}:Counting", f"{HERE}:Constant"


class Counting:
    """A partner whose action is the first observation value: shows which observation it acted on."""

    key, role, view = "counting", "bait", "world"

    def reset(self, seed: int | None = None) -> None:
        pass

    def act(self, obs: np.ndarray) -> int:
        return int(obs[0]) % N_ACTIONS


class Constant(Counting):
    key = "constant"

    def act(self, obs: np.ndarray) -> int:
        return 5


def played(name: str, lanes: int, frames: int, first: float = 0.0) -> np.ndarray:
    """(frames, lanes) actions of `name` in lanes of game seeds 0..lanes-1; frame t's observations
    are t + first everywhere (Counting acts on them)."""
    partners = Partners([SeatSpec.parse(name)] * lanes, "bait", np.arange(lanes))
    rows = [
        partners.act(lambda view, t=t: np.full((lanes, 64), t + first, np.float32), t) for t in range(frames)
    ]
    return np.array(rows)


def test_names_build_nested_partners() -> None:
    partner = make_partner("noisy(switch(B1,delayed(B5)))", "bait")
    assert isinstance(partner, OneGame) and partner.key == "noisy(switch(B1,delayed(B5)))"
    noisy = partner.form
    assert isinstance(noisy, Noisy) and isinstance(noisy.inner, Switching)
    assert isinstance(noisy.inner.first, PolicyLanes) and isinstance(noisy.inner.second, Delayed)
    assert noisy.inner.second.delay == DELAY
    assert isinstance(make_partner("sticky(mirror)", "shooter").form, Sticky)
    with pytest.raises(ValueError, match="plays"):
        make_partner("S1", "bait")
    with pytest.raises(ValueError, match="two partners"):
        make_partner("switch(B1)", "bait")


def test_external_partners_by_module_path() -> None:
    partner = make_partner(CONSTANT, "bait")
    assert isinstance(partner, Partner) and partner.act(np.zeros(64)) == 5
    with pytest.raises(ValueError, match="plays bait"):
        make_partner(CONSTANT, "shooter")


def test_noisy_slips_at_its_rate_and_is_seeded() -> None:
    actions = played(f"noisy({CONSTANT})", 400, 50)
    assert abs(np.mean(actions != 5) - 0.1 * 11 / 12) < 0.01  # a slip lands on the same action 1 time in 12
    assert set(np.unique(actions)) == set(range(N_ACTIONS))
    assert (played(f"noisy({CONSTANT})", 400, 50) == actions).all()


def test_delayed_acts_on_the_state_of_delay_frames_ago() -> None:
    actions = played(f"delayed({COUNTING})", 3, 20)
    assert (actions[: DELAY + 1] == 0).all()
    late = np.arange(DELAY + 1, 20)[:, None]
    assert (actions[DELAY + 1 :] == (late - DELAY) % N_ACTIONS).all()
    two = make_partner("delayed(B5,frames=2)", "bait")
    assert (two.form.delay, two.key) == (2, "delayed(B5,frames=2)")
    with pytest.raises(UsageError, match="frames=N"):
        make_partner("delayed(B5,frames=-1)", "bait")


def test_sticky_repeats_its_last_action() -> None:
    actions = played(f"sticky({COUNTING})", 50, 400)
    fresh = np.arange(400)[:, None] % N_ACTIONS
    assert 0.45 < np.mean(actions[1:] == actions[:-1]) < 0.56
    assert np.all((actions == fresh) | (actions == np.vstack([np.zeros((1, 50), int), actions[:-1]])))


def test_switching_changes_policy_at_its_frame() -> None:
    actions = played(f"switch({COUNTING},{CONSTANT})", 2, SWITCH_AT + 10, first=1.0)
    assert (actions[:SWITCH_AT] == (np.arange(SWITCH_AT)[:, None] + 1) % N_ACTIONS).all()
    assert (actions[SWITCH_AT:] == 5).all()
    with pytest.raises(UsageError, match="same observation view"):
        make_partner("switch(human(B1),B5)", "bait")


def test_forms_follow_the_partner_and_plug_ins_are_played_as_they_are() -> None:
    names = ["noisy(switch(B1,B5))", "noisy(switch(B7,B2))", "noisy(B1)", "switch(B1,B5)", "noisy(B2)"]
    groups = Partners(list(seats_of(names)), "bait", np.arange(5)).groups
    assert [len(rows) for rows, _ in groups] == [2, 2, 1]
    ((_, plug_in),) = Partners(list(seats_of([CONSTANT] * 2)), "bait", np.arange(2)).groups
    assert isinstance(plug_in, EachLane) and plug_in.copies[0] is not plug_in.copies[1]
    ((_, hand),) = Partners(list(seats_of(["human(B1,B5)"] * 2)), "bait", np.arange(2)).groups
    assert isinstance(hand, HumanLanes)
    ((_, on_a_wrapper),) = Partners(list(seats_of(["human(noisy(B4))"] * 2)), "bait", np.arange(2)).groups
    assert isinstance(on_a_wrapper, EachLane)


MIXED = [
    "noisy(B5)",
    "sticky(switch(B1,B5))",
    "delayed(circle(radius=150),frames=2)",
    "human(B1,B5)",
    "human(noisy(B4),skill=novice)",
    "switch(circle,human(B3))",
    f"noisy({CONSTANT})",
    "noisy(B5)",
]


def test_a_partner_acts_the_same_in_a_single_game_as_among_many_lanes() -> None:
    """The same partner spec played as a single game (`make_partner`: one lane of its batched
    form, what a stand-in and a recorded trial play) and among other partners' lanes
    (`Partners`, an evaluation's batch) gives the same actions, exactly: every draw is its game's,
    keyed by seed and frame. The lanes see the states of real games (the batched engine, the
    partners under test in the bait seat), past the switches' frame."""
    keys, frames = np.arange(20, 20 + len(MIXED)), SWITCH_AT + 30
    game = BatchGame(len(MIXED), GameConfig(frames=frames), keys)
    together, shooters = (
        Partners(list(seats_of(MIXED)), "bait", keys),
        Partners(list(seats_of(["S5"] * len(MIXED))), "shooter", keys),
    )
    singles = [make_partner(name, "bait") for name in MIXED]
    for partner, key in zip(singles, keys.tolist(), strict=True):
        partner.reset(policy_seed(key, "bait"))
    assert isinstance(singles[0], OneGame) and isinstance(singles[3], HumanLike)
    many, one = [], []
    for t in range(frames):
        seen = {view: observe(game, "bait", view) for view in ("world", "role")}
        many.append(together.act(seen.get, t))
        one.append([partner.act(seen[partner.view][i]) for i, partner in enumerate(singles)])
        game.step(many[-1], shooters.act(lambda view: observe(game, "shooter", view), t))
    assert (np.array(many) == np.array(one)).all()
    assert (np.array(many)[:, 0] != np.array(many)[:, 7]).any()  # two games of noisy(B5): two seeds


def test_population_covers_every_kind() -> None:
    kinds = population("bait")
    assert set(kinds) == {"library", "noisy", "delayed", "sticky", "switching", "human-like", "outside"}
    assert len(kinds["library"]) == 9 and len(kinds["switching"]) == 9 and len(kinds["outside"]) == 6
    for names in kinds.values():
        for name in names:
            assert make_partner(name, "bait").role == "bait"


def test_a_scripted_rule_with_other_settings_plays_them_under_its_own_name() -> None:
    name = "circle(radius=150,speed=3)"
    partner = make_partner(name, "bait")
    assert (partner.key, partner.radius, partner.speed, partner.outside) == (name, 150.0, 3.0, 235.0)
    assert kind_of(name) == "outside"
    for bad, problem in (
        ("circle(size=3)", "'size=3' is not SETTING=NUMBER for a setting of circle; valid: radius, speed"),
        ("circle(radius=wide)", "'radius=wide' is not SETTING=NUMBER"),
        ("mirror(radius=200)", "mirror plays the shooter seat, not the bait seat"),
    ):
        with pytest.raises(UsageError, match=re.escape(f"--partner {bad}: {problem}")):
            make_partner(bad, "bait")
