"""A lockstep adaptive match is paced by frames, never by the clock (issue 59). On a real bus the
adapter rules on every scoring frame and the adaptive seat answers the state after one only once
it has that frame's ruling, so the match is the same on every run (its states, the adapter's
statuses and rulings), and its switch plays from the frame the in-process evaluation gives."""

from __future__ import annotations

import dataclasses
import time

from services.adapter.core import initial_policy
from services.adapter.service import run_adapter
from services.agent.gate import RULING_WAIT
from services.agent.service import run_agent
from services.evaluation.evaluate import play_games
from services.population.adaptive import AdapterConfig
from services.population.seat import AdaptiveSeat, PolicySeat
from services.sim.service import run_sim
from shared import keys
from shared.game import GameConfig, ruled_at, scoring
from shared.messages import Action, AdapterStatus, Ruling, State

PARTNER, SEED, FRAMES = "B3", 4, 150
# Decides on the warm-up's last frame, 99, which is no scoring frame: the ruling on frame 101 plays
# the switch from frame 102 (a per-frame switch would play from 100, a late one later).
CONFIG = AdapterConfig("shooter", window=100, strategy="cem", seed=SEED)


def adaptive_match(bus, tap, background, wait_until, listener, match: str) -> dict:  # noqa: ANN001 - fixtures
    """Play one lockstep adaptive match on the bus; what must be the same on every run."""
    recorded = tap(listener, match)
    adapter = background(run_adapter, bus.config(), match, CONFIG)
    agents = [
        background(run_agent, bus.config(), match, "bait", PARTNER, SEED),
        background(run_agent, bus.config(), match, "shooter", initial_policy(CONFIG), SEED, adaptive=True),
    ]
    assert wait_until(lambda: recorded.is_alive("adapter"), timeout=20)
    policies = {"bait": PARTNER, "shooter": CONFIG.name}
    sim = background(run_sim, bus.config(), match, SEED, GameConfig(frames=FRAMES), "lockstep", policies,
                     wait_adapter=10)  # fmt: skip
    assert sim.result(timeout=120).frame == FRAMES
    assert adapter.result(timeout=10).total == 0
    for agent in agents:
        assert agent.result(timeout=10).total == 0
    shooter = sorted(recorded.of(Action, keys.action(match, "shooter")), key=lambda a: a.frame)
    return {
        "states": sorted((s.frame, s.hash) for s in recorded.of(State)),
        "adapter": sorted(
            (s.frame, repr(dataclasses.replace(s, match=""))) for s in recorded.of(AdapterStatus)
        ),
        "rulings": sorted((r.frame, r.policy, r.partner) for r in recorded.of(Ruling)),
        "plays": [(a.frame, a.policy) for a in shooter],
    }


def test_a_lockstep_adaptive_match_is_the_same_on_every_run_and_switches_as_evaluated(
    bus, tap, background, wait_until
) -> None:
    listener = bus.open(listen=True)
    first, second = (adaptive_match(bus, tap, background, wait_until, listener, m) for m in ("one", "two"))
    assert first == second
    assert len(first["states"]) == FRAMES + 1 and first["adapter"]
    assert [f for f, *_ in first["rulings"]] == [f for f in range(FRAMES - 1) if scoring(f)]  # none on 149
    switched = next(f for f, policy in first["plays"] if policy != initial_policy(CONFIG))
    evaluated = play_games(
        [(PolicySeat(PARTNER), AdaptiveSeat(CONFIG), SEED)], "shooter", GameConfig(frames=FRAMES)
    )
    assert switched == evaluated[0].timeline[0][0] == ruled_at(99) + 1 == 102


def test_a_lockstep_match_without_its_adapter_waits_once_and_plays_on(bus, tap, background) -> None:
    """No adapter rules: the adaptive seat waits RULING_WAIT once, then answers at once until a
    ruling comes; the match plays to its end with the initial policy."""
    recorded = tap(bus.open(listen=True), "alone")
    agents = [
        background(run_agent, bus.config(), "alone", "bait", PARTNER, SEED),
        background(run_agent, bus.config(), "alone", "shooter", initial_policy(CONFIG), SEED, adaptive=True),
    ]
    began = time.monotonic()
    policies = {"bait": PARTNER, "shooter": CONFIG.name}
    sim = background(run_sim, bus.config(), "alone", SEED, GameConfig(frames=FRAMES), "lockstep", policies)
    summary = sim.result(timeout=60)
    assert summary.frame == FRAMES and summary.drops == {}
    assert RULING_WAIT <= time.monotonic() - began < 10 * RULING_WAIT
    assert {a.policy for a in recorded.of(Action, keys.action("alone", "shooter"))} == {
        initial_policy(CONFIG)
    }
    for agent in agents:
        assert agent.result(timeout=10).total == 0
