"""The study's front door: who may come in. A new participant consents and gets an id (at a
limited rate, once per crowd-sourcing worker id, from a link signed for it where links are
signed); a returning one comes back through their id and resume key, a signed link or the
platform's own link, each under the same limit on reconnects; anyone else is refused in one line
that says whom to contact. The newest window of a participant plays their visit
(services/study/visit.py)."""

from __future__ import annotations

import asyncio
import logging

import zenoh
from websockets.asyncio.server import ServerConnection

from services.human.core import PerAddress, Quiet, RateLimit
from services.human.gateway import client_address, receive_first, refuse
from services.study.connection import Socket
from services.study.core import Participant, Study, worker_id
from services.study.serving import Serving
from services.study.trial import TrialRunner
from services.study.visit import Visit
from shared.page import ConsentText, Declined, Hello, ParticipantId, Stopped
from shared.secret import same_secret, signature

log = logging.getLogger("tsf.study")
ARRIVAL_BURST = 20  # participant ids issued at once, beyond the rate
ADDRESS_BURST = 5  # ... to one address
RECONNECT_BURST = 5  # reconnects of one participant at once (reloads), and refusals of one address
REFUSALS = 0.1  # refused attempts a second of one address, beyond the burst (a wrong key, an unproven link)
BUSY = "Too many people are starting right now. Please try again in a minute."
TAKEN = "This worker id has already taken part in this study."
NOT_YOURS = (
    "This worker id has begun this study, but this link does not show that it is yours: open the "
    "study from the platform's own link (the one you began with) to go on where you left off."
)
UNKNOWN = "unknown participant or resume key"
CONTACT = "the researchers, through the platform you came from"  # without [crowd] contact
NO_WORKER = "This link's ids are not ones this study can take (letters, digits and _ . : @ + - only)."
DECLINED = "You declined to take part. Nothing about you was recorded. You may close this window now."
UNSIGNED = "This link is not signed for its worker id. Please open the link exactly as the study gave it."
RECONNECTS = "Too many reconnects. Please wait a minute, then reload the page."
STOPPED = (
    "The study has stopped for now. Everything you did so far is kept: open your study link again "
    "later to go on where you left off (a game cut short is played again)."
)


