"""The agent service alone on a real bus: the test plays the sim, publishing states of a real game."""

from __future__ import annotations

import time
from collections import Counter

import msgpack
import pytest
import zenoh

from services.agent.seats import policy_for
from services.agent.service import run_agent
from services.sim.engine import Game
from services.sim.match import state_message, summary_message
from services.sim.observation import observe
from services.sim.play import policy_seed
from shared import keys
from shared.game import ROLES, GameConfig
from shared.messages import Action, PolicySwitch, Summary

MATCH, SEED, FRAMES = "agent", 5, 30
BLOCK = {"congestion_control": zenoh.CongestionControl.BLOCK}


class FakeSim:
    """Publishes the states of a real game to one agent and steps it with the agent's answers."""

    def __init__(self, z, recorded, role: str) -> None:  # noqa: ANN001 - a session and a Tap
        self.z, self.recorded, self.role = z, recorded, role
        self.game = Game(GameConfig(frames=FRAMES), SEED)
        self.applied = (0, 0)

    def put(self, key: str, data: bytes) -> None:
        self.z.put(key, data, **BLOCK)

    def step(self, wait_until) -> Action:  # noqa: ANN001 - the poll helper
        """Publish the current state, wait for the agent's action to it and step the game with it."""
        frame = self.game.frame
        self.put(keys.state(MATCH), state_message(self.game, MATCH, "sim", self.applied).encode())
        assert wait_until(lambda: any(a.frame == frame for a in self.actions()), timeout=2), frame
        action = next(a for a in self.actions() if a.frame == frame)
        self.applied = tuple(action.action if r == self.role else 0 for r in ROLES)
        self.game.step(*self.applied)
        return action

    def actions(self) -> list[Action]:
        return self.recorded.of(Action, keys.action(MATCH, self.role))

    def end(self, wait_until, agent) -> Counter:  # noqa: ANN001
        """Publish the summary; the agent must leave (thread and token) and answer nothing more."""
        self.put(keys.summary(MATCH), summary_message(self.game, MATCH, "sim", {}, {}).encode())
        drops = agent.result(timeout=5)
        assert wait_until(lambda: not self.recorded.is_alive("agent", self.role))
        return drops.counts


@pytest.fixture
def seat(bus, tap, background, wait_until):
    """seat(role, policy) -> a FakeSim for run_agent, started in a thread once its token is seen."""
    z = bus.open(listen=True)

    def make(role: str, policy: str) -> tuple[FakeSim, object]:
        recorded = tap(z, MATCH)
        agent = background(run_agent, bus.config(), MATCH, role, policy, SEED)
        assert wait_until(lambda: recorded.is_alive("agent", role)), "the agent declares its token"
        return FakeSim(z, recorded, role), agent

    return make


@pytest.mark.parametrize(("role", "policy"), [("bait", "circle"), ("shooter", "mirror")])
def test_one_action_per_state_as_the_policy_plays_it(seat, wait_until, role, policy):
    sim, agent = seat(role, policy)
    reference = policy_for(policy, role)
    reference.reset(policy_seed(SEED, role))
    for _ in range(FRAMES):
        expected = reference.act(observe(sim.game, role, reference.view))
        action = sim.step(wait_until)
        assert (action.match, action.role, action.policy, action.action) == (MATCH, role, policy, expected)
    assert sim.end(wait_until, agent) == Counter()
    assert [a.frame for a in sim.actions()] == list(range(FRAMES))


def test_a_policy_switch_applies_from_the_next_state(seat, wait_until):
    sim, agent = seat("shooter", "mirror")
    for _ in range(10):
        sim.step(wait_until)
    switch = PolicySwitch(
        match=MATCH, frame=9, sender="adapter", role="shooter", policy="idle", reason="test"
    )
    sim.put(keys.policy(MATCH, "shooter"), switch.encode())
    # zenoh-python runs each subscriber's callbacks in a thread of its own, so the agent orders a
    # switch and a state only by when it handles them: the switch is given a moment, as between frames.
    time.sleep(0.05)
    for _ in range(10):
        sim.step(wait_until)
    assert [a.policy for a in sim.actions()] == ["mirror"] * 10 + ["idle"] * 10
    assert sim.end(wait_until, agent) == Counter()


def test_bad_input_is_counted_and_the_agent_keeps_playing(seat, wait_until):
    sim, agent = seat("bait", "circle")
    policy_key, reasons = keys.policy(MATCH, "bait"), Counter()
    bad = [
        (keys.state(MATCH), b"\xc1 not msgpack", "undecodable"),
        (keys.state(MATCH), msgpack.packb({"v": 1, "type": "state", "match": MATCH}), "shape"),
        (keys.state(MATCH), Action(match=MATCH, frame=3, sender="x").encode(), "type"),
        (keys.summary(MATCH), b"\xc1", "undecodable"),
        (keys.summary(MATCH), Summary(match=MATCH, frame=3, sender="sim", kills=-1).encode(), "range"),
        (policy_key, msgpack.packb("idle"), "shape"),
        (
            policy_key,
            PolicySwitch(match=MATCH, frame=3, sender="x", role="shooter", policy="idle").encode(),
            "mismatch",
        ),
        (
            policy_key,
            PolicySwitch(match=MATCH, frame=3, sender="x", role="bait", policy="no-such-policy").encode(),
            "policy",
        ),
    ]
    for frame in range(6):
        for key, data, reason in bad if frame % 2 else []:
            sim.put(key, data)
            reasons[reason] += 1
        sim.step(wait_until)
    assert all(a.policy == "circle" for a in sim.actions())
    assert sim.end(wait_until, agent) == reasons
    assert [a.frame for a in sim.actions()] == list(range(6))
