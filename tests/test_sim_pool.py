"""A pool's sim on a real bus: matches come from orders on the pool's keys, several at once on one
clock, each with its own traffic on its own keys."""

from __future__ import annotations

import gc
import os
import signal

import msgpack
import pytest
import zenoh
from test_match_processes import may_raise_priority, nice, niced
from test_sim_contract import Hands, act

from services.sim.pool import BUS_BELOW, run_pool
from services.sim.service import MatchSim
from shared import keys
from shared.bus import BusConfig
from shared.game import ROLES
from shared.messages import GameEvent, MatchOrder, MatchStop, Start, State, Summary

POOL = "lab"
NAMES = {"bait": "B1", "shooter": "human"}


def order(match: str, frames: int, **fields: object) -> MatchOrder:
    given = {"seed": 3, "names": NAMES, "wait_players": 0.0, "wait_services": 0.0, **fields}
    return MatchOrder(match=match, frame=0, sender="test", frames=frames, **given)


def put(z: zenoh.Session, key: str, data: bytes) -> None:
    z.put(key, data, congestion_control=zenoh.CongestionControl.BLOCK)


def pool_ready(z: zenoh.Session, wait_until) -> bool:  # noqa: ANN001 - the wait_until fixture
    alive = keys.pool_alive(POOL, "sim")
    return wait_until(lambda: any(r.ok for r in z.liveliness().get(alive, timeout=1)), timeout=10)


@pytest.fixture
def pool(bus, background, wait_until):
    """The test's session (listening) and a pool sim in a thread connected to it, ready for orders."""
    z = bus.open(listen=True)
    sim = background(run_pool, bus.config(), POOL)
    assert pool_ready(z, wait_until), "the pool declares its token once subscribed"
    return z, sim


def live_matches(*ids: str) -> list[MatchSim]:
    """The matches of these ids still in memory (a pool that runs for hours must keep none)."""
    gc.collect()
    return [o for o in gc.get_objects() if isinstance(o, MatchSim) and o.match in ids]


def played(recorded, frames: int) -> Summary:  # noqa: ANN001 - a Tap
    """One start first, one state per frame in order, one summary last (returned)."""
    messages = [m for _, _, m in recorded.samples if isinstance(m, (Start, State, GameEvent, Summary))]
    assert isinstance(messages[0], Start) and len(recorded.of(Start)) == 1
    assert [s.frame for s in recorded.of(State)] == list(range(frames + 1))
    assert isinstance(messages[-1], Summary) and len(recorded.of(Summary)) == 1
    return messages[-1]


def test_a_pool_plays_overlapping_matches_each_on_its_own_keys(pool, tap, wait_until):
    z, sim = pool
    a, b = tap(z, "a"), tap(z, "b")
    hands = Hands(z, "a")
    put(z, keys.pool_order(POOL), order("a", 60).encode())
    first = hands.states.get(timeout=5)
    put(z, keys.pool_order(POOL), order("b", 30, seed=4).encode())
    put(z, keys.pool_order(POOL), order("a", 60).encode())  # a launcher re-puts until it sees the tokens
    hands.answer(first)
    hands.play(60)
    assert wait_until(lambda: a.of(Summary) and b.of(Summary), timeout=10)
    put(z, keys.pool_order(POOL), order("b", 30).encode())  # a match it had: ignored too
    summary_a, summary_b = played(a, 60), played(b, 30)
    assert (summary_a.frame, summary_b.frame) == (60, 30)
    assert a.of(Start)[0].policies == NAMES and (a.of(Start)[0].seed, b.of(Start)[0].seed) == (3, 4)
    assert a.timed(Start)[0][0] < b.timed(Start)[0][0] < a.timed(Summary)[0][0]  # they overlapped
    assert any(s.applied == [act(r, s.frame - 1) for r in ROLES] for s in a.of(State)[1:])
    assert all(s.applied == [0, 0] for s in b.of(State))  # nobody holds b's seats: no-op
    assert {"tick_jitter_ms_p99", "round_trip_ms_p99"} <= set(summary_a.timing)
    # An ended match leaves nothing declared: its token goes; later orders start nothing more.
    assert wait_until(lambda: not a.is_alive("sim") and not b.is_alive("sim"))
    assert len(a.of(Start)) == len(b.of(Start)) == 1
    assert wait_until(lambda: not live_matches("a", "b"), timeout=10)
    sim.stop.set()
    assert sim.result(timeout=5).drops.total == 0


