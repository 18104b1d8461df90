"""Every message type on the bus: versioned msgpack records, validated where they enter a service.

Each record is a map with the envelope `v` (SCHEMA_VERSION), `type`, `frame`, `sender`, the id of
what it belongs to, named for what it holds (`match`, `sweep` or `host`: the type's `ID`), and the
type's own fields. `decode(data, Type)` checks type, shape and ranges and returns the
dataclass, or raises `MessageError` whose `reason` is a short, stable code that services count and
log once per reason. docs/contract.md lists the fields.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import hmac
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import msgpack

from shared import keys
from shared.checks import (
    Check,
    boolean,
    keyed,
    matching,
    named,
    number,
    one_of,
    plain,
    rows,
    vector,
    whole,
)
from shared.game import (
    DEATH_CAUSES,
    EVENT_KINDS,
    FRAMES,
    N_ACTIONS,
    OBS_SIZE,
    ROLES,
    SEEDS,
    GameConfig,
    Range,
)
from shared.secret import same_secret, signature

SCHEMA_VERSION = 2
MAX_BYTES = 64 * 1024
MAX_FRAME = 10**9
JOB_SEEDS = Range(1, 1000)  # games of one job (tsf sweep --chunk)
JOB_VALUES = 10_000  # values in one job's result


class MessageError(ValueError):
    """A message that does not meet the contract. `reason` is a short code for counting."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def printable(text: str, most: int) -> str:
    """`text` as a message's free-text field takes it: printable ASCII (others become ?), at most
    `most` characters; for reasons and errors that may hold anything a user's code raised."""
    return "".join(c if " " <= c <= "~" else "?" for c in text)[:most]


_ROLE = one_of(ROLES)
_ROLE_OR_NONE = one_of(("", *ROLES))
# A policy's name in messages: a key, an adaptive agent's name, a plug-in's (services/agent/outside.py).
NAME_MOST = 64  # characters of a policy's or an adaptive agent's name that a message carries
POLICY_NAME = rf"[A-Za-z0-9_.:-]{{1,{NAME_MOST}}}"
_KEY = matching(POLICY_NAME)
_KEY_OR_NONE = matching(f"(?:{POLICY_NAME})?")
_ACTION = whole(0, N_ACTIONS - 1)
_SENDER = matching(r"[A-Za-z0-9_.:/-]{1,64}")
_ID = matching(r"[A-Za-z0-9_-]{1,64}")  # a match, sweep or host id: one key chunk (keys.check_match)


@dataclass(frozen=True, kw_only=True)
class Message:
    """The envelope every message carries. Each type adds the id of what it belongs to, named `ID`
    for what it holds: through its family (MatchMessage, JobMessage) or itself (HostStatus). Every
    message is built by keyword: with up to a dozen fields, a positional call would silently accept
    fields in the wrong order."""

    TYPE: ClassVar[str] = ""
    ID: ClassVar[str] = ""
    CHECKS: ClassVar[dict[str, Check]] = {}
    # Fields the type gained after its first version: a record written before lacks them and reads
    # with the field's default (docs/contract.md, "Versions"); every other field is required.
    ADDED: ClassVar[frozenset[str]] = frozenset()

    frame: int
    sender: str

    def encode(self) -> bytes:
        record = {"v": SCHEMA_VERSION, "type": self.TYPE}
        record.update((f.name, getattr(self, f.name)) for f in dataclasses.fields(self))
        return msgpack.packb(record, use_bin_type=True)


@dataclass(frozen=True, kw_only=True)
class MatchMessage(Message):
    """A message about one match: its traffic, and a study server's and a match host's about it."""

    ID: ClassVar[str] = "match"

    match: str


@dataclass(frozen=True, kw_only=True)
class JobMessage(Message):
    """A message of the job system, within one sweep (one run of jobs: a table or an evaluation)."""

    ID: ClassVar[str] = "sweep"

    sweep: str


