"""The experimenter's dashboard: a live view of a running study, and a spectator's view of any of
its running matches, served on a port of its own (`tsf study --dashboard-token FILE
--dashboard-port N`), never on the participants' one.

Every socket shows the dashboard's token first (compared as bytes in constant time,
shared/secret.py); a participant's id and resume key open nothing here, and nothing here opens
a seat: the dashboard only reads, and a spectator's bridge has no publisher and no token
(services/human/gateway.py watch). The page and its script are public and hold no data; the
token travels in the link's fragment (`#token=...`), which a browser never sends in a request.

Messages (up, first and only): `dashboard` (token) or `watch` (token, match). Down: `study` (the
overview below, once a second) or the spectator's `watching` (the match's variant and the
person's seat), `welcome`, frames and `end`, then a close once the match is over. The overview
is read on the study server's own event loop (its state lives there), and is a pure function of
the study, its admission and who is connected (`overview`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Callable, Collection

import zenoh
from websockets.asyncio.server import ServerConnection

from services.human.gateway import Gateway, Web, receive_first, refuse, watch
from services.runtime.launch import watcher_bus
from services.study.core import Admission, Participant, Study
from shared.page import DashboardHello, Overview, Watching
from shared.secret import same_secret

log = logging.getLogger("tsf.study.dashboard")
PAGES = {
    "/": "dashboard.html", "/dashboard.js": "dashboard.js", "/watch": "index.html", "/tsf.js": "tsf.js",
    "/contract.js": "contract.js",
}  # fmt: skip
EVERY = 1.0  # seconds between two overviews sent down
WRONG = "not the dashboard's token"
NOT_RUNNING = "no such match is running"
TOKEN_LENGTH = range(16, 65)  # the token's accepted length (characters)


STATES = ("playing", "finished", "screened out", "dropped", "refused")  # a participant's, as shown


def state(study: Study, participant: Participant, connected: bool) -> str:
    """Where a participant stands: `playing` (their page is connected), `finished`, `screened out`,
    `refused` (they came back and were refused, and are not playing), else `dropped` (they left
    before the end, and may come back)."""
    if participant.screened:
        return "screened out"
    if study.next_trial(participant) is None:
        return "finished"
    if connected:
        return "playing"
    return "refused" if participant.refused else "dropped"


def about(study: Study, match: str) -> dict:
    """A running match as the spectator's view names it: the variant that plays (the study's own
    name, never shown to participants) and the person's seat; a practice game's variant is
    `practice`."""
    owner = study.participants.get(match.removeprefix(f"{study.config.name}-").split("-", 1)[0])
    if owner is None:
        return {"variant": "", "person": ""}
    session = next((a["session"] for a in owner.attempts if a["match"] == match), None)
    variant = "practice" if session is None else study.config.variants[owner.order[session - 1]].name
    return {"variant": variant, "person": owner.role}


def overview(study: Study, admission: Admission, connected: Collection[str] = ()) -> dict:
    """What the experimenter sees: each participant (the study's anonymous id, never a worker id)
    with their state (STATES), trials done, failed and replayed, attention checks passed, times
    refused, the running attempt; trials done per variant and role, and participants per role and
    state; the queue; the running matches, their variant and the person's seat, and where; this
    machine's and each match host's slots. `connected`: the participants whose page is open."""
    prefix = f"{study.config.name}-"

    def owner(match: str) -> str:  # match ids are <study>-<participant>-s<session>t<trial>[-a<attempt>]
        return match.removeprefix(prefix).split("-", 1)[0]

    config = study.config
    total = len(config.variants) * config.trials
    done = {(v.name, role): 0 for v in config.variants for role in config.roles}
    participants = []
    for p in study.participants.values():
        statuses = [a["status"] for a in p.attempts]
        running = [a["match"] for a in p.attempts if a["status"] in ("running", "dropped")]
        for a in p.attempts:
            if a["status"] == "done":
                done[config.variants[p.order[a["session"] - 1]].name, p.role] += 1
        participants.append({
            "id": p.id, "role": p.role, "state": state(study, p, p.id in connected), "trials": total,
            "done": statuses.count("done"), "failed": statuses.count("failed"),
            "replayed": sum(a["attempt"] > 1 for a in p.attempts), "checks": p.checks,
            "refused": len(p.refused), "match": running[-1] if running else None,
        })  # fmt: skip
    used: dict[str, int] = {}
    for where in admission.running.values():
        used[where] = used.get(where, 0) + 1
    slots = {Admission.LOCAL: admission.cap, **admission.hosts}
    return {
        "type": "study",
        "study": study.config.name,
        "participants": participants,
        "counts": {
            "variants": [
                {"variant": v.name, **{role: done[v.name, role] for role in config.roles}}
                for v in config.variants
            ],
            "roles": {role: sum(p["role"] == role for p in participants) for role in config.roles},
            "states": {s: sum(p["state"] == s for p in participants) for s in STATES},
        },
        "queue": [{"match": m, "participant": owner(m)} for m in admission.waiting],
        "matches": [
            {"match": m, "participant": owner(m), **about(study, m), "host": where or "local"}
            for m, where in admission.running.items()
        ],
        "hosts": [{"host": h or "local", "slots": n, "used": used.get(h, 0)} for h, n in slots.items()],
    }


def read_token(text: str) -> str:
    """The dashboard's token as a file holds it (surrounding white space dropped); ValueError for
    one too short to be hard to guess, or too long for a socket's first message."""
    token = text.strip()
    if len(token) not in TOKEN_LENGTH:
        raise ValueError(f"{len(token)} characters: give 16 to 64 (e.g. `openssl rand -hex 24`)")
    return token


class Dashboard:
    """The dashboard's web server, started beside the study's (`with`); `show()` the overview, read
    on `loop` (the study server's), `endpoint(match)` the running match's sim endpoint ("" for one
    on a match host, then watched through `router`), None when not running; `describe(match)` its
    variant and the person's seat (`about`), which the spectator's view shows."""

    def __init__(
        self,
        token: str,
        web: Web,
        loop: asyncio.AbstractEventLoop,
        show: Callable[[], dict],
        endpoint: Callable[[str], str | None],
        low_latency: bool = True,
        router: zenoh.Session | None = None,
        describe: Callable[[str], dict] = lambda match: {"variant": "", "person": ""},
    ) -> None:
        self.token, self.loop, self.show, self.endpoint, self.describe = token, loop, show, endpoint, describe
        self.low_latency, self.router = low_latency, router
        self.gateway = Gateway(None, self.handle, web, PAGES)

    def __enter__(self) -> Dashboard:
        self.gateway.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.gateway.__exit__(*exc)

    @property
    def url(self) -> str:
        return self.gateway.url

    async def on_study(self, read: Callable[[], object]) -> object:
        """`read()` run on the study server's loop (where its state changes), awaited here."""

        async def call() -> object:
            return read()

        return await asyncio.wrap_future(asyncio.run_coroutine_threadsafe(call(), self.loop))

    async def handle(self, ws: ServerConnection, _: zenoh.Session | None) -> None:
        first = await receive_first(ws, ("dashboard", "watch"))
        if first is None:
            return
        if not self.token or not same_secret(first.token, self.token):
            log.warning("dashboard: refused a socket from %s: %s", ws.remote_address[0], WRONG)
            await refuse(ws, WRONG)
            return
        if isinstance(first, DashboardHello):
            while True:
                shown = {k: v for k, v in (await self.on_study(self.show)).items() if k != "type"}
                await ws.send(Overview(**shown).encode())
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(ws.wait_closed(), EVERY)
                    return
        await self.spectate(ws, first.match or "")

    async def spectate(self, ws: ServerConnection, match: str) -> None:
        """The match's frames, drawn by the participants' page; closed once the match has ended."""
        endpoint = await self.on_study(lambda: self.endpoint(match))
        if endpoint is None or (not endpoint and self.router is None):
            await refuse(ws, NOT_RUNNING)
            return
        own = bool(endpoint)  # a local match's sim, dialled by a session of the spectator's own
        described = await self.on_study(lambda: self.describe(match))
        await ws.send(Watching(match=match, **described).encode())
        bus = watcher_bus(endpoint, self.low_latency)
        z = await asyncio.to_thread(zenoh.open, bus.to_zenoh()) if own else self.router
        watching = asyncio.ensure_future(watch(ws, z, match))
        try:
            while not watching.done() and await self.on_study(lambda: self.endpoint(match)) is not None:
                await asyncio.wait({watching}, timeout=EVERY)
            await ws.close(1000, "the match has ended")
            await watching
        finally:
            if own:  # never on the loop: a zenoh close may wait for its threads
                threading.Thread(target=z.close, daemon=True).start()
