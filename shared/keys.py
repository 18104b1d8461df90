"""Every zenoh key expression of the system, namespaced by match id. Nothing else builds keys.

tsf/<match>/state                 sim -> all       one State per frame
tsf/<match>/action/<role>         agent or human -> sim, one Action per state
tsf/<match>/policy/<role>         adapter or operator -> agent: which library policy to play
tsf/<match>/ruling/<role>         adapter -> agent: its Ruling on each scoring frame (shared.game.scoring)
tsf/<match>/start                 sim -> all       the match's Start (config, seats), once, before its states
tsf/<match>/event                 sim -> all       game events (kills, deaths, ...)
tsf/<match>/summary               sim -> all       the match result, once, at the end
tsf/<match>/adapter               adapter -> all   AdapterStatus: similarity scores, belief, choice
tsf/<match>/alive/<service>[/<role>]  liveliness tokens, one per running service

A match id is never one of the namespaces below (`sweep`, `host`, `pool`): tsf/pool/... is a pool's.

tsf/sweep/<sweep>/coordinator       liveliness token of a sweep's coordinator
tsf/sweep/<sweep>/worker/<worker>   liveliness token of a sweep worker
tsf/sweep/<sweep>/job/<worker>      coordinator -> one worker: a JobOrder (any kind of job)
tsf/sweep/<sweep>/result            workers -> coordinator: JobResults

tsf/host/<host>/alive               liveliness token of a match host
tsf/host/<host>/status              host -> study servers: HostStatus (its slots), every second
tsf/host/<host>/offer               study server -> host, a query: MatchOffer, answered MatchAnswer
tsf/host/<host>/stop                study server -> host: MatchStop (end a match early)
tsf/host/<host>/done                host -> study server: MatchDone (the match ended; its hash)
tsf/host/<host>/recording/<match>   study server -> host, a query (?offset=N): RecordingChunk

tsf/pool/<pool>/order               launcher -> a pool's services: MatchOrder (play this match)
tsf/pool/<pool>/stop                launcher -> a pool's services: MatchStop (end this match now)
tsf/pool/<pool>/refused             a pool's service -> launcher: MatchRefused (it cannot play its part)
tsf/pool/<pool>/alive/<service>     liveliness token of each of a pool's services
"""

from __future__ import annotations

import functools
import re
from typing import NamedTuple

from shared.errors import UsageError
from shared.game import ROLES, check_role

PREFIX = "tsf"
SERVICES = ("sim", "agent", "recorder", "adapter", "human")
_MATCH_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
NAMESPACES = ("sweep", "host", "pool")  # tsf/<namespace>/...: keys that are no match's


def check_name(name: str) -> str:
    """A match, sweep, host, pool or worker id is one key chunk: letters, digits, '-' and '_' only
    (no wildcards, no '/')."""
    if not isinstance(name, str) or not _MATCH_ID.match(name):
        raise UsageError("--match", name, "invalid match id: use 1-64 letters, digits, '-' or '_'")
    return name


def check_match(match: str) -> str:
    """A match id: one key chunk (`check_name`) that is not a namespace, whose keys it would share."""
    if check_name(match) in NAMESPACES:
        names = ", ".join(f"tsf/{n}" for n in NAMESPACES)
        raise UsageError("--match", match, f"is a bus namespace ({names}), not a match id: choose another")
    return match


def _role(role: str) -> str:
    """A seat named by a user (--role): a UsageError, not a bug, when it is not one."""
    if role not in ROLES:
        raise UsageError("--role", role, "unknown role", ROLES)
    return role


def state(match: str) -> str:
    return f"{PREFIX}/{check_match(match)}/state"


def action(match: str, role: str) -> str:
    return f"{PREFIX}/{check_match(match)}/action/{_role(role)}"


def policy(match: str, role: str) -> str:
    return f"{PREFIX}/{check_match(match)}/policy/{_role(role)}"


def ruling(match: str, role: str) -> str:
    return f"{PREFIX}/{check_match(match)}/ruling/{_role(role)}"


def start(match: str) -> str:
    return f"{PREFIX}/{check_match(match)}/start"


def event(match: str) -> str:
    return f"{PREFIX}/{check_match(match)}/event"


def summary(match: str) -> str:
    return f"{PREFIX}/{check_match(match)}/summary"


def adapter(match: str) -> str:
    return f"{PREFIX}/{check_match(match)}/adapter"


def alive(match: str, service: str, role: str | None = None) -> str:
    """Liveliness token key of one running service (agents and humans name their role)."""
    if service not in SERVICES:
        raise UsageError("--service", service, "unknown service", SERVICES)
    key = f"{PREFIX}/{check_match(match)}/alive/{service}"
    return f"{key}/{_role(role)}" if role is not None else key


def actions(match: str) -> str:
    """Both seats' action keys (what the sim subscribes to)."""
    return f"{PREFIX}/{check_match(match)}/action/*"


def seats_alive(match: str) -> str:
    """Liveliness tokens of every service that plays a seat (agents and human gateways)."""
    return f"{PREFIX}/{check_match(match)}/alive/*/*"


def services_alive(match: str) -> str:
    """Liveliness tokens of every service of a match (what a launcher watches)."""
    return f"{PREFIX}/{check_match(match)}/alive/**"