@dataclass(frozen=True, kw_only=True)
class State(MatchMessage):
    """One frame of the game, published by the sim after stepping.

    `obs` holds each role's world-view observation values (float64, docs/observation.md), from
    which agents build their policy's input; `snapshot` holds what a viewer or the recorder needs
    beyond them: ships [x, y, vx, vy, heading, alive], fortress [facing, alive, vulnerable, lock,
    since_shell], every missile [x, y, vx, vy, owner] and shell [x, y, vx, vy]."""

    TYPE: ClassVar[str] = "state"
    CHECKS: ClassVar[dict[str, Check]] = {
        "obs": keyed(ROLES, vector(OBS_SIZE)),
        "ships": rows(6, 2),
        "fortress": vector(5),
        "missiles": rows(5, 64),
        "shells": rows(4, 256),
        "kills": whole(0, MAX_FRAME),
        "points": whole(-(10**9), 10**9),
        "frames": whole(1, MAX_FRAME),
        "hash": matching(r"[0-9a-f]{16}"),
        "applied": lambda v: isinstance(v, list) and len(v) == 2 and all(_ACTION(a) for a in v),
        "sent_ns": whole(0, 2**63),
    }

    obs: dict[str, list[float]] = field(default_factory=dict)
    ships: list[list[float]] = field(default_factory=list)
    fortress: list[float] = field(default_factory=list)
    missiles: list[list[float]] = field(default_factory=list)
    shells: list[list[float]] = field(default_factory=list)
    kills: int = 0
    points: int = 0
    frames: int = 1
    hash: str = "0" * 16
    applied: list[int] = field(default_factory=lambda: [0, 0])  # the actions that led to this frame
    sent_ns: int = 0

    @property
    def last(self) -> bool:
        """The game's last state: the sim applies no answer to it, so no seat sends one (a late
        answer would reach the recording or not by timing)."""
        return self.frame >= self.frames


@dataclass(frozen=True, kw_only=True)
class Action(MatchMessage):
    """A player's action for the state of `frame`, from an agent (`policy` = its key) or a human.
    `failures` counts the frames of this match on which the seat's policy raised or answered no
    action (it played no-op then); `failure` says why, on the frame it happened, else ""."""

    TYPE: ClassVar[str] = "action"
    CHECKS: ClassVar[dict[str, Check]] = {
        "role": _ROLE,
        "action": _ACTION,
        "policy": _KEY_OR_NONE,
        "failures": whole(0, MAX_FRAME),
        "failure": matching(r"[ -~]{0,200}"),
    }
    ADDED: ClassVar[frozenset[str]] = frozenset(("failures", "failure"))  # with policy failures

    role: str = "bait"
    action: int = 0
    policy: str = ""
    failures: int = 0
    failure: str = ""


@dataclass(frozen=True, kw_only=True)
class PolicySwitch(MatchMessage):
    """Tells the agent of `role` to play library policy `policy` from the next frame on."""

    TYPE: ClassVar[str] = "policy"
    CHECKS: ClassVar[dict[str, Check]] = {"role": _ROLE, "policy": _KEY, "reason": matching(r"[ -~]{0,200}")}

    role: str = "bait"
    policy: str = "circle"
    reason: str = ""


@dataclass(frozen=True, kw_only=True)
class Ruling(MatchMessage):
    """The adapter's ruling on the scoring frame `frame` (shared.game.scoring): the agent of `role`
    plays `policy` from the next frame on ("" before the adapter has an estimate: it goes on with
    what it plays); `partner` is the estimate ("" while the window fills). Put on every scoring
    frame but the game's last answered one (no seat answers the state after it), a switch or not:
    in a lockstep match the adaptive seat answers the next state only once it has it
    (services/agent/gate.py), so a switch plays from the same frame on every run, the frame the
    in-process evaluation gives."""

    TYPE: ClassVar[str] = "ruling"
    CHECKS: ClassVar[dict[str, Check]] = {"role": _ROLE, "policy": _KEY_OR_NONE, "partner": _KEY_OR_NONE}

    role: str = "bait"
    policy: str = ""
    partner: str = ""


