"""The page's contract: every WebSocket message between a browser (or a stand-in) and the human
gateway, the study server or its dashboard, typed and validated as the bus messages are
(shared/messages.py), defined once here.

Messages are JSON objects with `type` and the type's own fields. Up (page -> server) messages are
validated where they enter the server (`decode(text, allowed)`: at most MAX_MESSAGE bytes, only the
types expected then, every field checked; a `PageError` with a short reason otherwise); down
(server -> page) messages are built from these types (`encode()`), and a client reads them with
`decode_down` (services/study/standin.py does). The page itself (services/human/static/*.js)
reads the same definitions: `CONTRACT`, generated into services/human/static/contract.js, which
the page loads before its script; tests/test_page_contract.py checks that file, and that every
message the scripts handle or send, and every field they read or write, is one of them.
docs/contract.md lists them.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar, TypeVar

from shared import checks
from shared.checks import boolean, list_of, named, number, or_none, text, whole
from shared.game import EVENT_KINDS, ROLES

MAX_MESSAGE = 1024  # bytes: the largest message a browser has reason to send (a hello with its link)
KEYS = ("left", "right", "thrust", "fire")
LINK_PARAMS = 6  # the link's parameters a study's hello may carry
GEOMETRY = (
    "fps", "frames", "arena_x", "arena_y", "fortress_radius", "shield_radius", "region_radius",
    "ship_radius", "missile_radius", "shell_radius", "rear_arc",
)  # fmt: skip  # the numbers the page draws with (GameConfig's)


class PageError(ValueError):
    """A message that does not meet the page's contract; `reason` is a short code for counting."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


_SHORT = text(64, 1)  # an id, a token, a key, a link's value
_ROLE = lambda v: v in ROLES  # noqa: E731 - a check like the others
_NUMBERS = list_of(number(), 64)
_ROWS = list_of(list_of(number(), 8), 512)
_POINTS = or_none(named(whole()))


@dataclass(frozen=True, kw_only=True)
class PageMessage:
    """A page message: its `TYPE`, its direction (`UP`: page -> server) and its fields' checks;
    `OPTIONAL` fields may be left out (None then), every other is required."""

    TYPE: ClassVar[str] = ""
    UP: ClassVar[bool] = False
    CHECKS: ClassVar[dict[str, checks.Check]] = {}
    OPTIONAL: ClassVar[frozenset[str]] = frozenset()

    def encode(self) -> str:
        """The JSON text frame (optional fields left out when None)."""
        fields = ((f.name, getattr(self, f.name)) for f in dataclasses.fields(self))
        shown = {name: value for name, value in fields if value is not None or name not in self.OPTIONAL}
        return json.dumps({"type": self.TYPE, **shown}, separators=(",", ":"))


_ALL: list[type[PageMessage]] = []  # every type, in the order defined: each registered by _message


def _message(
    kind: str, up: bool, fields: dict[str, checks.Check], optional: tuple[str, ...] = ()
) -> Callable:
    """Give a PageMessage class its TYPE, direction and checks, and register it (UP and DOWN,
    the page's CONTRACT, are built from every type so registered)."""

    def decorate(cls: type) -> type:
        cls.TYPE, cls.UP, cls.CHECKS, cls.OPTIONAL = kind, up, fields, frozenset(optional)
        message = dataclass(frozen=True, kw_only=True)(cls)
        _ALL.append(message)
        return message

    return decorate


# Up: page -> gateway, study server, dashboard.


@_message("join", True, {"role": _ROLE, "token": _SHORT, "obs": boolean}, ("obs",))
class Join(PageMessage):
    """The first message of a seat's link (`tsf play`): the seat and its token; `obs` asks for the
    seat's observation values too (a scripted player's)."""

    role: str
    token: str
    obs: bool | None = None


