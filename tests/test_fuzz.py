"""Fuzz: random bytes and wrong-schema maps on every key a service subscribes to, during lockstep
matches of the real services (in threads); nothing crashes, every drop is counted, the game is unchanged."""

from __future__ import annotations

import itertools
from collections import Counter

import msgpack
import pytest
import zenoh
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from services.agent.scripted import CircleBait, MirrorShooter
from services.agent.service import run_agent
from services.recorder.recording import load, replay
from services.recorder.service import run_recorder
from services.sim.engine import Game
from services.sim.match import start_message, state_message, summary_message
from services.sim.observation import observe
from services.sim.play import policy_seed
from services.sim.service import run_sim
from shared import keys
from shared.game import ROLES, GameConfig
from shared.messages import Action, GameEvent, MessageError, PolicySwitch, State, Summary, decode

SEED, FRAMES = 4, 40
CONFIG = GameConfig(frames=FRAMES)
POLICIES = {"bait": "circle", "shooter": "mirror"}
# Key suffix -> (the type the services expect there, the services that read it).
SUBSCRIBED = {
    "action/bait": (Action, ("sim",)),
    "action/shooter": (Action, ("sim",)),
    "policy/bait": (PolicySwitch, ("bait",)),
    "policy/shooter": (PolicySwitch, ("shooter",)),
    "state": (State, ROLES),
    "summary": (Summary, ROLES),
}
_game = Game(CONFIG, SEED)
VALID = {  # one valid record of each type: corrupted, or sent where another type is expected
    m.TYPE: msgpack.unpackb(m.encode())
    for m in (
        start_message(_game, "m", "sim", "lockstep", POLICIES),
        state_message(_game, "m", "sim", (0, 0)),
        Action(match="m", frame=0, sender="x", role="bait", action=3, policy="circle"),
        PolicySwitch(match="m", frame=0, sender="x", role="bait", policy="idle"),
        GameEvent(match="m", frame=0, sender="sim", kind="kill", role="shooter"),
        summary_message(_game, "m", "sim", {}, {}),
    )
}


def clean_run() -> tuple[list[str], tuple]:
    """State hashes and result of the match played in-process (equal to a clean bus run, test_match)."""
    game, bait, shooter = Game(CONFIG, SEED), CircleBait(), MirrorShooter()
    bait.reset(policy_seed(SEED, "bait"))
    shooter.reset(policy_seed(SEED, "shooter"))
    hashes = [game.state_hash()]
    while not game.done:
        game.step(
            bait.act(observe(game, "bait", bait.view)), shooter.act(observe(game, "shooter", shooter.view))
        )
        hashes.append(game.state_hash())
    return hashes, (game.kills, game.points, game.counters())


CLEAN = clean_run()


def reason(suffix: str, data: bytes, match: str) -> str | None:
    """Why the services reading `suffix` drop `data` (as the contract says), or None if they take it."""
    try:
        message = decode(data, SUBSCRIBED[suffix][0])
    except MessageError as error:
        return error.reason
    if suffix.startswith(("action/", "policy/")) and (
        message.role != suffix.split("/")[1] or message.match != match
    ):
        return "mismatch"
    return None


def record(kind: str, how: str, pick: int) -> bytes:
    """A record of `kind` made invalid for every type: a field dropped, set to None, or one added."""
    fields = dict(VALID[kind])
    name = sorted(fields)[pick % len(fields)]
    if how == "drop":
        del fields[name]
    elif how == "none":
        fields[name] = None
    else:
        fields["junk"] = 1
    return msgpack.packb(fields)


def rematch(data: bytes, match: str) -> bytes:
    """Records made from VALID name match "m": point them at this example's match instead."""
    try:
        fields = msgpack.unpackb(data)
    except Exception:
        return data
    if isinstance(fields, dict) and fields.get("match") == "m":
        return msgpack.packb({**fields, "match": match})
    return data


kinds = st.sampled_from(sorted(VALID))
payloads = st.one_of(
    st.binary(max_size=200),
    st.builds(record, kinds, st.sampled_from(["drop", "none", "extra"]), st.integers(0, 50)),
    st.dictionaries(
        st.text(max_size=6),
        st.one_of(st.none(), st.integers(-(2**63), 2**63 - 1), st.text(max_size=6)),
        max_size=6,
    ).map(msgpack.packb),
    kinds.map(lambda kind: msgpack.packb(VALID[kind])),  # valid, but (below) only where not expected
)
bad_inputs = st.lists(
    st.tuples(st.sampled_from(sorted(SUBSCRIBED)), payloads, st.integers(0, FRAMES // 2)), max_size=12
)


matches = itertools.count()


@pytest.fixture
def listener(bus):
    """The test's session, kept over all examples; each example's services connect to it."""
    return bus, bus.open(listen=True)


@settings(
    max_examples=30,
    deadline=None,
    phases=[Phase.explicit, Phase.reuse, Phase.generate],  # a match per example: shrinking takes minutes
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@pytest.mark.long
@pytest.mark.slow
@given(bad_inputs)
def test_bad_input_anywhere_is_dropped_counted_and_harmless(listener, tap, background, tmp_path, inputs):
    bus, z = listener
    match = f"fuzz{next(matches)}"
    inputs = [
        (s, d, f) for s, d, f in ((s, rematch(d, match), f) for s, d, f in inputs) if reason(s, d, match)
    ]
    by_frame = {f: [(s, d) for s, d, g in inputs if g == f] for f in range(FRAMES)}

    def inject(sample: zenoh.Sample) -> None:
        try:
            frame = decode(sample.payload.to_bytes(), State).frame
        except MessageError:  # what this test itself puts on the state key
            return
        for suffix, data in by_frame.get(frame, []):
            z.put(f"tsf/{match}/{suffix}", data, congestion_control=zenoh.CongestionControl.BLOCK)

    recorded = tap(z, match)
    injector = z.declare_subscriber(keys.state(match), inject)
    try:
        recorder = background(run_recorder, bus.config(), match, tmp_path)
        agents = {r: background(run_agent, bus.config(), match, r, POLICIES[r], SEED) for r in ROLES}
        sim = background(run_sim, bus.config(), match, SEED, CONFIG, "lockstep", POLICIES, wait_recorder=10)
        summary = sim.result(timeout=30)
        drops = {r: agent.result(timeout=10).counts for r, agent in agents.items()}
        recording = load(recorder.result(timeout=10))
    finally:
        injector.undeclare()

    expected = {service: Counter() for service in ("sim", *ROLES)}
    for suffix, data, _ in inputs:
        for service in SUBSCRIBED[suffix][1]:
            expected[service][reason(suffix, data, match)] += 1
    assert summary.drops == expected["sim"] and drops == {r: expected[r] for r in ROLES}
    assert [s.hash for s in recording.states] == CLEAN[0]
    assert (summary.kills, summary.points, summary.counters) == CLEAN[1]
    assert recording.clean and recording.gaps == [] and recording.undecodable == 0 and replay(recording) == []
    answers = Counter((a.role, a.frame) for _, a in recording.actions)  # the last state's may be cut off
    assert {k for k in answers if k[1] < FRAMES} == set(itertools.product(ROLES, range(FRAMES)))
    assert max(answers.values()) == 1 and recording.summary == summary
    assert recording.events == recorded.of(GameEvent, keys.event(match))