@dataclass(frozen=True, kw_only=True)
class GameEvent(MatchMessage):
    """Something that happened in a frame (services/sim/engine.py Event), or the match's start/end."""

    TYPE: ClassVar[str] = "event"
    CHECKS: ClassVar[dict[str, Check]] = {
        "kind": one_of(EVENT_KINDS),
        "role": _ROLE_OR_NONE,
        "detail": matching(r"[ -~]{0,200}"),
    }

    kind: str = "kill"
    role: str = ""
    detail: str = ""


_COUNT = whole(0, MAX_FRAME)
_SEED = whole(SEEDS.low, SEEDS.high)


def _counters(v: Any) -> bool:
    """One player's counters, shaped as services.sim.engine.Counters.to_dict()."""
    plain = ("kills", "missiles_fired", "shield_hits", "frames_in_region", "frames_locked")
    return (
        isinstance(v, dict)
        and set(v) == {*plain, "deaths"}
        and all(_COUNT(v[k]) for k in plain)
        and keyed(DEATH_CAUSES, _COUNT)(v["deaths"])
    )


def _config(value: Any) -> bool:
    try:
        GameConfig.from_dict(value)
    except (TypeError, ValueError):
        return False
    return True


@dataclass(frozen=True, kw_only=True)
class Start(MatchMessage):
    """The match's set-up, published by the sim when it starts: enough to replay it."""

    TYPE: ClassVar[str] = "start"
    CHECKS: ClassVar[dict[str, Check]] = {
        "seed": _SEED,
        "mode": one_of(("realtime", "lockstep")),
        "config": _config,
        "policies": keyed(ROLES, _KEY_OR_NONE),
    }

    seed: int = 0
    mode: str = "realtime"
    config: dict = field(default_factory=dict)
    policies: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True, kw_only=True)
class Summary(MatchMessage):
    """The match result, published once by the sim when the match ends."""

    TYPE: ClassVar[str] = "summary"
    CHECKS: ClassVar[dict[str, Check]] = {
        "kills": whole(0, MAX_FRAME),
        "kills_per_minute": number(0.0),
        "points": whole(-(10**9), 10**9),
        "counters": keyed(ROLES, _counters),
        "timing": named(number()),
        "drops": named(whole(0, 2**63)),
        "failures": lambda v: isinstance(v, dict) and set(v) <= set(ROLES) and all(map(_COUNT, v.values())),
    }
    ADDED: ClassVar[frozenset[str]] = frozenset(("failures",))  # with policy failures

    kills: int = 0
    kills_per_minute: float = 0.0
    points: int = 0
    counters: dict = field(default_factory=dict)
    drops: dict[str, int] = field(default_factory=dict)  # bad input the sim dropped, by reason
    timing: dict[str, float] = field(default_factory=dict)  # round trip and tick jitter, ms
    failures: dict[str, int] = field(default_factory=dict)  # frames a seat's policy failed, by seat


# An adaptive strategy's name as the wire carries it (AdapterStatus.strategy): every strategy
# AdapterConfig allows is checked against this at import (services/population/adaptive.py).
STRATEGY_NAME = re.compile(r"[a-z-]{1,32}")


@dataclass(frozen=True, kw_only=True)
class AdapterStatus(MatchMessage):
    """The adapter's view of the partner, published with each ruling whose batch changed it (every
    SCORE_FRAMES frames of the match) and at the match's end.

    `role` is the adaptive agent's seat (the partner plays the other); `scores` holds the CEM
    similarity (mean log-probability over the window) of each library policy of the partner's role;
    `belief` the posterior over partner types where the strategy keeps one (else empty);
    `partner` the estimated type ("" while the window fills); `policy` what our agent plays."""

    TYPE: ClassVar[str] = "adapter"
    CHECKS: ClassVar[dict[str, Check]] = {
        "role": _ROLE,
        "strategy": matching(STRATEGY_NAME.pattern),
        "window": whole(1, 100_000),
        "filled": whole(0, 100_000),
        "partner": _KEY_OR_NONE,
        "policy": _KEY,
        "scores": named(number(-1e6, 0.0)),
        "belief": named(number(0.0, 1.0)),
        "out_of_library": boolean,
    }

    role: str
    strategy: str
    window: int
    filled: int
    partner: str
    policy: str
    scores: dict[str, float] = field(default_factory=dict)
    belief: dict[str, float] = field(default_factory=dict)
    out_of_library: bool = False


