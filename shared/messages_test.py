"""The message contract: every type round-trips, every bad input fails with its reason code, and no
input whatever makes decoding raise anything but MessageError."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from services.sim.engine import Game
from services.sim.match import start_message, state_message, summary_message
from shared.game import OBS_SIZE, GameConfig
from shared.messages import (
    CHUNK,
    MAX_BYTES,
    RECORDED,
    SCHEMA_VERSION,
    TYPES,
    Action,
    AdapterStatus,
    GameEvent,
    HostStatus,
    JobOrder,
    JobResult,
    MatchAnswer,
    MatchDone,
    MatchOffer,
    MatchOrder,
    MatchRefused,
    MatchStop,
    Message,
    MessageError,
    PolicySwitch,
    RecordingChunk,
    Ruling,
    Start,
    State,
    Summary,
    decode,
    decode_any,
)

M = "match-1"
POLICIES = {"bait": "circle", "shooter": "mirror"}
FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def played(steps: int = 40) -> Game:
    """A game after some steps with the shooter firing, so that missiles and events exist."""
    game = Game(GameConfig(frames=60), seed=3)
    for frame in range(steps):
        game.step(2 + 4 * (frame % 3 == 0), 1 + 4 * (frame % 5 == 0))
    return game


def examples() -> dict[str, Message]:
    """One realistic instance of every message type."""
    game = played()
    return {
        "start": start_message(Game(GameConfig(frames=60), seed=3), M, "sim", "lockstep", POLICIES),
        "state": state_message(game, M, "sim", (6, 1)),
        "action": Action(
            match=M, frame=game.frame, sender="agent/bait", role="bait", action=11, policy="circle"
        ),
        "policy": PolicySwitch(
            match=M,
            frame=game.frame,
            sender="adapter",
            role="shooter",
            policy="mirror",
            reason="cross-entropy 2.3 > 1.5",
        ),
        "ruling": Ruling(match=M, frame=191, sender="adapter", role="shooter", policy="GS2", partner="G4"),
        "event": GameEvent(match=M, frame=12, sender="sim", kind="death", role="bait", detail="shell"),
        "summary": summary_message(game, M, "sim", {"range": 2, "shape": 1}, {"round_trip_ms_p50": 1.5}),
        "sweep_job": JobOrder(
            sweep="table",
            frame=0,
            sender="sweep",
            job="B5-S4-10-10",
            kind="team",
            args={"role": "shooter", "games": [["noisy(B5)", "adaptive-T400-cem", 3]]},
            plugins=["my_lab.partners:Alice"],
            library="0123456789abcdef",
            config=GameConfig().hash(),
        ),
        "adapter": AdapterStatus(
            match=M,
            frame=420,
            sender="adapter",
            role="shooter",
            strategy="cem",
            window=400,
            filled=400,
            partner="B5",
            policy="S5",
            scores={"B1": -4.1, "B5": -1.2},
            belief={"B1": 0.05, "B5": 0.95},
            out_of_library=False,
        ),  # fmt: skip
        "sweep_result": JobResult(
            sweep="table",
            frame=0,
            sender="worker/w1",
            job="B5-S4-10-10",
            values=[8.0, 6.5, 9.0],
            error="",
            seconds=1.25,
            library="0123456789abcdef",
            config=GameConfig().hash(),
        ),
        "host_status": HostStatus(host="lab-2", frame=0, sender="host/lab-2", slots=4, free=3),
        "match_offer": MatchOffer(
            match=M,
            frame=0,
            sender="study",
            seed=7,
            frames=300,
            bait="human",
            shooter="",
            adapter="adaptive-T30-cem",
            wait_players=915.0,
            timeout=1035.0,
            library="0123456789abcdef",
            config=GameConfig().hash(),
        ),  # fmt: skip
        "match_answer": MatchAnswer(
            match=M, frame=0, sender="host/lab-2", accepted=False, reason="no free slot"
        ),
        "match_stop": MatchStop(match=M, frame=0, sender="study"),
        "match_refused": MatchRefused(
            match=M, frame=0, sender="pool/lab/agent", service="agent", reason="policy: OSError: gone"
        ),
        "match_order": MatchOrder(
            match=M,
            frame=0,
            sender="pool/lab",
            seed=7,
            frames=300,
            mode="realtime",
            bait="",
            shooter="S4",
            names={"bait": "human", "shooter": "adaptive-T30-cem"},
            adapter="adaptive-T30-cem",
            adaptive="shooter",
            wait_players=915.0,
            wait_services=30.0,
            folder="practice",
        ),  # fmt: skip
        "match_done": MatchDone(match=M, frame=0, sender="host/lab-2", error="", size=5, sha256="ab" * 32),
        "recording_chunk": RecordingChunk(
            match=M, frame=0, sender="host/lab-2", offset=0, size=5, data=b"TSF\x00\x01"
        ),
    }


EXAMPLES = examples()


def record(kind: str, /, **changes: Any) -> dict:
    """The wire record of the example of `kind`, with fields changed (a value of ... deletes it)."""
    out = msgpack.unpackb(EXAMPLES[kind].encode(), raw=False)
    for name, value in changes.items():
        if value is ...:
            del out[name]
        else:
            out[name] = value
    return out


def pack(value: Any) -> bytes:
    return msgpack.packb(value, use_bin_type=True)


def reason(data: bytes, expected: type[Message] | None = None) -> str:
    with pytest.raises(MessageError) as caught:
        decode(data, expected) if expected else decode_any(data)
    return caught.value.reason


def test_examples_cover_every_type() -> None:
    assert set(EXAMPLES) == set(TYPES)
    assert EXAMPLES["state"].missiles  # a state with projectiles in flight


@pytest.mark.parametrize("kind", sorted(TYPES))
def test_round_trip(kind: str) -> None:
    message = EXAMPLES[kind]
    data = message.encode()
    for view in (data, bytearray(data), memoryview(data)):
        for decoded in (decode(view, TYPES[kind]), decode_any(view)):
            assert type(decoded) is TYPES[kind]
            assert decoded.encode() == data
            if kind != "start":  # msgpack turns the config's spawn tuples into lists
                assert decoded == message


def test_start_config_round_trips() -> None:
    start = decode(EXAMPLES["start"].encode(), Start)
    assert GameConfig.from_dict(start.config) == GameConfig(frames=60)
    assert (start.seed, start.mode, start.policies) == (3, "lockstep", POLICIES)


def version_1(kind: str) -> bytes:
    """The example of `kind` as a version-1 peer wrote it: `v` 1, and its id named `match`."""
    old = record(kind, v=1)
    old["match"] = old.pop(EXAMPLES[kind].ID)
    return pack(old)


@pytest.mark.parametrize("kind", sorted(TYPES))
def test_version_1(kind: str) -> None:
    """Old recordings load: a version-1 record of a match's own traffic decodes to the message its
    version-2 record does. A version-1 job or host peer (and a host message sealed by one) is
    refused as `version`: it could not read this version's answers."""
    if TYPES[kind] in RECORDED:
        for decoded in (decode(version_1(kind), TYPES[kind]), decode_any(version_1(kind))):
            assert decoded.encode() == EXAMPLES[kind].encode()
    else:
        assert reason(version_1(kind), TYPES[kind]) == reason(version_1(kind)) == "version"


