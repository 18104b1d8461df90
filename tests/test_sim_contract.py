"""The sim service alone on a real bus: the test plays both seats by hand."""

from __future__ import annotations

import queue
import random
import time
from collections import Counter

import msgpack
import pytest
import zenoh

from services.sim.engine import Game
from services.sim.service import run_sim
from shared import keys
from shared.game import ROLES, GameConfig
from shared.messages import MAX_BYTES, SCHEMA_VERSION, Action, GameEvent, Start, State, Summary, decode

SEED = 11
POLICIES = {"bait": "hand", "shooter": "hand"}


def act(role: str, frame: int) -> int:
    """The hand-played action of a seat for the state of `frame` (never no-op for the shooter)."""
    return frame % 12 if role == "bait" else 1 + 5 * frame % 11


def hashes(config: GameConfig, applied: list[list[int]]) -> list[str]:
    """The state hashes the engine gives for these applied actions (frame 0 first)."""
    game = Game(config, SEED)
    out = [game.state_hash()]
    for actions in applied[1:]:
        game.step(*actions)
        out.append(game.state_hash())
    return out


class Hands:
    """Plays seats by hand from the test thread: holds their liveliness tokens and answers states."""

    def __init__(self, z, match: str, roles: tuple[str, ...] = ROLES) -> None:  # noqa: ANN001 - a session
        self.z, self.match = z, match
        self.states: queue.SimpleQueue[State] = queue.SimpleQueue()
        self.subscriber = z.declare_subscriber(
            keys.state(match), lambda s: self.states.put(decode(s.payload.to_bytes(), State))
        )
        self.tokens = {r: z.liveliness().declare_token(keys.alive(match, "agent", r)) for r in roles}

    def leave(self, role: str) -> None:
        self.tokens.pop(role).undeclare()

    def put(self, role: str, data: bytes) -> None:
        self.z.put(keys.action(self.match, role), data, congestion_control=zenoh.CongestionControl.BLOCK)

    def answer(self, state: State, roles: tuple[str, ...] = ROLES) -> None:
        for role in roles:
            self.put(
                role,
                Action(
                    match=self.match,
                    frame=state.frame,
                    sender="test",
                    role=role,
                    action=act(role, state.frame),
                    policy="hand",
                ).encode(),
            )

    def play(self, frames: int, before=None, roles=lambda frame: ROLES) -> list[State]:  # noqa: ANN001
        """Answer every state until the last; `before(state)` runs before each answer."""
        states = []
        while not states or states[-1].frame < frames:
            states.append(self.states.get(timeout=5))
            if before:
                before(states[-1])
            self.answer(states[-1], roles(states[-1].frame))
        return states


@pytest.fixture
def table(bus, tap, background):
    """table(match, frames, mode, roles, **sim options) -> (hands, tap, the sim's future): the test's
    session listens, records the match and holds the seats; run_sim connects in a thread."""
    z = bus.open(listen=True)

    def make(match: str, frames: int, mode: str = "lockstep", roles: tuple[str, ...] = ROLES, **options):
        recorded, hands = tap(z, match), Hands(z, match, roles)
        config, options = GameConfig(frames=frames), {"policies": POLICIES, **options}
        return hands, recorded, background(run_sim, bus.config(), match, SEED, config, mode, **options)

    return make


def sim_messages(recorded) -> list:  # noqa: ANN001 - a Tap
    return [
        m for _, k, m in recorded.samples if k.rsplit("/", 1)[-1] in ("start", "state", "event", "summary")
    ]


def check_match_shape(recorded, summary: Summary, frames: int, mode: str) -> list[State]:  # noqa: ANN001
    """Start first, one State per frame in order, summary once and last; returns the states."""
    messages = sim_messages(recorded)
    start = messages[0]
    assert isinstance(start, Start)
    assert (start.seed, start.mode, start.policies, start.frame) == (SEED, mode, POLICIES, 0)
    assert GameConfig.from_dict(start.config) == GameConfig(frames=frames)
    states = [m for m in messages if isinstance(m, State)]
    assert [s.frame for s in states] == list(range(frames + 1))
    assert messages[-1] == summary and recorded.of(Summary) == [summary]
    assert summary.frame == frames
    assert all(isinstance(m, (Start, State, GameEvent, Summary)) for m in messages)
    return states


def test_lockstep_applies_exactly_the_actions_sent(table, wait_until):
    hands, recorded, sim = table("lock", 40)
    hands.play(40)
    summary = sim.result(timeout=10)
    assert wait_until(lambda: recorded.of(Summary))
    states = check_match_shape(recorded, summary, 40, "lockstep")
    assert states[0].applied == [0, 0]
    assert all(s.applied == [act(r, s.frame - 1) for r in ROLES] for s in states[1:])
    assert [s.hash for s in states] == hashes(GameConfig(frames=40), [s.applied for s in states])
    assert summary.drops == {}