def test_a_stop_ends_only_its_match_and_stopping_the_pool_ends_the_rest(pool, tap, wait_until):
    z, sim = pool
    a, b = tap(z, "a"), tap(z, "b")
    for match in ("a", "b"):
        put(z, keys.pool_order(POOL), order(match, 900).encode())
    assert wait_until(lambda: len(a.of(State)) > 5 and len(b.of(State)) > 5)
    put(z, keys.pool_stop(POOL), MatchStop(match="a", frame=0, sender="test").encode())
    assert wait_until(lambda: a.of(Summary))
    states_b = len(b.of(State))
    assert wait_until(lambda: len(b.of(State)) > states_b + 10), "b plays on"
    assert not b.of(Summary)
    sim.stop.set()
    sim.result(timeout=5)
    stopped_a, stopped_b = played(a, a.of(Summary)[0].frame), played(b, b.of(Summary)[0].frame)
    assert stopped_a.frame < stopped_b.frame < 900


def test_a_bad_order_is_dropped_and_counted(pool, tap, wait_until):
    z, sim = pool
    good = order("ok", 10).encode()
    bad = [
        b"\xc1garbage",
        msgpack.packb({**msgpack.unpackb(good), "frames": 0}),
        msgpack.packb({**msgpack.unpackb(good), "mode": "fast"}),
        MatchStop(match="ok", frame=0, sender="test").encode(),  # a stop on the order key
    ]
    for data in bad:
        put(z, keys.pool_order(POOL), data)
    put(z, keys.pool_stop(POOL), good)  # an order on the stop key
    recorded = tap(z, "ok")
    put(z, keys.pool_order(POOL), good)
    assert wait_until(lambda: recorded.of(Summary))
    played(recorded, 10)
    sim.stop.set()
    assert sim.result(timeout=5).drops.counts == {"undecodable": 1, "range": 2, "type": 2}


def test_sigterm_ends_the_running_matches_and_exits_0(endpoint, bus, spawn, tap, wait_until):
    """Also: the pool raises every thread's priority at once (where permitted), before any match;
    where not, its bus's threads step below its clock (the main thread)."""
    router = BusConfig("router", (endpoint,))
    process = spawn("sim", router, "--pool", POOL, "--priority", "3")
    z = bus.open()  # a peer that connects to the pool's router
    assert pool_ready(z, wait_until)
    base, pid = nice(os.getpid()), process.pid
    if may_raise_priority():
        assert set(niced(pid).values()) == {base - 3}
    else:
        assert wait_until(lambda: niced(pid) == {**{t: base + BUS_BELOW for t in niced(pid)}, pid: base})
    recorded = tap(z, "long")
    put(z, keys.pool_order(POOL), order("long", 900).encode())
    assert wait_until(lambda: len(recorded.of(State)) > 3)
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=10) == 0
    assert played(recorded, recorded.of(Summary)[0].frame).frame < 900


def test_a_lockstep_order_steps_on_its_seats_answers(pool, tap, wait_until):
    z, sim = pool
    recorded, hands = tap(z, "lock"), Hands(z, "lock")
    put(z, keys.pool_order(POOL), order("lock", 40, mode="lockstep", wait_players=5.0).encode())
    states = hands.play(40)
    assert wait_until(lambda: recorded.of(Summary))
    assert played(recorded, 40).frame == 40 and recorded.of(Start)[0].mode == "lockstep"
    assert all(s.applied == [act(r, s.frame - 1) for r in ROLES] for s in states[1:])