_HASH = matching(r"[0-9a-f]{16}")


JOB_KINDS = (
    "table",
    "team",
    "session",
    "identify",
    "calibrate",
    "pairs",
    "train",
)  # what a job computes (services/jobs/kinds.py)
_JOB_ID = matching(r"[A-Za-z0-9_.-]{1,64}")
_PLUGIN = matching(r"[A-Za-z_][A-Za-z0-9_.]{0,100}:[A-Za-z_][A-Za-z0-9_.]{0,60}")


@dataclass(frozen=True, kw_only=True)
class JobOrder(JobMessage):
    """A coordinator's job for one worker slot: one piece of a bulk computation (a table cell's
    games, a batch of evaluation games, sessions, identification runs), its `kind` saying which.
    `args` are the kind's arguments; `plugins` the `module:attr`
    partners or policies it needs imported; `library` and `config` the hashes the worker's own copies
    must have; `batch` the jobs handed to the worker at once, this one among them (sent back to back,
    played together)."""

    TYPE: ClassVar[str] = "sweep_job"
    CHECKS: ClassVar[dict[str, Check]] = {
        "job": _JOB_ID,
        "kind": one_of(JOB_KINDS),
        "batch": whole(1, 100_000),
        "args": lambda v: isinstance(v, dict) and plain()(v),
        "plugins": lambda v: isinstance(v, list) and len(v) <= 16 and all(_PLUGIN(x) for x in v),
        "library": _HASH,
        "config": _HASH,
    }

    job: str = ""
    kind: str = "table"
    batch: int = 1
    args: dict[str, Any] = field(default_factory=dict)
    plugins: list[str] = field(default_factory=list)
    library: str = "0" * 16
    config: str = "0" * 16


FAULTS = ("", "worker", "job")  # whose fault a failed job is ("" for a result)


@dataclass(frozen=True, kw_only=True)
class JobResult(JobMessage):
    """A worker's answer to a job: the kind's values, or why it could not run it, with whose
    `fault` that is: "worker" when this worker cannot (other library, rules or a plug-in missing:
    no more jobs of the sweep go to it, others may run it), "job" when the job itself failed and
    would fail anywhere (the run ends). `library` and `config` are the hashes it computed with,
    checked on arrival as on every journal line."""

    TYPE: ClassVar[str] = "sweep_result"
    CHECKS: ClassVar[dict[str, Check]] = {
        "job": _JOB_ID,
        "values": lambda v: isinstance(v, list) and len(v) <= JOB_VALUES and plain()(v),
        "error": matching(r"[ -~]{0,300}"),
        "fault": one_of(FAULTS),
        "seconds": number(0.0),
        "library": _HASH,
        "config": _HASH,
    }

    job: str = ""
    values: list[Any] = field(default_factory=list)
    error: str = ""
    fault: str = ""
    seconds: float = 0.0
    library: str = "0" * 16
    config: str = "0" * 16


CHUNK = 48 * 1024  # bytes of a recording in one RecordingChunk (a message stays under MAX_BYTES)
_WAIT = number(0.0, 24 * 3600.0)
_SHA256 = matching(r"[0-9a-f]{64}")
_AUTH = matching(r"(?:[0-9a-f]{64})?")  # a host message's HMAC (sealed), "" before it is sealed


