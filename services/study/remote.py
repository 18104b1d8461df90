"""The study server's side of the match-host protocol (services/study/host.py is the host's).

The server's session joins the study's zenoh router (or is it: `tsf study --listen`). It follows
the hosts' liveliness tokens and their slots (`hosts`, which admission adds to its own), offers a
host a trial's match, bridges the participant's seat over the router as for a local match, waits
for the host's MatchDone, and fetches the recording chunk by chunk into the study's directory:
written aside, its sha256 checked against the host's, and only then put in place, so a recording
in the study directory is always whole. A host that goes away mid-trial fails the trial (it is
offered again, as after a local timeout); so does a host that does not answer or refuses.

Every message both ways is sealed with the study's host secret (shared.messages.sealed): what a
peer without it puts on the router (slots, answers, a match's end, chunks of a recording) is
counted, logged once and dropped, so it can neither offer slots nor return a recording.
"""

from __future__ import annotations

import hashlib
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from services.recorder.service import recording_path
from services.runtime.launch import MatchPlan
from services.runtime.pool import Tokens
from services.study.host import offer_of
from shared import keys
from shared.bus import BusConfig, Drops, subscribe, why
from shared.errors import Failure
from shared.messages import (
    HostStatus,
    MatchAnswer,
    MatchDone,
    MatchStop,
    MessageError,
    RecordingChunk,
    authentic,
    decode,
    recording_query,
    sealed,
)

log = logging.getLogger("tsf.study")
ANSWER = 10.0  # seconds a host has to answer an offer, or a chunk query
ENDING = 20.0  # seconds a host has to report a match the server asked it to end
SENDER = "study"