def test_families_name_their_id() -> None:
    """Each message's id says what it holds: a match's, a sweep's or a host's."""
    ids = {kind: message.ID for kind, message in EXAMPLES.items()}
    assert {k for k, i in ids.items() if i != "match"} == {"sweep_job", "sweep_result", "host_status"}
    assert (EXAMPLES["sweep_job"].sweep, EXAMPLES["host_status"].host) == ("table", "lab-2")


def obs_with(value: float, role: str = "shooter", index: int = 5, length: int | None = None) -> bytes:
    obs = {r: list(v) for r, v in EXAMPLES["state"].obs.items()}
    obs[role][index] = value
    if length is not None:
        obs[role] = (obs[role] + [0.0] * length)[:length]
    return pack(record("state", obs=obs))


BAD: list[tuple[str, Callable[[], bytes], type[Message] | None, str]] = [
    ("wrong version", lambda: pack(record("action", v=SCHEMA_VERSION + 1)), Action, "version"),
    ("no version", lambda: pack(record("action", v=...)), None, "version"),
    ("unknown type", lambda: pack(record("action", type="chat")), None, "type"),
    ("type is a list", lambda: pack(record("action", type=["action"])), None, "type"),
    ("type is a map", lambda: pack(record("action", type={"a": 1})), None, "type"),
    ("wrong expected type", lambda: EXAMPLES["action"].encode(), State, "type"),
    ("missing field", lambda: pack(record("action", role=...)), Action, "shape"),
    ("missing envelope", lambda: pack(record("state", frame=...)), None, "shape"),
    ("extra field", lambda: pack(record("event", colour="red")), GameEvent, "shape"),
    ("action 12", lambda: pack(record("action", action=12)), Action, "range"),
    ("action -1", lambda: pack(record("action", action=-1)), Action, "range"),
    ("bool action", lambda: pack(record("action", action=True)), Action, "range"),
    ("bool frame", lambda: pack(record("policy", frame=False)), PolicySwitch, "range"),
    ("float kills", lambda: pack(record("summary", kills=1.0)), Summary, "range"),
    ("unknown role", lambda: pack(record("action", role="pilot")), Action, "range"),
    ("wildcard match", lambda: pack(record("event", match="a/*")), GameEvent, "range"),
    ("wildcard sweep", lambda: pack(record("sweep_result", sweep="a/*")), JobResult, "range"),
    ("job with a match id", lambda: pack(record("sweep_job", sweep=..., match="t")), JobOrder, "shape"),
    ("host status, no host", lambda: pack(record("host_status", host=...)), HostStatus, "shape"),
    ("unknown event", lambda: pack(record("event", kind="explosion")), GameEvent, "range"),
    ("bad mode", lambda: pack(record("start", mode="turbo")), Start, "range"),
    ("bad config", lambda: pack(record("start", config={"fps": 30})), Start, "range"),
    ("bad hash", lambda: pack(record("state", hash="XYZ")), State, "range"),
    ("applied too short", lambda: pack(record("state", applied=[1])), State, "range"),
    ("too many missiles", lambda: pack(record("state", missiles=[[0.0] * 5] * 65)), State, "range"),
    ("negative kpm", lambda: pack(record("summary", kills_per_minute=-1.0)), Summary, "range"),
    ("counters roles", lambda: pack(record("summary", counters={"bait": {}})), Summary, "range"),
    ("undecodable", lambda: b"\xc1", None, "undecodable"),
    ("truncated", lambda: EXAMPLES["action"].encode()[:-1], Action, "undecodable"),
    ("trailing bytes", lambda: EXAMPLES["action"].encode() + b"\x00", Action, "undecodable"),
    ("bad utf-8", lambda: b"\x81\xa1v\xa2\xff\xfe", None, "undecodable"),
    ("list", lambda: pack([1, "state"]), None, "shape"),
    ("int", lambda: pack(7), State, "shape"),
    ("too large", lambda: b"\x00" * (MAX_BYTES + 1), None, "too_large"),
    ("too large valid", lambda: pack(record("event", detail="x" * MAX_BYTES)), GameEvent, "too_large"),
    ("NaN in obs", lambda: obs_with(math.nan), State, "range"),
    ("inf in obs", lambda: obs_with(math.inf, "bait"), State, "range"),
    ("-inf in obs", lambda: obs_with(-math.inf, index=0), State, "range"),
    ("huge in obs", lambda: obs_with(1e300), State, "range"),
    ("bool in obs", lambda: obs_with(True), State, "range"),  # type: ignore[arg-type]
    ("str in obs", lambda: obs_with("1.0"), State, "range"),  # type: ignore[arg-type]
    ("short obs", lambda: obs_with(0.0, length=OBS_SIZE - 1), State, "range"),
    ("long obs", lambda: obs_with(0.0, length=OBS_SIZE + 1), State, "range"),
    (
        "inf in fortress",
        lambda: pack(record("state", fortress=[0.0, 1.0, 0.0, math.inf, 0.0])),
        State,
        "range",
    ),
    ("NaN timing", lambda: pack(record("summary", timing={"tick_late_ms_p50": math.nan})), Summary, "range"),
    ("obs missing role", lambda: pack(record("state", obs={"bait": [0.0] * OBS_SIZE})), State, "range"),
    ("version true", lambda: pack(record("action", v=True)), Action, "version"),
    ("version float", lambda: pack(record("action", v=1.0)), Action, "version"),
    ("config NaN", lambda: pack(record("start", config=config_with(ship_thrust=math.nan))), Start, "range"),
    ("negative seed", lambda: pack(record("start", seed=-1)), Start, "range"),
    ("seed past 2^32", lambda: pack(record("start", seed=2**32)), Start, "range"),
    ("a day-long game", lambda: pack(record("start", config=config_with(frames=2_592_000))), Start, "range"),
    ("job of no kind", lambda: pack(record("sweep_job", kind="mine")), JobOrder, "range"),
    ("job NaN arg", lambda: pack(record("sweep_job", args={"x": [math.nan]})), JobOrder, "range"),
    ("job plugin path", lambda: pack(record("sweep_job", plugins=["/etc/passwd"])), JobOrder, "range"),
    ("result of bytes", lambda: pack(record("sweep_result", values=[b"x"])), JobResult, "range"),
    (
        "chunk over CHUNK",
        lambda: pack(record("recording_chunk", data=bytes(CHUNK + 1))),
        RecordingChunk,
        "range",
    ),
    ("chunk as text", lambda: pack(record("recording_chunk", data="TSF")), RecordingChunk, "range"),
    ("short hash", lambda: pack(record("match_done", sha256="ab" * 31)), MatchDone, "range"),
    ("offer of a seat 'x y'", lambda: pack(record("match_offer", bait="x y")), MatchOffer, "range"),
    ("order into folder '../x'", lambda: pack(record("match_order", folder="../x")), MatchOrder, "range"),
    (
        "config spawn",
        lambda: pack(record("start", config=config_with(bait_spawn=["a", None, []]))),
        Start,
        "range",
    ),
    (
        "counter values",
        lambda: pack(record("summary", counters={"bait": b"x", "shooter": 1})),
        Summary,
        "range",
    ),
]