class Front:
    """The study's front door: admits each participant who connects (consent, or resume) and runs
    their visit; the newest window of a participant plays. Its fields are what every participant's
    admission shares: the rate limits and who is playing."""

    def __init__(
        self, study: Study, serving: Serving, runner: TrialRunner, trusted: tuple[str, ...] = ()
    ) -> None:
        self.study, self.serving, self.runner, self.trusted = study, serving, runner, trusted
        self.playing: dict[
            str, tuple[Socket, asyncio.Event]
        ] = {}  # participant -> their socket, set once it left
        self.arrivals = RateLimit(serving.arrivals, ARRIVAL_BURST)
        self.per_address = PerAddress(serving.arrivals_per_address, ADDRESS_BURST)
        self.reconnects = PerAddress(serving.reconnects, RECONNECT_BURST)  # by participant
        self.refusals = PerAddress(REFUSALS, RECONNECT_BURST)  # by address
        self.quiet = Quiet()  # refusals: logged once per address, kind and minute

    async def over_limit(self, socket: Socket, address: str, reason: str, line: str) -> None:
        """Refuse a socket over one of the limits with `reason`; `line` goes to the log, once per
        address and minute."""
        if self.quiet(f"{line} {address}"):
            log.warning("refused %s: %s (said once a minute per address)", address, line)
        await refuse(socket.ws, reason)

    async def stopping(self) -> None:
        """The server stops: tell everyone playing that their progress is kept, and close."""
        contact = self.study.config.crowd.contact
        text = STOPPED + (f" If it stays stopped, please contact {contact}." if contact else "")
        for socket, _ in list(self.playing.values()):
            socket.send(Stopped(text=text))
        await asyncio.gather(*(socket.close() for socket, _ in list(self.playing.values())))

    async def handle(self, ws: ServerConnection, z: zenoh.Session | None) -> None:
        hello = await receive_first(ws, ("hello",))
        if hello is None:
            return
        socket, left = Socket(ws), asyncio.Event()  # set once this handler is done
        participant = None
        try:
            participant = await self.admit(socket, hello)
            if participant is None:
                return
            older = self.playing.get(participant.id)
            if older is not None:  # a reload, or the page in another window: the newest one plays
                await older[0].ws.close(1000, "the study was opened again in another window")
                older[0].gone.set()
                await older[1].wait()  # its trial ended and set down (resumed below)
            self.playing[participant.id] = (socket, left)
            test = bool(self.serving.test_token) and same_secret(hello.test, self.serving.test_token)
            await Visit(self.study, self.runner, socket, participant, bool(hello.obs) and test).run()
        finally:
            if participant is not None and self.playing.get(participant.id, (None,))[0] is socket:
                del self.playing[participant.id]
            left.set()
            for task in socket.tasks:
                task.cancel()

    async def admit(self, socket: Socket, hello: Hello) -> Participant | None:
        """The participant who resumes (id and key), or a new one once they consent: ids are
        issued only then, at a limited rate, and once per crowd-sourcing worker id."""
        address = client_address(socket.ws, self.trusted)
        if hello.participant is not None:
            participant = self.study.resume(hello.participant, hello.key or "")
            if participant is None:
                known = self.study.participants.get(hello.participant)
                await self.turn_away(socket, address, self.contact(UNKNOWN), "resume key", known)
                return None
            return await self.back(socket, address, participant, "their id and key")
        ids = [worker_id(v) for v in self.study.config.crowd.ids(hello.link or {})]
        worker = ids[0] or worker_id(hello.worker)
        if worker is None or None in ids:
            await self.turn_away(socket, address, NO_WORKER, "no worker id")
            return None
        if self.serving.link_secret and not (
            worker and same_secret(hello.sig, signature(self.serving.link_secret, worker))
        ):
            await self.turn_away(socket, address, UNSIGNED, "unsigned")
            return None
        link = {k: v for k, v in zip(("study", "session"), ids[1:], strict=True) if v}
        return await self.arrive(socket, address, worker, link)

    async def arrive(
        self, socket: Socket, address: str, worker: str, link: dict[str, str]
    ) -> Participant | None:
        """A worker id with its link: back through it if it has taken part, else asked to consent
        and, once they do, given a participant id (at a limited rate)."""
        study = self.study
        if study.taken(worker):  # back through the platform's link: another tab, browser or device
            return await self.returning(socket, address, study.by_worker(worker), link)
        socket.send(ConsentText(text=study.config.consent_text()))
        answer = await socket.wait_for(("consent", "decline"))
        if answer == "decline":  # no id, nothing written
            socket.send(Declined(text=DECLINED))
            await socket.close()
        if answer != "consent":
            return None
        if study.taken(worker):  # a second window of the same worker consented first
            return await self.returning(socket, address, study.by_worker(worker), link)
        if socket.closed:  # consented and left: no id, no match
            return None
        if not (self.per_address.allow(address) and self.arrivals.allow()):
            await self.over_limit(socket, address, BUSY, "over the limits on new participants")
            return None
        participant = study.arrive(worker, link)
        log.info("participant %s arrives and plays the %s", participant.id, participant.role)
        socket.send(ParticipantId(participant=participant.id, key=participant.key))
        return participant

    def proven(self, participant: Participant, link: dict[str, str]) -> bool:
        """Whether a returning worker id's link shows that it is the participant's own: signed for
        the id (with a link secret, checked before this), or carrying the platform's session id
        they began with ([crowd] resume = "session"); a worker id alone never does."""
        if self.serving.link_secret:
            return True
        began = participant.link.get("session", "")
        return self.study.config.crowd.resume == "session" and bool(began) and link.get("session") == began

    async def returning(
        self, socket: Socket, address: str, participant: Participant, link: dict[str, str]
    ) -> Participant | None:
        """A worker id that has taken part comes back through a link (a crashed tab, another
        browser, a phone): resumed where they left off if the link is proven theirs (a finished
        or screened-out one is shown their end again), else refused."""
        if self.proven(participant, link):
            how = "a signed link" if self.serving.link_secret else "the platform's link"
            return await self.back(socket, address, participant, how)
        finished = self.study.next_trial(participant) is None or participant.screened
        text, why = (TAKEN, "taken") if finished else (NOT_YOURS, "unproven")
        await self.turn_away(socket, address, self.contact(text), why, participant)
        return None

    async def back(
        self, socket: Socket, address: str, participant: Participant, how: str
    ) -> Participant | None:
        """A participant back in through `how` (their id and key, a signed link, the platform's
        link): every way counts against the one limit on their reconnects (`--reconnects`; 0:
        none), since each cuts the trial being played."""
        if not self.serving.reconnects:
            await self.over_limit(
                socket, address, RECONNECTS, f"no reconnects (--reconnects 0): {participant.id}"
            )
            return None
        if not self.reconnects.allow(f"participant {participant.id}"):
            await self.over_limit(socket, address, RECONNECTS, f"too many reconnects of {participant.id}")
            return None
        log.info("participant %s resumes through %s", participant.id, how)
        socket.send(ParticipantId(participant=participant.id, key=participant.key))
        return participant

    def contact(self, text: str) -> str:
        """A refusal's text with whom to contact if it is wrong."""
        contact = self.study.config.crowd.contact or CONTACT
        return f"{text.rstrip('.')}. If this is wrong, please contact {contact}."

    async def turn_away(
        self, socket: Socket, address: str, text: str, why: str, participant: Participant | None = None
    ) -> None:
        """Refuse a socket with `text`: every refusal comes here. At most RECONNECT_BURST of one
        address at once and REFUSALS a second (then RECONNECTS); journalled for `participant`
        (the dashboard shows it) and logged once per address, kind (`why`) and minute: 200
        attempts wrote 200 journal lines and 200 warnings."""
        if not self.refusals.allow(address):
            await self.over_limit(socket, address, RECONNECTS, "too many refused attempts")
            return
        if self.quiet(f"{why} {address}"):
            if participant is not None:
                self.study.refused(participant, why)
            who = participant.id if participant else "a hello"
            log.warning("refused %s from %s: %s (said once a minute per address)", who, address, why)
        await refuse(socket.ws, text)
