"""The agent and adapter services in pool mode on a real bus: many matches from a pool's orders,
each seat played as the single-match service plays it, every part of a match gone when it ends."""

from __future__ import annotations

import signal
from collections import Counter

import pytest
import zenoh

from services.adapter.core import initial_policy
from services.adapter.service import run_adapter_pool
from services.agent.seats import policy_for
from services.agent.service import run_agent_pool
from services.population.adaptive import AdapterConfig
from services.sim.engine import Game
from services.sim.match import state_message, summary_message
from services.sim.observation import observe
from services.sim.play import policy_seed
from services.sim.service import run_sim
from services.table.table import DEFAULT_TABLE, Table
from shared import keys
from shared.bus import Drops, serve_orders, session
from shared.game import ROLES, GameConfig
from shared.messages import Action, AdapterStatus, MatchOrder, MatchRefused, PolicySwitch, Summary, decode

POOL, FRAMES = "pool", 12
BLOCK = {"congestion_control": zenoh.CongestionControl.BLOCK}
NAMES = {"bait": "B3", "shooter": "S5"}


def order(match: str, seed: int, **fields: object) -> MatchOrder:
    return MatchOrder(match=match, frame=0, sender="launcher", seed=seed, names=NAMES, **fields)


def pool_alive(z: zenoh.Session, service: str) -> bool:
    return any(
        reply.ok is not None for reply in z.liveliness().get(keys.pool_alive(POOL, service), timeout=1)
    )


class Played:
    """One match's sim side, without a sim: publishes the states of a real game one at a time and
    waits for each seat's answer."""

    def __init__(self, z: zenoh.Session, recorded, match: str, seed: int) -> None:  # noqa: ANN001 - a Tap
        self.z, self.recorded, self.match = z, recorded, match
        self.game = Game(GameConfig(frames=FRAMES), seed)

    def actions(self, role: str) -> list[Action]:
        return self.recorded.of(Action, keys.action(self.match, role))

    def step(self, roles: tuple[str, ...], wait_until) -> None:  # noqa: ANN001 - the poll helper
        frame = self.game.frame
        self.z.put(
            keys.state(self.match), state_message(self.game, self.match, "sim", (0, 0)).encode(), **BLOCK
        )
        for role in roles:
            assert wait_until(lambda r=role: any(a.frame == frame for a in self.actions(r)), timeout=3), (
                role,
                frame,
            )
        self.game.step(0, 0)

    def end(self) -> None:
        self.z.put(
            keys.summary(self.match), summary_message(self.game, self.match, "sim", {}, {}).encode(), **BLOCK
        )


def expected(role: str, policy: str, seed: int, frames: int) -> list[int]:
    """What the policy plays in `role`'s seat of a game of `seed` whose seats play no-op."""
    game, reference = Game(GameConfig(frames=FRAMES), seed), policy_for(policy, role)
    reference.reset(policy_seed(seed, role))
    answers = []
    for _ in range(frames):
        answers.append(reference.act(observe(game, role, reference.view)))
        game.step(0, 0)
    return answers


@pytest.fixture
def agents(bus, background, wait_until):
    """The test's session (the pool's router stands in for it) and an agent pool on it."""
    z = bus.open(listen=True)
    pool = background(run_agent_pool, bus.config(), POOL)
    assert wait_until(lambda: pool_alive(z, "agent"), timeout=10), "the pool declares its token"
    return z, pool