@_message("watch", True, {"token": _SHORT, "match": _SHORT}, ("token", "match"))
class Watch(PageMessage):
    """Or first: watch a match, playing no seat (the dashboard's spectator names the match and
    shows its token)."""

    token: str | None = None
    match: str | None = None


@_message("dashboard", True, {"token": _SHORT}, ("token",))
class DashboardHello(PageMessage):
    """The dashboard's first message: its token (services/study/dashboard.py)."""

    token: str | None = None


@_message("ready", True, {})
class Ready(PageMessage):
    """The instructions are read: play."""


@_message("keys", True, dict.fromkeys(KEYS, boolean))
class Keys(PageMessage):
    """The held keys, sent on every change."""

    left: bool
    right: bool
    thrust: bool
    fire: bool


def _link(v: object) -> bool:
    """The link's parameters (services/study/crowd.py): a few names and values, each short."""
    return isinstance(v, dict) and len(v) <= LINK_PARAMS and all(map(_SHORT, [*v, *v.values()]))


HELLO = ("participant", "key", "obs", "worker", "sig", "test", "link")


@_message(
    "hello", True,
    {"participant": _SHORT, "key": _SHORT, "obs": boolean, "worker": _SHORT, "sig": _SHORT, "test": _SHORT,
     "link": _link},
    HELLO,
)  # fmt: skip
class Hello(PageMessage):
    """The study's first message: a participant's id and resume key to resume, or a new arrival's
    worker id, its signature and the link's other parameters; `test` and `obs` for stand-ins."""

    participant: str | None = None
    key: str | None = None
    obs: bool | None = None
    worker: str | None = None
    sig: str | None = None
    test: str | None = None
    link: dict[str, str] | None = None


@_message("consent", True, {})
class Consent(PageMessage):
    """The participant agrees to the consent text."""


@_message("decline", True, {})
class Decline(PageMessage):
    """The participant does not agree."""


@_message("answer", True, {"answer": _SHORT})
class Answer(PageMessage):
    """The button clicked in an attention check."""

    answer: str


# Down: gateway -> page.

_GEOMETRY = {name: number() for name in GEOMETRY}


@_message("welcome", False, {"match": _SHORT, "role": or_none(_ROLE), **_GEOMETRY, "points": _POINTS})
class Welcome(PageMessage):
    """A seat taken (or, role None, a spectator): the match, the arena's geometry, how points
    count (None: not shown)."""

    match: str
    role: str | None
    fps: int
    frames: int
    arena_x: float
    arena_y: float
    fortress_radius: float
    shield_radius: float
    region_radius: float
    ship_radius: float
    missile_radius: float
    shell_radius: float
    rear_arc: float
    points: dict[str, int] | None = None


@_message("refused", False, {"reason": text(400)})
class Refused(PageMessage):
    """Why the page cannot go on (and, in a study, whom to contact); the socket closes."""

    reason: str


@_message("setup", False, _GEOMETRY)
class Setup(PageMessage):
    """The match's own numbers, when it starts."""

    fps: int
    frames: int
    arena_x: float
    arena_y: float
    fortress_radius: float
    shield_radius: float
    region_radius: float
    ship_radius: float
    missile_radius: float
    shell_radius: float
    rear_arc: float


@_message(
    "state", False,
    {"frame": whole(0), "frames": whole(1), "ships": _ROWS, "fortress": _NUMBERS, "missiles": _ROWS,
     "shells": _ROWS, "kills": whole(0), "points": whole(), "applied": list_of(whole(0, 11), 2),
     "respawn": or_none(whole(0)), "ending": boolean, "obs": or_none(_NUMBERS)},
    ("obs",),
)  # fmt: skip
class StateView(PageMessage):
    """One frame to draw: ships [x, y, heading, alive], the fortress [facing, alive, vulnerable,
    lock], missiles [x, y, owner], shells [x, y], the actions that led to it, and what it means
    for the person (services/human/core.py Narrator): `respawn`, frames until both ships come back
    (None while one lives), `ending`, the partner agent ending a stalled round; `obs` the seat's
    observation values, for stand-ins that show the test token."""

    frame: int
    frames: int
    ships: list
    fortress: list
    missiles: list
    shells: list
    kills: int
    points: int
    applied: list[int]
    respawn: int | None
    ending: bool
    obs: list[float] | None = None