def config_with(**changes: Any) -> dict:
    return {**GameConfig().to_dict(), **changes}


@pytest.mark.parametrize(("data", "expected", "code"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_input_reason(data: Callable[[], bytes], expected: type[Message] | None, code: str) -> None:
    payload = data()
    assert reason(payload, expected) == code
    if expected is not None and code != "type":  # the same bytes fail the same way untyped
        assert reason(payload) == code


def test_message_error_is_value_error() -> None:
    error = MessageError("range", "bad")
    assert isinstance(error, ValueError) and error.reason == "range" and str(error) == "range: bad"


# ---------------------------------------------------------------------------------------- fuzzing

SCALARS = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=20)
    | st.binary(max_size=20)
)
PACKABLE = st.recursive(
    SCALARS,
    lambda inner: (
        st.lists(inner, max_size=6)
        | st.dictionaries(st.text(max_size=8) | st.binary(max_size=4) | st.integers(-9, 9), inner, max_size=6)
    ),
    max_leaves=30,
)
ENVELOPE = {"v", "type", "match", "sweep", "host", "frame", "sender"}
FIELDS = sorted(ENVELOPE | {n for t in TYPES.values() for n in t.CHECKS})


def only_message_errors(data: bytes) -> None:
    """Every decoder either returns a message that re-encodes to itself or raises MessageError."""
    for expected in (None, *TYPES.values()):
        try:
            message = decode(data, expected) if expected else decode_any(data)
        except MessageError:
            continue
        assert decode(message.encode(), type(message)).encode() == message.encode()


@FUZZ
@given(st.binary(max_size=300))
def test_fuzz_bytes(data: bytes) -> None:
    only_message_errors(data)


@FUZZ
@given(PACKABLE)
def test_fuzz_structures(value: Any) -> None:
    only_message_errors(pack(value))


@FUZZ
@given(st.sampled_from(sorted(TYPES)), st.dictionaries(st.sampled_from(FIELDS), PACKABLE, max_size=4))
def test_fuzz_near_valid(kind: str, changes: dict) -> None:
    """Valid records with a few fields replaced by anything: reaches every field check."""
    only_message_errors(pack({**record(kind), **changes}))
