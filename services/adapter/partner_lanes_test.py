"""Partners in bulk: each batched wrapper does what its scalar form does, lane by lane; plug-ins
are played as they are; a lane's partner depends on its game's seed, not on its batch."""

from __future__ import annotations

import itertools

import numpy as np

from services.adapter.partner_lanes import EachLane, HumanLanes, Partners, PolicyLanes, lanes
from services.adapter.partners import SWITCH_AT, Delayed, Noisy, Sticky, Switching, make_partner
from services.adapter.partners_test import Constant, Counting
from services.sim.play import policy_seed
from shared.game import N_ACTIONS


def batched(partner, keys: list[int]):
    out = lanes([partner] * len(keys), 0, itertools.count(2))
    out.reset(np.array(keys))
    return out


def counting_frames(n: int, lanes_: int = 3) -> list[np.ndarray]:
    """Frame t's observations: lane i sees t + 100 i everywhere (Counting acts on it)."""
    return [np.stack([np.full(64, float(t + 100 * i)) for i in range(lanes_)]) for t in range(n)]


def test_forms_follow_the_partner_and_plug_ins_are_played_as_they_are() -> None:
    partner = batched(make_partner("noisy(switch(B1,delayed(B5)))", "bait"), [0])
    assert type(partner).__name__ == "NoisyLanes" and type(partner.inner).__name__ == "SwitchLanes"
    assert isinstance(partner.inner.first, PolicyLanes) and partner.inner.second.delay == 6
    names = ["noisy(switch(B1,B5))", "noisy(switch(B7,B2))", "noisy(B1)", "switch(B1,B5)", "noisy(B2)"]
    assert [len(rows) for rows, _ in Partners(names, "bait", np.arange(5)).groups] == [2, 2, 1]
    plug_in = batched(make_partner("services.adapter.partners_test:Constant", "bait"), [0, 1])
    assert isinstance(plug_in, EachLane) and len(plug_in.copies) == 2
    assert plug_in.copies[0] is not plug_in.copies[1]


def test_delayed_and_switching_lanes_act_as_the_scalar_partners_exactly() -> None:
    for make in (lambda: Delayed(Counting()), lambda: Switching(Counting(), Constant())):
        scalar = [make() for _ in range(3)]
        for p in scalar:
            p.reset(0)
        frames = counting_frames(SWITCH_AT + 20)
        lanes_ = batched(make(), [0, 1, 2])
        for t, obs in enumerate(frames):
            expected = [p.act(row) for p, row in zip(scalar, obs, strict=True)]
            assert lanes_.act(obs, t).tolist() == expected, t


def test_noisy_and_sticky_lanes_change_actions_at_their_rates() -> None:
    keys = list(range(400))
    noisy = batched(Noisy(Constant()), keys)
    actions = np.stack([noisy.act(np.zeros((400, 64), np.float32), t) for t in range(50)])
    assert abs(np.mean(actions != 5) - 0.1 * 11 / 12) < 0.01
    assert set(np.unique(actions)) == set(range(N_ACTIONS))
    sticky = batched(Sticky(Counting()), keys[:50])
    frames = counting_frames(400, 50)
    played = np.stack([sticky.act(obs, t) for t, obs in enumerate(frames)])
    fresh = np.stack([obs[:, 0].astype(int) % N_ACTIONS for obs in frames])
    assert 0.45 < np.mean(played[1:] == played[:-1]) < 0.56
    assert np.all((played == fresh) | (played == np.vstack([np.zeros((1, 50), int), played[:-1]])))


def test_a_lanes_partner_depends_on_its_seed_not_its_batch() -> None:
    names = ["noisy(B5)", "sticky(switch(B1,B5))", "noisy(B5)", "delayed(circle)"]
    rng = np.random.default_rng(0)
    frames = [rng.normal(size=(4, 64)).astype(np.float32) for _ in range(30)]
    together = Partners(names, "bait", np.array([3, 4, 5, 6]))
    alone = Partners(names[2:3], "bait", np.array([5]))
    for t, obs in enumerate(frames):
        both = together.act(lambda view, obs=obs: obs, t)
        assert both[2] == alone.act(lambda view, obs=obs: obs[2:3], t)[0]


def test_human_like_lanes_act_as_the_scalar_partners_of_the_same_games() -> None:
    """human(...) of project policies plays HumanLike.act_lanes, reset as the scalar game resets
    its partner (policy_seed), so every lane acts as that game's partner; on a wrapper it is
    played lane by lane."""
    keys, rng = [3, 4, 5], np.random.default_rng(1)
    together = batched(make_partner("human(B1,B5)", "bait"), keys)
    assert isinstance(together, HumanLanes)
    assert isinstance(batched(make_partner("human(noisy(B4))", "bait"), keys), EachLane)
    alone = [make_partner("human(B1,B5)", "bait") for _ in keys]
    for partner, key in zip(alone, keys, strict=True):
        partner.reset(policy_seed(key, "bait"))
    for t in range(120):
        obs = rng.normal(size=(3, 64)).astype(np.float32)
        assert together.act(obs, t).tolist() == [p.act(row) for p, row in zip(alone, obs, strict=True)], t