@_message(
    "event", False,
    {"frame": whole(0), "kind": lambda v: v in EVENT_KINDS, "role": lambda v: v in ("", *ROLES),
     "detail": text(200)},
)  # fmt: skip
class EventView(PageMessage):
    """A kill, death (its cause in `detail`), shield hit or respawn, as it happens."""

    frame: int
    kind: str
    role: str
    detail: str


@_message(
    "end", False,
    {"kills": whole(0), "kills_per_minute": number(), "points": whole(), "frame": whole(0),
     "frames": whole(1)},
)  # fmt: skip
class End(PageMessage):
    """The match's result; `frame` short of `frames`: it was stopped early (never "Time is up")."""

    kills: int
    kills_per_minute: float
    points: int
    frame: int
    frames: int


# Down: study server -> page (services/study/admission.py, visit.py, trial.py).

_TEXT = text(4000)


@_message("consent", False, {"text": _TEXT})
class ConsentText(PageMessage):
    """The consent text, with "I agree" and "I do not agree"."""

    text: str


@_message("declined", False, {"text": _TEXT})
class Declined(PageMessage):
    """The participant declined: nothing was recorded."""

    text: str


@_message("participant", False, {"participant": _SHORT, "key": _SHORT})
class ParticipantId(PageMessage):
    """The participant's id and resume key, kept by the browser."""

    participant: str
    key: str


@_message("check", False, {"text": _TEXT, "options": list_of(_SHORT, 8)})
class Check(PageMessage):
    """An attention check: its question and one button per option."""

    text: str
    options: list[str]


@_message("wait", False, {"reason": _TEXT, "seconds": whole(0)})
class Wait(PageMessage):
    """A game is being set up: why the page waits, and about how long."""

    reason: str
    seconds: int


@_message(
    "trial", False,
    {"role": _ROLE, "agent": text(64), "last": or_none(whole(0)), "session": whole(1), "sessions": whole(1),
     "trial": whole(1), "trials": whole(1), "again": boolean, "practice": boolean, "instructions": _TEXT,
     "points": _POINTS, "why": text(400)},
)  # fmt: skip
class Trial(PageMessage):
    """The next game: where it sits in the study, the partner's label, the last game's kills, whether
    it is played again and why (the last game failed, or was cut short by a reload or by the
    server's stop), the role's instructions ("" for the page's own) and how points count (None:
    hidden by the study)."""

    role: str
    agent: str
    last: int | None
    session: int
    sessions: int
    trial: int
    trials: int
    again: bool
    practice: bool
    instructions: str
    points: dict[str, int] | None
    why: str = ""  # the game is played again because ... ("" when it is not)


@_message("queue", False, {"place": whole(1), "wait": whole(0)})
class Queue(PageMessage):
    """Every game place is taken: the place in the queue and about how many seconds it waits."""

    place: int
    wait: int


@_message("done", False, {"text": _TEXT, "code": text(64), "redirect": text(2000)})
class Done(PageMessage):
    """The study is over for the participant: the end text, the completion code, the platform's
    address to go back to ("" for none)."""

    text: str
    code: str
    redirect: str


@_message("screened", False, {"text": _TEXT, "redirect": text(2000)})
class Screened(PageMessage):
    """Screened out by the attention checks: why, and the platform's address."""

    text: str
    redirect: str


@_message("problem", False, {"text": _TEXT})
class Problem(PageMessage):
    """A game could not be started, again and again: tell the experimenter."""

    text: str


@_message("stopped", False, {"text": _TEXT})
class Stopped(PageMessage):
    """The study server stops: progress is kept, and how to go on."""

    text: str