@dataclass(frozen=True, kw_only=True)
class HostStatus(Message):
    """A match host's capacity, put every second while it runs: the one message a host puts about
    itself rather than about one of its matches, so its id is the host's name."""

    TYPE: ClassVar[str] = "host_status"
    ID: ClassVar[str] = "host"
    CHECKS: ClassVar[dict[str, Check]] = {"slots": whole(0, 1024), "free": whole(0, 1024), "auth": _AUTH}

    host: str
    slots: int = 1
    free: int = 1
    auth: str = ""


@dataclass(frozen=True, kw_only=True)
class MatchOffer(MatchMessage):
    """A study server asks a match host to run a match: its seats (a policy key, `human` for a seat
    the server plays over the router, "" for the adaptive seat), the adaptive agent's name if any,
    how long the sim waits for the players and how long the whole match may take. `library` and
    `config` are the hashes the host's own copies must have: of all it may play and adapt by
    (library.play_hash), and of the rules."""

    TYPE: ClassVar[str] = "match_offer"
    CHECKS: ClassVar[dict[str, Check]] = {
        "seed": _SEED,
        "frames": whole(FRAMES.low, FRAMES.high),
        "bait": _KEY_OR_NONE,
        "shooter": _KEY_OR_NONE,
        "adapter": matching(f"(?:{POLICY_NAME})?"),
        "wait_players": _WAIT,
        "timeout": _WAIT,
        "library": _HASH,
        "config": _HASH,
        "auth": _AUTH,
    }

    seed: int = 0
    frames: int = 1800
    bait: str = ""
    shooter: str = ""
    adapter: str = ""
    wait_players: float = 10.0
    timeout: float = 0.0
    library: str = "0" * 16
    config: str = "0" * 16
    auth: str = ""


@dataclass(frozen=True, kw_only=True)
class MatchAnswer(MatchMessage):
    """A match host's reply to an offer: accepted, or why not (full, other library, ...)."""

    TYPE: ClassVar[str] = "match_answer"
    CHECKS: ClassVar[dict[str, Check]] = {
        "accepted": boolean,
        "reason": matching(r"[ -~]{0,300}"),
        "auth": _AUTH,
    }

    accepted: bool = False
    reason: str = ""
    auth: str = ""


@dataclass(frozen=True, kw_only=True)
class MatchStop(MatchMessage):
    """A study server asks the match host to end `match` now (the participant left, or it ran late)."""

    TYPE: ClassVar[str] = "match_stop"
    CHECKS: ClassVar[dict[str, Check]] = {"auth": _AUTH}

    auth: str = ""


@dataclass(frozen=True, kw_only=True)
class MatchOrder(MatchMessage):
    """A launcher asks a pool's services (long-lived, many matches each) to play a match: what its
    own command lines would say to a match's own processes. `bait`/`shooter` are the policies the
    agent service starts each seat with ("" for a seat no agent plays: a person's), `names` what
    the Start record calls each seat, `adaptive` the seat the adapter service adapts with the
    adaptive agent `adapter` ("" for none), `wait_players` and `wait_services` the sim's waits
    before the first frame (for the seats; for the recorder and the adapter), `folder` the
    recording's folder under the recorder's own ("" for that one)."""

    TYPE: ClassVar[str] = "match_order"
    CHECKS: ClassVar[dict[str, Check]] = {
        "seed": _SEED,
        "frames": whole(FRAMES.low, FRAMES.high),
        "mode": one_of(("realtime", "lockstep")),
        "bait": _KEY_OR_NONE,
        "shooter": _KEY_OR_NONE,
        "names": keyed(ROLES, _KEY),
        "adapter": matching(f"(?:{POLICY_NAME})?"),
        "adaptive": _ROLE_OR_NONE,
        "wait_players": _WAIT,
        "wait_services": _WAIT,
        "folder": matching(r"[A-Za-z0-9_-]{0,64}"),
    }

    seed: int = 0
    frames: int = 1800
    mode: str = "realtime"
    bait: str = ""
    shooter: str = ""
    names: dict[str, str] = field(default_factory=dict)
    adapter: str = ""
    adaptive: str = ""
    wait_players: float = 10.0
    wait_services: float = 10.0
    folder: str = ""

    def policy(self, role: str) -> str:
        """The policy the agent service starts `role`'s seat with; "" for a seat it does not play."""
        return self.bait if role == "bait" else self.shooter


