"""The adapter service on a real bus: it switches the agent to the best response to a library
partner, never averages malformed partner actions into its window, and dying mid-match leaves the
match and the agent's policy intact; a restarted adapter rebuilds its window from live frames."""

from __future__ import annotations

import signal

import msgpack
import numpy as np
import pytest
import zenoh

from services.adapter.core import Scorer
from services.adapter.service import run_adapter
from services.agent import library, networks
from services.agent.service import run_agent
from services.population.adaptive import AdapterConfig
from services.sim.engine import Game
from services.sim.match import state_message
from services.sim.observation import observe
from services.sim.play import policy_seed
from services.sim.service import run_sim
from services.table.table import DEFAULT_TABLE, Table
from shared import keys
from shared.game import SCORE_FRAMES, GameConfig
from shared.messages import Action, AdapterStatus, PolicySwitch, State, Summary

BLOCK = {"congestion_control": zenoh.CongestionControl.BLOCK}
BEST_FOR_B3 = Table.load(DEFAULT_TABLE).best_shooter("B3")
FED = 6 * SCORE_FRAMES  # frames fed by hand: the last is a scoring frame, so all are scored and reported


def test_adapter_switches_the_agent_to_the_best_response(bus, tap, background, wait_until) -> None:
    match = "adapt"
    recorded = tap(bus.open(listen=True), match)
    config = AdapterConfig("shooter", window=100, strategy="cem")
    adapter = background(run_adapter, bus.config(), match, config)
    assert wait_until(lambda: recorded.is_alive("adapter"), timeout=10)
    agents = [
        background(run_agent, bus.config(), match, r, p, 7) for r, p in (("bait", "B3"), ("shooter", "S5"))
    ]
    sim = background(
        run_sim,
        bus.config(),
        match,
        7,
        GameConfig(frames=400),
        "lockstep",
        {"bait": "B3", "shooter": "adaptive"},
    )
    summary = sim.result(timeout=60)
    assert summary.frame == 400
    switches = recorded.of(PolicySwitch, keys.policy(match, "shooter"))
    assert switches and switches[0].policy == BEST_FOR_B3 and switches[0].sender == "adapter"
    assert "B3" in switches[0].reason
    assert wait_until(
        lambda: any(a.policy == BEST_FOR_B3 for a in recorded.of(Action, keys.action(match, "shooter")))
    )
    statuses = recorded.of(AdapterStatus, keys.adapter(match))
    assert statuses[-1].partner == "B3" and statuses[-1].policy == BEST_FOR_B3
    assert set(statuses[-1].scores) == set(library.keys("bait"))
    assert max(statuses[-1].scores, key=statuses[-1].scores.get) == "B3"
    assert adapter.result(timeout=5).total == 0
    for agent in agents:
        agent.result(timeout=5)