class Remote:
    """The match hosts on the router, and the matches offered to them."""

    def __init__(self, bus: BusConfig, secret: bytes) -> None:
        if not secret:
            raise ValueError("match hosts need the study's host secret")
        self.secret = secret
        try:
            self.z = zenoh.open(bus.to_zenoh())
        except zenoh.ZError as error:
            where = ", ".join(bus.connect or bus.listen)
            raise Failure(f"no session for match hosts at {where}: {why(error)}") from None
        self.alive: set[str] = set()
        self.slots: dict[str, int] = {}  # live hosts that have said their slots
        self.offered: set[str] = set()
        self.done: dict[str, MatchDone] = {}
        self.changed = threading.Condition()
        self.on_change: Callable[[], None] = lambda: None  # set by the server: wakes the queue
        self.drops = Drops("study/hosts")
        self.declared = [
            self.z.liveliness().declare_subscriber(keys.host_alive(), self._on_alive, history=True),
            subscribe(self.z, keys.host_status(), HostStatus, self._on_status, self.drops),
            subscribe(self.z, keys.host_done(), MatchDone, self._on_done, self.drops),
        ]

    def hosts(self) -> dict[str, int]:
        """Each live host's slots."""
        with self.changed:
            return dict(self.slots)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        host = keys.parse(sample.key_expr).worker
        with self.changed:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(host)
            else:
                log.warning("match host %s went away", host)
                self.alive.discard(host)
                self.slots.pop(host, None)
            self.changed.notify_all()
        self.on_change()

    def _check(self, message: HostStatus | MatchDone) -> None:
        if not authentic(message, self.secret):
            raise MessageError(
                "unauthenticated", f"{message.TYPE} from {message.sender} not sealed with the secret"
            )

    def _on_status(self, status: HostStatus) -> None:
        self._check(status)
        with self.changed:
            if status.host not in self.alive or self.slots.get(status.host) == status.slots:
                return
            log.info("match host %s offers %d slots", status.host, status.slots)
            self.slots[status.host] = status.slots
        self.on_change()

    def _on_done(self, done: MatchDone) -> None:
        self._check(done)
        with self.changed:
            if done.match not in self.offered:
                raise MessageError("unknown_match", f"no match {done.match} was offered")
            self.done[done.match] = done
            self.changed.notify_all()

    def run(
        self, host: str, plan: MatchPlan, stop: threading.Event, on_taken: Callable[[], None] = lambda: None
    ) -> None:
        """Run `plan` on `host` and put its recording into `plan.directory`, hash checked; a
        Failure says why the match or its recording failed (the recording, if whole, is kept).
        `on_taken` is called once (on zenoh's thread) when every service of the host's pool has
        taken the match: their tokens, seen over the router, as Pool.run sees them on the host."""
        offer = sealed(offer_of(plan, SENDER), self.secret)
        with Tokens(self.z, keys.services_alive(plan.match), plan.tokens(), on_taken=on_taken):
            answer = self._ask(keys.host_offer(host), MatchAnswer, payload=offer.encode())
            if answer is None:
                raise Failure(f"match host {host} did not answer the offer of {plan.match}")
            if not answer.accepted:
                raise Failure(f"match host {host} refused {plan.match}: {answer.reason}")
            with self.changed:
                self.offered.add(plan.match)
            try:
                done = self._wait(host, plan, stop)
            finally:
                with self.changed:
                    self.offered.discard(plan.match)
        if done.size:
            self.fetch(host, plan.match, done, recording_path(plan.directory, plan.match))
        if done.error:
            raise Failure(f"on match host {host}: {done.error}")

    def _wait(self, host: str, plan: MatchPlan, stop: threading.Event) -> MatchDone:
        """The host's report of the match's end; asks it to end the match when `stop` is set."""
        deadline = time.monotonic() + (plan.timeout or 24 * 3600.0) + ENDING
        asked = False
        with self.changed:
            while plan.match not in self.done:
                if host not in self.alive:
                    raise Failure(f"match host {host} went away during {plan.match}")
                if time.monotonic() > deadline:
                    raise Failure(f"match host {host} never reported the end of {plan.match}")
                if stop.is_set() and not asked:
                    stopping = sealed(MatchStop(match=plan.match, frame=0, sender=SENDER), self.secret)
                    self.z.put(keys.host_stop(host), stopping.encode())
                    deadline, asked = min(deadline, time.monotonic() + ENDING), True
                self.changed.wait(0.2)
            return self.done.pop(plan.match)

    def fetch(self, host: str, match: str, done: MatchDone, path: Path) -> None:
        """Fetch a recording chunk by chunk to `path`: written aside and moved in place only once its
        size and sha256 are the host's."""
        path.parent.mkdir(parents=True, exist_ok=True)
        part = path.with_name(path.name + ".part")
        digest = hashlib.sha256()
        try:
            with part.open("wb") as out:
                while (offset := out.tell()) < done.size:
                    selector = recording_query(keys.host_recording(host, match), offset, self.secret)
                    chunk = self._ask(selector, RecordingChunk)
                    if chunk is None or chunk.offset != offset or chunk.size != done.size or not chunk.data:
                        raise Failure(
                            f"match host {host} did not serve {match}'s recording from byte {offset}"
                        )
                    out.write(chunk.data)
                    digest.update(chunk.data)
            if digest.hexdigest() != done.sha256:
                raise Failure(f"{match}'s recording from host {host} does not match its sha256")
            part.replace(path)
        finally:
            part.unlink(missing_ok=True)

    def _ask(self, selector: str, kind: type, payload: bytes | None = None):  # noqa: ANN202 - a `kind`
        """The first valid reply of `kind` to a query, or None (no answer within ANSWER seconds)."""
        for reply in self.z.get(selector, payload=payload, timeout=ANSWER):
            if reply.ok is None:
                continue
            try:
                message = decode(reply.ok.payload.to_bytes(), kind)
                self._check(message)
                return message
            except MessageError as error:
                self.drops.drop(selector, error)
        return None

    def close(self) -> None:
        for declared in self.declared:
            declared.undeclare()
        self.z.close()