def test_the_start_names_both_seats_without_policies(table, wait_until):
    hands, recorded, sim = table("nameless", 3, policies=None)
    hands.play(3)
    sim.result(timeout=10)
    assert wait_until(lambda: recorded.of(Summary))
    assert [s.policies for s in recorded.of(Start)] == [{"bait": "", "shooter": ""}]


def test_realtime_ticks_at_30_hz(table, wait_until):
    frames = 60
    hands, recorded, sim = table("rt", frames, "realtime")
    hands.play(frames)
    summary = sim.result(timeout=10)
    assert wait_until(lambda: recorded.of(Summary))
    states = check_match_shape(recorded, summary, frames, "realtime")
    rate = frames / ((states[-1].sent_ns - states[0].sent_ns) / 1e9)
    assert rate == pytest.approx(30, rel=0.1)
    arrivals = [t for t, m in recorded.timed(State)]
    assert frames / (arrivals[-1] - arrivals[0]) == pytest.approx(30, rel=0.1)
    # The latest action of each seat is applied: a hand-played one (or no-op before the first).
    played = {r: {0} | {act(r, f) for f in range(frames)} for r in ROLES}
    assert all(s.applied[i] in played[r] for s in states for i, r in enumerate(ROLES))
    assert {"tick_jitter_ms_p50", "tick_jitter_ms_p99", "round_trip_ms_p50"} <= set(summary.timing)


def test_a_seat_without_a_player_plays_noop(table):
    """The shooter never declares its token: its actions are ignored and the sim does not wait."""
    hands, _, sim = table("absent", 30, roles=("bait",), wait_players=0.5, step_timeout=2.0)
    began = time.monotonic()
    states = hands.play(30)  # both seats' actions are sent
    sim.result(timeout=10)
    assert all(s.applied == [act("bait", s.frame - 1), 0] for s in states[1:])
    assert time.monotonic() - began < 2.0 + 0.5  # the wait for players, never a step timeout


def test_a_seat_whose_player_leaves_plays_noop_from_the_next_frame(table):
    hands, _, sim = table("leaves", 30, step_timeout=2.0)
    began = time.monotonic()

    def leave_at_10(state: State) -> None:
        if state.frame == 10:
            hands.leave("shooter")

    states = hands.play(30, leave_at_10, roles=lambda frame: ROLES if frame < 10 else ("bait",))
    sim.result(timeout=10)
    assert [s.applied[1] for s in states[1:11]] == [act("shooter", f) for f in range(10)]
    assert all(s.applied == [act("bait", s.frame - 1), 0] for s in states[11:])
    assert time.monotonic() - began < 2.0  # the sim saw the token go instead of timing out


def bad_inputs(match: str, frame: int, rng: random.Random) -> list[tuple[str, bytes, str]]:
    """(seat key, bytes, the reason the sim must count) for one burst of bad input. The well-formed
    ones answer the *next* frame, so that any of them accepted would change the game."""

    def action(**fields) -> bytes:
        return Action(**{"match": match, "frame": frame + 1, "sender": "x", "action": 5, **fields}).encode()

    def record(**fields) -> bytes:
        return msgpack.packb({**msgpack.unpackb(action(role="bait")), **fields})

    return [
        ("bait", b"\xc1" + rng.randbytes(rng.randrange(64)), "undecodable"),
        ("bait", b"\0" * (MAX_BYTES + 1), "too_large"),
        ("bait", msgpack.packb([1, 2, 3]), "shape"),
        ("shooter", msgpack.packb({"v": 1, "type": "action", "match": match}), "shape"),
        ("bait", record(v=SCHEMA_VERSION + 1), "version"),
        ("bait", record(type="summary"), "type"),
        ("shooter", action(role="shooter", action=99), "range"),
        ("shooter", action(role="bait"), "mismatch"),
        ("bait", action(role="bait", match="elsewhere"), "mismatch"),
    ]


def test_bad_action_input_is_dropped_counted_and_harmless(table):
    clean_hands, _, clean_sim = table("clean", 30)
    clean = clean_hands.play(30)
    expected = clean_sim.result(timeout=10)

    rng, reasons = random.Random(0), Counter()
    dirty_hands, _, dirty_sim = table("dirty", 30)

    def spoil(state: State) -> None:
        if state.frame % 5 == 1:
            for role, data, reason in bad_inputs("dirty", state.frame, rng):
                dirty_hands.put(role, data)
                reasons[reason] += 1

    dirty = dirty_hands.play(30, spoil)
    summary = dirty_sim.result(timeout=10)
    assert summary.drops == dict(reasons) and len(reasons) == 7
    assert [(s.hash, s.applied) for s in dirty] == [(s.hash, s.applied) for s in clean]
    assert (summary.kills, summary.points, summary.counters) == (
        expected.kills,
        expected.points,
        expected.counters,
    )