def test_malformed_partner_actions_are_dropped_and_never_averaged(bus, tap, background, wait_until) -> None:
    match = "adapt-bad"
    z = bus.open(listen=True)
    recorded = tap(z, match)
    # no switching: only the window is watched
    config = AdapterConfig("shooter", window=50, strategy="cem", warmup=1000)
    adapter = background(run_adapter, bus.config(), match, config)
    assert wait_until(lambda: recorded.is_alive("adapter"), timeout=10)
    game, partner = Game(GameConfig(frames=60), 2), networks.load("B5")
    partner.reset(policy_seed(2, "bait"))
    bait_key = keys.action(match, "bait")
    valid: list[tuple[list[float], int]] = []
    for frame in range(FED):
        state = state_message(game, match, "sim", (0, 0))
        z.put(keys.state(match), state.encode(), **BLOCK)
        action = partner.act(observe(game, "bait", partner.view))
        bad = [
            b"\xc1 not msgpack",
            Action(
                match=match, frame=frame, sender="agent/shooter", role="shooter", action=3, policy="S5"
            ).encode(),  # wrong seat for the key
            msgpack.packb(
                {
                    **_record(
                        Action(match=match, frame=frame, sender="human", role="bait", action=0, policy="")
                    ),
                    "action": 99,
                }
            ),
            Action(
                match="other", frame=frame, sender="agent/bait", role="bait", action=1, policy="B5"
            ).encode(),  # another match
        ]
        for data in bad if frame % 4 == 0 else []:
            z.put(bait_key, data, **BLOCK)
        z.put(
            bait_key,
            Action(
                match=match, frame=frame, sender="agent/bait", role="bait", action=action, policy="B5"
            ).encode(),
            **BLOCK,
        )
        valid.append((state.obs["bait"], action))
        game.step(action, 0)
    assert wait_until(
        lambda: any(s.filled == FED for s in recorded.of(AdapterStatus, keys.adapter(match))), timeout=10
    ), [s.filled for s in recorded.of(AdapterStatus)]
    z.put(keys.summary(match), b"not a summary")  # also dropped; then a real summary ends it
    z.put(keys.summary(match), _summary(game, match), **BLOCK)
    drops = adapter.result(timeout=5)
    bad = len(range(0, FED, 4))  # frames with bad actions
    counts = drops.counts
    assert counts["undecodable"] >= bad + 1 and (counts["mismatch"], counts["range"]) == (2 * bad, bad)
    last = [s for s in recorded.of(AdapterStatus, keys.adapter(match)) if s.filled == FED][-1]
    scorer = Scorer([networks.load(k) for k in library.keys("bait")])
    expected = np.mean([scorer(v, a) for v, a in valid], axis=0)
    np.testing.assert_allclose([last.scores[k] for k in scorer.keys], expected, rtol=1e-9)


@pytest.mark.long
@pytest.mark.slow
def test_killing_the_adapter_leaves_the_match_and_the_agent_intact(bus, tap, spawn, wait_until) -> None:
    match = "adapt-kill"
    recorded = tap(bus.open(listen=True), match)
    config = AdapterConfig("shooter", window=60, strategy="cem")
    first = spawn("adapter", bus.config(), "--match", match, *config.to_args())
    assert wait_until(lambda: recorded.is_alive("adapter"), timeout=20)
    spawn("agent", bus.config(), "--match", match, "--role", "bait", "--policy", "B3")
    spawn("agent", bus.config(), "--match", match, "--role", "shooter", "--policy", "S5")
    sim = spawn("sim", bus.config(), "--match", match, "--frames", "420", "--wait-adapter", "10")
    assert wait_until(lambda: recorded.of(PolicySwitch), timeout=20)
    first.send_signal(signal.SIGKILL)
    first.wait()
    assert wait_until(lambda: not recorded.is_alive("adapter"), timeout=10)
    killed_at = recorded.of(State)[-1].frame
    second = spawn("adapter", bus.config(), "--match", match, *config.to_args())
    assert wait_until(lambda: recorded.of(Summary), timeout=30)
    assert sim.wait(10) == 0
    states = recorded.of(State)
    assert states[-1].frame == 420 and len({s.frame for s in states}) > 400  # the match went on
    later = [a for a in recorded.of(Action, keys.action(match, "shooter")) if a.frame > killed_at]
    assert later and all(a.policy == BEST_FOR_B3 for a in later)  # the agent kept its policy
    rebuilt = [s for s in recorded.of(AdapterStatus) if s.frame > killed_at]
    assert rebuilt and rebuilt[0].filled < rebuilt[0].frame - killed_at + 5  # a new window from live frames
    assert max(s.filled for s in rebuilt) == 60
    assert second.wait(10) == 0


def _record(message: Action) -> dict:
    return msgpack.unpackb(message.encode(), raw=False)


def _summary(game: Game, match: str) -> bytes:
    from services.sim.match import summary_message

    return summary_message(game, match, "sim", {}, {}).encode()