def test_the_pool_plays_each_ordered_seat_as_a_single_agent_does(agents, tap, wait_until) -> None:
    z, pool = agents
    both, shooter_only = tap(z, "both"), tap(z, "person")
    z.put(keys.pool_order(POOL), order("both", 3, bait="B3", shooter="S1").encode(), **BLOCK)
    z.put(keys.pool_order(POOL), order("person", 4, shooter="S1").encode(), **BLOCK)
    assert wait_until(
        lambda: all(both.is_alive("agent", r) for r in ROLES) and shooter_only.is_alive("agent", "shooter")
    )
    a, b = Played(z, both, "both", 3), Played(z, shooter_only, "person", 4)
    for _ in range(6):  # the two matches' frames interleave
        a.step(ROLES, wait_until)
        b.step(("shooter",), wait_until)
    assert not shooter_only.is_alive("agent", "bait") and not b.actions("bait")  # a person's seat
    for played, role, policy, seed in (
        (a, "bait", "B3", 3),
        (a, "shooter", "S1", 3),
        (b, "shooter", "S1", 4),  # one library policy's weights, two seats: each its own stream
    ):
        actions = played.actions(role)
        assert [x.frame for x in actions] == list(range(6))
        assert {(x.match, x.role, x.policy, x.sender) for x in actions} == {
            (played.match, role, policy, f"agent/{role}")
        }
        assert [x.action for x in actions] == expected(role, policy, seed, 6)
    pool.stop.set()
    assert pool.result(timeout=5).counts == Counter()
    assert wait_until(lambda: not both.alive and not shooter_only.alive and not pool_alive(z, "agent"))


def test_a_repeated_order_is_ignored_and_a_seat_ends_on_its_summary(agents, tap, wait_until) -> None:
    z, pool = agents
    recorded = tap(z, "repeat")
    first = order("repeat", 1, bait="circle")
    for again in (first, order("repeat", 1, bait="B3", shooter="S5")):  # re-put, even changed
        z.put(keys.pool_order(POOL), again.encode(), **BLOCK)
    played = Played(z, recorded, "repeat", 1)
    assert wait_until(lambda: recorded.is_alive("agent", "bait"))
    for _ in range(3):
        played.step(("bait",), wait_until)
    assert {x.policy for x in played.actions("bait")} == {"circle"} and not played.actions("shooter")
    played.end()
    assert wait_until(lambda: not recorded.alive), "the seat's token goes with the match"
    z.put(keys.pool_order(POOL), first.encode(), **BLOCK)  # the launcher's late re-put
    played.step((), wait_until)
    assert not wait_until(lambda: recorded.alive or len(played.actions("bait")) > 3, timeout=1)
    pool.stop.set()
    assert pool.result(timeout=5).counts == Counter()


def test_a_killed_sim_ends_its_seats_only(agents, tap, bus, wait_until) -> None:
    z, pool = agents
    killed, live = tap(z, "killed"), tap(z, "live")
    sim = bus.open()  # the killed match's sim: its session, holding the sim's token
    token = sim.liveliness().declare_token(keys.alive("killed", "sim"))
    for match in ("killed", "live"):
        z.put(keys.pool_order(POOL), order(match, 2, bait="circle", shooter="mirror").encode(), **BLOCK)
    assert wait_until(lambda: all(t.is_alive("agent", r) for t in (killed, live) for r in ROLES))
    assert wait_until(lambda: killed.is_alive("sim"))
    token.undeclare()
    assert wait_until(lambda: not killed.alive, timeout=3), "both seats of the killed match leave"
    played = Played(z, live, "live", 2)
    for _ in range(3):
        played.step(ROLES, wait_until)
    assert all(live.is_alive("agent", r) for r in ROLES)
    pool.stop.set()
    assert pool.result(timeout=5).counts == Counter()


def test_a_bad_order_is_counted_and_dropped(agents, tap, wait_until) -> None:
    z, pool = agents
    recorded = tap(z, "good")
    bad = [
        b"\xc1 not msgpack",
        order("wrong", 1, bait="S4").encode(),  # a shooter in the bait seat
        order("unknown", 1, shooter="no-such-policy").encode(),
        Summary(match="x", frame=1, sender="sim").encode(),
    ]
    for data in bad:
        z.put(keys.pool_order(POOL), data, **BLOCK)
    z.put(keys.pool_order(POOL), order("good", 1, bait="circle").encode(), **BLOCK)
    assert wait_until(lambda: recorded.is_alive("agent", "bait"))
    Played(z, recorded, "good", 1).step(("bait",), wait_until)
    pool.stop.set()
    assert pool.result(timeout=5).counts == Counter({"undecodable": 1, "policy": 2, "type": 1})


BEST_FOR_B3 = Table.load(DEFAULT_TABLE).best_shooter("B3")