@dataclass(frozen=True, kw_only=True)
class MatchDone(MatchMessage):
    """A match host's match has ended: `error` says why it failed ("" if it did not, or if only its
    recording is incomplete: the server judges the recording it fetches), and `size` and `sha256`
    describe its recording (size 0: none), which the server then fetches in chunks."""

    TYPE: ClassVar[str] = "match_done"
    CHECKS: ClassVar[dict[str, Check]] = {
        "error": matching(r"[ -~]{0,300}"),
        "size": whole(0, 2**40),
        "sha256": lambda v: v == "" or _SHA256(v),
        "auth": _AUTH,
    }

    error: str = ""
    size: int = 0
    sha256: str = ""
    auth: str = ""


@dataclass(frozen=True, kw_only=True)
class MatchRefused(MatchMessage):
    """A pool's service cannot play its part of an ordered match (an agent whose policy does not
    load: its weights file gone): it says so at once, on tsf/pool/<pool>/refused, so that the
    launcher fails the match now with this `reason` instead of waiting for a token that never
    comes. `service` is the one that refused (`agent`, `adapter`, `recorder`, `sim`)."""

    TYPE: ClassVar[str] = "match_refused"
    CHECKS: ClassVar[dict[str, Check]] = {
        "service": one_of(keys.SERVICES),
        "reason": matching(r"[ -~]{0,300}"),
    }

    service: str = "agent"
    reason: str = ""


@dataclass(frozen=True, kw_only=True)
class RecordingChunk(MatchMessage):
    """A host's reply to a recording query: up to CHUNK bytes from `offset` of a `size`-byte file."""

    TYPE: ClassVar[str] = "recording_chunk"
    CHECKS: ClassVar[dict[str, Check]] = {
        "offset": whole(0, 2**40),
        "size": whole(0, 2**40),
        "data": lambda v: isinstance(v, bytes) and len(v) <= CHUNK,
        "auth": _AUTH,
    }

    offset: int = 0
    size: int = 0
    data: bytes = b""
    auth: str = ""


Sealed = TypeVar("Sealed", bound=Message)  # one of the six above, each with its `auth`


def sealed(message: Sealed, secret: bytes) -> Sealed:
    """A match-host message signed with the study's host secret: its `auth` is the HMAC-SHA256 of
    its encoding with `auth` empty, so a peer without the secret can neither make one nor alter one."""
    return dataclasses.replace(message, auth=_seal(message, secret))


def authentic(message: Sealed, secret: bytes) -> bool:
    """Whether `message` was sealed with `secret` (compared as bytes)."""
    return same_secret(message.auth, _seal(message, secret))


def _seal(message: Sealed, secret: bytes) -> str:
    unsealed = dataclasses.replace(message, auth="").encode()
    return hmac.new(secret, unsealed, hashlib.sha256).hexdigest()


def recording_query(key: str, offset: int, secret: bytes) -> str:
    """The selector that asks a host for a chunk of a recording (`key`: keys.host_recording) from
    `offset`, signed: `auth` is `recording_auth`."""
    return f"{key}?offset={offset};auth={recording_auth(key, str(offset), secret)}"


def recording_auth(key: str, offset: str, secret: bytes) -> str:
    """The HMAC-SHA256 of a recording query's selector without its `auth` (`key?offset=N`)."""
    return signature(secret, f"{key}?offset={offset}")