# Down: the dashboard (services/study/dashboard.py).


@_message("watching", False, {"match": _SHORT, "variant": text(64), "person": lambda v: v in ("", *ROLES)})
class Watching(PageMessage):
    """The spectator's match: its variant and the person's seat."""

    match: str
    variant: str
    person: str


_ROWS_OF_MAPS = list_of(lambda v: isinstance(v, dict), 100_000)


@_message(
    "study", False,
    {"study": _SHORT, "participants": _ROWS_OF_MAPS, "counts": lambda v: isinstance(v, dict),
     "queue": _ROWS_OF_MAPS, "matches": _ROWS_OF_MAPS, "hosts": _ROWS_OF_MAPS},
)  # fmt: skip
class Overview(PageMessage):
    """The dashboard's overview, once a second (services/study/dashboard.py overview)."""

    study: str
    participants: list[dict] = field(default_factory=list)
    counts: dict = field(default_factory=dict)
    queue: list[dict] = field(default_factory=list)
    matches: list[dict] = field(default_factory=list)
    hosts: list[dict] = field(default_factory=list)


UP: dict[str, type[PageMessage]] = {t.TYPE: t for t in _ALL if t.UP}
DOWN: dict[str, type[PageMessage]] = {t.TYPE: t for t in _ALL if not t.UP}
# What the page reads: each type's fields by direction, as services/human/static/contract.js holds it.
CONTRACT = {
    direction: {kind: [f.name for f in dataclasses.fields(t)] for kind, t in types.items()}
    for direction, types in (("up", UP), ("down", DOWN))
}
CONTRACT_JS = "services/human/static/contract.js"


def contract_js() -> str:
    """The page's copy of the contract, generated from the types above (`python -m shared.page >
    services/human/static/contract.js`; tests/test_page_contract.py checks it is this)."""
    return (
        "// Generated from shared/page.py (python -m shared.page): the page's messages and their fields,\n"
        "// up (page -> server) and down. Do not edit; tests/test_page_contract.py checks it.\n"
        f"const CONTRACT = Object.freeze({json.dumps(CONTRACT, indent=1)});\n"
    )


M = TypeVar("M", bound=PageMessage)


def decode(text: str | bytes, allowed: tuple[str, ...]) -> PageMessage:
    """A browser's text frame -> the validated up message, or PageError. `allowed`: the types
    accepted now (a join only first, keys only after it)."""
    if not isinstance(text, str):
        raise PageError("binary", "only text frames are accepted")
    if len(text.encode()) > MAX_MESSAGE:
        raise PageError("too_large", f"{len(text)} characters")
    return _build(text, UP, allowed)


def decode_down(text: str) -> PageMessage:
    """A server's text frame -> the validated down message, or PageError (a client's reading)."""
    return _build(text, DOWN, tuple(DOWN))


def _build(text: str, types: dict[str, type[PageMessage]], allowed: tuple[str, ...]) -> PageMessage:
    try:
        message = json.loads(text)
    except ValueError:
        raise PageError("undecodable", "not JSON") from None
    if not isinstance(message, dict) or message.get("type") not in allowed or message["type"] not in types:
        kind = message.get("type") if isinstance(message, dict) else type(message).__name__
        raise PageError("type", f"{kind!r} where {allowed} was expected")
    kind = types[message.pop("type")]
    if not set(message) <= set(kind.CHECKS):
        raise PageError("shape", f"{kind.TYPE}: unexpected fields {sorted(set(message) - set(kind.CHECKS))}")
    for name, check in kind.CHECKS.items():
        if name not in message and name not in kind.OPTIONAL:
            raise PageError("shape", f"{kind.TYPE}: missing field {name!r}")
        if name in message and not check(message[name]):
            raise PageError("shape", f"bad {kind.TYPE} message ({name})")
    return kind(**message)


if __name__ == "__main__":
    print(contract_js(), end="")