def test_the_adapter_pool_switches_an_ordered_match_as_the_single_adapter_does(
    bus, tap, background, wait_until
) -> None:
    z = bus.open(listen=True)
    adapted, plain = tap(z, "adapted"), tap(z, "plain")
    adapters = background(run_adapter_pool, bus.config(), POOL)
    agents = background(run_agent_pool, bus.config(), POOL)
    assert wait_until(lambda: pool_alive(z, "adapter") and pool_alive(z, "agent"), timeout=10)
    config = AdapterConfig("shooter", window=100, strategy="cem", seed=7)
    ordered = order(
        "adapted", 7, bait="B3", shooter=initial_policy(config), adapter=config.name, adaptive="shooter"
    )
    for made in (ordered, order("plain", 7, bait="B3", shooter="S5")):
        z.put(keys.pool_order(POOL), made.encode(), **BLOCK)
    assert wait_until(
        lambda: adapted.is_alive("adapter") and all(adapted.is_alive("agent", r) for r in ROLES)
    )
    sim = background(run_sim, bus.config(), "adapted", 7, GameConfig(frames=400), "lockstep", NAMES)
    assert sim.result(timeout=60).frame == 400
    switches = adapted.of(PolicySwitch, keys.policy("adapted", "shooter"))
    assert switches and switches[0].policy == BEST_FOR_B3 and "B3" in switches[0].reason
    assert any(a.policy == BEST_FOR_B3 for a in adapted.of(Action, keys.action("adapted", "shooter")))
    statuses = adapted.of(AdapterStatus, keys.adapter("adapted"))
    assert statuses[-1].partner == "B3" and statuses[-1].policy == BEST_FOR_B3
    assert wait_until(lambda: not adapted.alive), "the match's adapter and seats leave with it"
    assert not plain.is_alive("adapter") and plain.is_alive("agent", "shooter")  # no adapter ordered
    for service in (adapters, agents):
        service.stop.set()
        assert service.result(timeout=5).total == 0


def test_pool_processes_leave_on_sigterm_with_their_matches_tokens(bus, tap, spawn, wait_until) -> None:
    z = bus.open(listen=True)
    recorded = tap(z, "open")
    config = AdapterConfig("shooter", window=100, strategy="cem", seed=1)
    processes = [spawn(service, bus.config(), "--pool", POOL) for service in ("agent", "adapter")]
    assert wait_until(lambda: pool_alive(z, "agent") and pool_alive(z, "adapter"), timeout=30)
    made = order(
        "open", 1, bait="B3", shooter=initial_policy(config), adapter=config.name, adaptive="shooter"
    )
    z.put(keys.pool_order(POOL), made.encode(), **BLOCK)
    assert wait_until(
        lambda: recorded.is_alive("adapter") and all(recorded.is_alive("agent", r) for r in ROLES)
    )
    for process in processes:
        process.send_signal(signal.SIGTERM)
    assert [process.wait(10) for process in processes] == [0, 0]
    assert wait_until(
        lambda: not recorded.alive and not pool_alive(z, "agent") and not pool_alive(z, "adapter")
    )


def test_an_order_a_pool_fails_to_start_for_its_own_fault_is_refused_at_once(bus, background, wait_until):
    """A fault of the service's own (a library file missing, a bug) is not the order's, yet its
    launcher must hear of it now rather than wait for tokens that never come."""
    z = bus.open(listen=True)
    refusals: list[MatchRefused] = []
    z.declare_subscriber(
        keys.pool_refused(POOL), lambda s: refusals.append(decode(s.payload.to_bytes(), MatchRefused))
    )

    def start(made: MatchOrder) -> list:
        raise FileNotFoundError(f"no weights for {made.match}")

    def serve(config, stop):  # noqa: ANN001 - the bus config and the fixture's stop event
        with session(config) as served:
            serve_orders(served, POOL, "agent", start, Drops("agent"), stop)

    server = background(serve, bus.config())
    assert wait_until(lambda: pool_alive(z, "agent"), timeout=10)
    z.put(keys.pool_order(POOL), order("broken", 1).encode(), **BLOCK)
    assert wait_until(lambda: refusals, timeout=5)
    assert refusals[0].match == "broken" and "no weights for broken" in refusals[0].reason
    server.stop.set()
    server.result(timeout=5)