TYPES: dict[str, type[Message]] = {
    t.TYPE: t
    for t in (
        Start, State, Action, PolicySwitch, Ruling, GameEvent, Summary, AdapterStatus, JobOrder, JobResult,
        HostStatus, MatchOffer, MatchAnswer, MatchStop, MatchDone, RecordingChunk, MatchOrder, MatchRefused,
    )
}  # fmt: skip
# Version 1 named every family's id `match`: for a match's own traffic, what a recording holds, that
# is still its name, so old recordings load. A live job or host peer of version 1 is refused
# (`version`): it would refuse this version's answers, and a sealed message's seal covers its
# version.
RECORDED = frozenset((Start, State, Action, PolicySwitch, Ruling, GameEvent, Summary, AdapterStatus))
_ENVELOPE: dict[str, Check] = {"frame": whole(0, MAX_FRAME), "sender": _SENDER}
M = TypeVar("M", bound=Message)


def decode(data: bytes | bytearray | memoryview, expected: type[M]) -> M:
    """Bytes from the bus -> a validated message of the expected type, or MessageError."""
    return _build(_unpack(data), expected)


def decode_seat_action(data: bytes | bytearray | memoryview, key: str, match: str) -> Action:
    """An action that arrived on `key` (tsf/<match>/action/<role>): valid, of this match, and of
    the seat the key names; else MessageError (a spoofed or misrouted action is a `mismatch`)."""
    action = decode(data, Action)
    try:
        seat = keys.parse(key).role
    except ValueError:
        seat = ""
    if action.match != match or seat != action.role:
        raise MessageError("mismatch", f"{action.role} action for {action.match} on {key}")
    return action


def seat_actions(match: str) -> Callable[[bytes | bytearray | memoryview, str], Action]:
    """decode_seat_action for one match, as a subscriber's decoder (shared.bus.subscribe)."""
    return lambda data, key: decode_seat_action(data, key, match)


def decode_any(data: bytes | bytearray | memoryview) -> Message:
    """Bytes -> a validated message of whichever known type it declares (for the recorder)."""
    record = _unpack(data)
    kind = record.get("type")
    if not isinstance(kind, str) or kind not in TYPES:  # a list or map here is unhashable
        raise MessageError("type", f"unknown message type {kind!r}")
    return _build(record, TYPES[kind])


def _unpack(data: bytes | bytearray | memoryview) -> dict:
    if len(data) > MAX_BYTES:
        raise MessageError("too_large", f"{len(data)} bytes > {MAX_BYTES}")
    try:
        record = msgpack.unpackb(bytes(data), raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types for garbage
        raise MessageError("undecodable", f"not msgpack: {type(exc).__name__}") from None
    if not isinstance(record, dict):
        raise MessageError("shape", f"expected a map, got {type(record).__name__}")
    if type(record.get("v")) is not int or record["v"] not in (1, SCHEMA_VERSION):
        raise MessageError("version", f"schema version {record.get('v')!r}, expected {SCHEMA_VERSION}")
    return record


@functools.cache
def _fields(kind: type[Message]) -> tuple[dict[str, Check], frozenset[str]]:
    """A type's checks, envelope included, and every field name a record of it may hold (built once:
    every message that enters a service passes here)."""
    checks = {**_ENVELOPE, kind.ID: _ID, **kind.CHECKS}
    return checks, frozenset((*checks, "v", "type"))


def _build(record: dict, expected: type[M]) -> M:
    if record.get("type") != expected.TYPE:
        raise MessageError("type", f"expected {expected.TYPE!r}, got {record.get('type')!r}")
    if record["v"] != SCHEMA_VERSION and expected not in RECORDED:
        raise MessageError(
            "version", f"{expected.TYPE} of schema version {record['v']}, expected {SCHEMA_VERSION}"
        )
    checks, names = _fields(expected)
    if not names.issuperset(record):
        raise MessageError("shape", f"unexpected fields {sorted(set(record) - names)}")
    for name, check in checks.items():
        if name not in record:
            if name in expected.ADDED:
                continue
            raise MessageError("shape", f"missing field {name!r}")
        if not check(record[name]):
            raise MessageError("range", f"bad {expected.TYPE}.{name}: {str(record[name])[:80]}")
    return expected(**{name: record[name] for name in checks if name in record})
