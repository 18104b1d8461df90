"""Partner stand-ins: the name grammar, and that each wrapper changes play as it says."""

from __future__ import annotations

import re

import numpy as np
import pytest

from services.adapter.partners import (
    DELAY,
    SWITCH_AT,
    Delayed,
    Noisy,
    Partner,
    Sticky,
    Switching,
    group_of,
    make_partner,
    population,
)
from shared.errors import UsageError
from shared.game import N_ACTIONS


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


def observations(n: int) -> list[np.ndarray]:
    return [np.full(64, float(t)) for t in range(n)]


def test_names_build_nested_partners() -> None:
    partner = make_partner("noisy(switch(B1,delayed(B5)))", "bait")
    assert isinstance(partner, Noisy) and isinstance(partner.inner, Switching)
    assert partner.key == "noisy(switch(B1,delayed(B5)))"
    assert isinstance(make_partner("sticky(mirror)", "shooter"), Sticky)
    with pytest.raises(ValueError, match="plays"):
        make_partner("S1", "bait")
    with pytest.raises(ValueError, match="two partners"):
        make_partner("switch(B1)", "bait")


def test_external_partners_by_module_path() -> None:
    partner = make_partner("services.adapter.partners_test:Constant", "bait")
    assert isinstance(partner, Partner) and partner.act(np.zeros(64)) == 5
    with pytest.raises(ValueError, match="plays bait"):
        make_partner("services.adapter.partners_test:Constant", "shooter")


def test_noisy_slips_at_its_rate_and_is_seeded() -> None:
    partner = Noisy(Constant())
    partner.reset(3)
    actions = [partner.act(np.zeros(64)) for _ in range(20_000)]
    slipped = np.mean([a != 5 for a in actions])
    assert abs(slipped - 0.1 * 11 / 12) < 0.01  # a slip lands on the same action 1 time in 12
    partner.reset(3)
    assert [partner.act(np.zeros(64)) for _ in range(100)] == actions[:100]


def test_delayed_acts_on_the_state_of_delay_frames_ago() -> None:
    partner = Delayed(Counting())
    partner.reset(0)
    actions = [partner.act(obs) for obs in observations(20)]
    assert actions[: DELAY + 1] == [0] * (DELAY + 1)
    assert actions[DELAY + 1 :] == [(t - DELAY) % N_ACTIONS for t in range(DELAY + 1, 20)]
    two = make_partner("delayed(B5,frames=2)", "bait")
    assert (two.delay, two.key) == (2, "delayed(B5,frames=2)")
    assert make_partner("delayed(B5,frames=6)", "bait").key == "delayed(B5)"
    with pytest.raises(UsageError, match="frames=N"):
        make_partner("delayed(B5,frames=-1)", "bait")


def test_sticky_repeats_its_last_action() -> None:
    partner = Sticky(Counting())
    partner.reset(1)
    actions = [partner.act(obs) for obs in observations(2000)]
    repeated = np.mean([a == b for a, b in zip(actions, actions[1:], strict=False)])
    assert 0.45 < repeated < 0.56


def test_switching_changes_policy_at_its_frame() -> None:
    partner = Switching(Counting(), Constant())
    partner.reset(0)
    actions = [partner.act(np.full(64, 1.0)) for _ in range(SWITCH_AT + 10)]
    assert set(actions[:SWITCH_AT]) == {1} and set(actions[SWITCH_AT:]) == {5}


def test_population_covers_every_group() -> None:
    groups = population("bait")
    assert set(groups) == {"library", "noisy", "delayed", "sticky", "switching", "human-like", "outside"}
    assert len(groups["library"]) == 9 and len(groups["switching"]) == 9 and len(groups["outside"]) == 6
    for names in groups.values():
        for name in names:
            assert make_partner(name, "bait").role == "bait"


def test_a_scripted_rule_with_other_settings_plays_them_under_its_own_name() -> None:
    name = "circle(radius=150,speed=3)"
    partner = make_partner(name, "bait")
    assert (partner.key, partner.radius, partner.speed, partner.outside) == (name, 150.0, 3.0, 235.0)
    assert group_of(name) == "outside"
    for bad, problem in (
        ("circle(size=3)", "'size=3' is not SETTING=NUMBER for a setting of circle; valid: radius, speed"),
        ("circle(radius=wide)", "'radius=wide' is not SETTING=NUMBER"),
        ("mirror(radius=200)", "mirror plays the shooter seat, not the bait seat"),
    ):
        with pytest.raises(UsageError, match=re.escape(f"--partner {bad}: {problem}")):
            make_partner(bad, "bait")