def everything(match: str) -> str:
    """All data keys of a match (what the recorder subscribes to)."""
    return f"{PREFIX}/{check_match(match)}/**"


def job_worker(sweep: str, worker: str = "*") -> str:
    """A sweep worker's liveliness token (the default `*` matches every worker of the sweep)."""
    return f"{PREFIX}/sweep/{check_name(sweep)}/worker/{_worker(worker)}"


def job_coordinator(sweep: str) -> str:
    """The coordinator's liveliness token: workers leave when it goes away."""
    return f"{PREFIX}/sweep/{check_name(sweep)}/coordinator"


def job_order(sweep: str, worker: str) -> str:
    return f"{PREFIX}/sweep/{check_name(sweep)}/job/{_worker(worker)}"


def job_result(sweep: str) -> str:
    return f"{PREFIX}/sweep/{check_name(sweep)}/result"


def host_alive(host: str = "*") -> str:
    """A match host's liveliness token (the default `*` matches every host)."""
    return f"{PREFIX}/host/{_worker(host)}/alive"


def host_status(host: str = "*") -> str:
    return f"{PREFIX}/host/{_worker(host)}/status"


def host_offer(host: str) -> str:
    return f"{PREFIX}/host/{check_name(host)}/offer"


def host_stop(host: str) -> str:
    return f"{PREFIX}/host/{check_name(host)}/stop"


def host_done(host: str = "*") -> str:
    return f"{PREFIX}/host/{_worker(host)}/done"


def host_recording(host: str, match: str = "*") -> str:
    """A recording a host serves, chunk by chunk (the default `*`: every one, the host's queryable)."""
    return f"{PREFIX}/host/{check_name(host)}/recording/{_worker(match)}"


def pool_order(pool: str) -> str:
    return f"{PREFIX}/pool/{check_name(pool)}/order"


def pool_stop(pool: str) -> str:
    return f"{PREFIX}/pool/{check_name(pool)}/stop"


def pool_refused(pool: str) -> str:
    return f"{PREFIX}/pool/{check_name(pool)}/refused"


def pool_alive(pool: str, service: str = "*") -> str:
    """A pool service's liveliness token (the default `*` matches each of the pool's services)."""
    if service != "*" and service not in SERVICES:
        raise UsageError("--service", service, "unknown service", SERVICES)
    return f"{PREFIX}/pool/{check_name(pool)}/alive/{service}"


def _worker(worker: str) -> str:
    return worker if worker == "*" else check_name(worker)


class Key(NamedTuple):
    """The parts of a key: `match` is the match id (or the sweep id), `kind` the chunk after it."""

    match: str
    kind: str  # state, start, event, summary, adapter, action, policy, ruling, alive; or a sweep's kinds
    role: str = ""  # the seat an action, policy, ruling or seat's alive key names
    service: str = ""  # the service an alive key names
    worker: str = ""  # the worker a sweep's worker or job key names, the match host a host key names,
    # or the pool a pool key names


_PLAIN = ("state", "start", "event", "summary", "adapter")  # tsf/<match>/<kind>
_HOST = ("alive", "status", "offer", "stop", "done")  # tsf/host/<host>/<kind>
_SEAT = ("action", "policy", "ruling")  # tsf/<match>/<kind>/<role>


def parse(key: object) -> Key:
    """The inverse of the builders above: the parts of any concrete key they make; else ValueError.
    The last 4096 keys read are remembered: a service reads its matches' few keys on every message."""
    return _parse(str(key))


@functools.lru_cache(maxsize=4096)
def _parse(key: str) -> Key:
    chunks = key.split("/")
    if len(chunks) >= 4 and chunks[:2] == [PREFIX, "sweep"]:
        _, _, sweep, kind, *rest = chunks
        if kind in ("coordinator", "result") and not rest:
            return Key(check_name(sweep), kind)
        if kind in ("worker", "job") and len(rest) == 1:
            return Key(check_name(sweep), kind, worker=check_name(rest[0]))
    if len(chunks) >= 4 and chunks[:2] == [PREFIX, "host"]:
        _, _, host, kind, *rest = chunks
        if kind in _HOST and not rest:
            return Key("", kind, worker=check_name(host))
        if kind == "recording" and len(rest) == 1:
            return Key(check_match(rest[0]), kind, worker=check_name(host))
    if len(chunks) >= 4 and chunks[:2] == [PREFIX, "pool"]:
        _, _, pool, kind, *rest = chunks
        if kind in ("order", "stop", "refused") and not rest:
            return Key("", kind, worker=check_name(pool))
        if kind == "alive" and len(rest) == 1 and rest[0] in SERVICES:
            return Key("", kind, service=rest[0], worker=check_name(pool))
    if len(chunks) >= 3 and chunks[0] == PREFIX:
        _, match, kind, *rest = chunks
        if kind in _PLAIN and not rest:
            return Key(check_match(match), kind)
        if kind in _SEAT and len(rest) == 1:
            return Key(check_match(match), kind, role=check_role(rest[0]))
        if kind == "alive" and rest and rest[0] in SERVICES and len(rest) <= 2:
            role = check_role(rest[1]) if len(rest) == 2 else ""
            return Key(check_match(match), kind, role=role, service=rest[0])
    raise ValueError(f"not a key of the system: {key!r}")
