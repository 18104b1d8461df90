"""`tsf match-host`: runs the matches that study servers on other machines offer it over the router.

A match host is a `tsf` process on a machine of its own, connected to the study's zenoh router. It
holds a liveliness token (`tsf/host/<host>/alive`) and puts its slots every second; a study server
offers it a match (MatchOffer, a query), which it accepts while it has a free slot, the same
library and the same rules. Each accepted match is played by the host's warm pool
(services/runtime/pool.py: one sim, agent, recorder and adapter process for all its matches), whose
sim, the pool's router, also connects to the study's router, so the participant's seat, bridged by
the study server, reaches it over the router under the match's own keys. When the match ends
the host puts MatchDone with its recording's size and sha256, and serves the recording in chunks
(a queryable); the study server fetches it and checks the hash. A `stop` from the server ends a
match early. Killed, the host's token goes and the server offers the trial again.
"""

from __future__ import annotations

import hashlib
import logging
import threading
from pathlib import Path

import zenoh

from services.agent import library
from services.population.seat import AdaptiveSeat, SeatSpec
from services.recorder.service import recording_path
from services.runtime.launch import MatchPlan
from services.runtime.pool import Pool, pool_name
from shared import keys
from shared.bus import BusConfig, Drops, subscribe, why
from shared.errors import Failure, UsageError
from shared.game import ROLES, GameConfig
from shared.messages import (
    CHUNK,
    HostStatus,
    MatchAnswer,
    MatchDone,
    MatchOffer,
    MatchStop,
    MessageError,
    RecordingChunk,
    authentic,
    decode,
    recording_auth,
    sealed,
)
from shared.secret import same_secret

log = logging.getLogger("tsf.host")
WAIT_SERVICES = 30.0  # seconds a hosted match's sim waits for its recorder and adapter


def offer_of(plan: MatchPlan, sender: str) -> MatchOffer:
    """The offer that asks a host to run `plan`: each seat by its name (the adaptive seat's is sent
    empty, and its agent's name as `adapter`)."""
    adapter = plan.adapter
    seats = {role: "" if adapter and role == adapter.role else str(spec) for role, spec in plan.seats.items()}
    return MatchOffer(
        match=plan.match, frame=0, sender=sender, seed=plan.seed, frames=plan.frames, **seats,
        adapter=adapter.name if adapter else "", wait_players=plan.wait_players,
        timeout=plan.timeout, library=library.play_hash(), config=GameConfig().hash(),
    )  # fmt: skip


def plan_of(offer: MatchOffer, directory: Path) -> MatchPlan:
    """The match an offer asks for, run here. A seat the host cannot fill is a UsageError
    (MatchPlan's checks)."""
    empty = [role for role in ROLES if not getattr(offer, role)]
    seats = {role: SeatSpec.parse(getattr(offer, role), f"--{role}") for role in ROLES if role not in empty}
    if offer.adapter or empty:
        adapter = SeatSpec.parse(offer.adapter, "adapter") if offer.adapter else None
        if len(empty) != 1 or not isinstance(adapter, AdaptiveSeat):
            raise UsageError("adapter", offer.adapter, "not an adaptive agent for the one empty seat")
        seats[empty[0]] = adapter
    return MatchPlan(
        offer.match, offer.seed, offer.frames, directory=directory,
        wait_players=offer.wait_players, wait_services=WAIT_SERVICES,
        timeout=offer.timeout, **seats,
    )  # fmt: skip


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as data:
        while block := data.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


class Host:
    """The bookkeeping of one match host, apart from the bus: its matches and their recordings."""

    def __init__(self, name: str, slots: int, out: Path, secret: bytes) -> None:
        if not secret:
            raise ValueError("a match host needs the study's host secret")
        self.name, self.slots, self.out, self.secret = name, slots, out, secret
        self.sender = f"host/{name}"
        self.running: dict[str, tuple[threading.Event, threading.Thread]] = {}
        self.finished: dict[str, Path] = {}  # match -> its recording, served in chunks
        self.lock = threading.RLock()
        self.hashes = (library.play_hash(), GameConfig().hash())

    def status(self) -> HostStatus:
        with self.lock:
            free = max(0, self.slots - len(self.running))
        return sealed(
            HostStatus(host=self.name, frame=0, sender=self.sender, slots=self.slots, free=free), self.secret
        )

    def check(self, message: MatchOffer | MatchStop) -> None:
        """MessageError unless `message` is the study server's, sealed with the secret."""
        if not authentic(message, self.secret):
            raise MessageError(
                "unauthenticated", f"{message.TYPE} from {message.sender} not sealed with the secret"
            )

    def refusal(self, offer: MatchOffer) -> str:
        """Why this host cannot run `offer` now; "" if it can."""
        if (offer.library, offer.config) != self.hashes:
            return f"library/rules {'/'.join(self.hashes)} on host {self.name}: update its checkout"
        with self.lock:
            if offer.match in self.running or offer.match in self.finished:
                return f"match {offer.match} was offered before"
            if len(self.running) >= self.slots:
                return f"host {self.name} has no free slot"
        return ""

    def chunk(self, key: str, offset: str, auth: object) -> RecordingChunk:
        """Up to CHUNK bytes from `offset` of the recording of the finished match `key` names (a
        recording query's, signed with `auth`); ValueError if the query is not the server's or
        there is no such recording."""
        if not same_secret(auth, recording_auth(key, offset, self.secret)):
            raise MessageError("unauthenticated", f"a query for {key} not signed with the secret")
        match, offset = keys.parse(key).match, int(offset)
        with self.lock:
            path = self.finished.get(match)
        if path is None or not path.exists():
            raise ValueError(f"no recording of {match} on host {self.name}")
        with path.open("rb") as data:
            size = data.seek(0, 2)
            data.seek(min(offset, size))
            block = data.read(CHUNK)
        chunk = RecordingChunk(match=match, frame=0, sender=self.sender, offset=offset, size=size, data=block)
        return sealed(chunk, self.secret)


def run_match_host(
    bus: BusConfig, name: str, slots: int, out: Path, stop: threading.Event, secret: bytes
) -> int:
    """Serve matches until `stop`; then end the running ones. Returns the number of matches run.
    `secret` is the study's host secret."""
    return MatchHost(bus, name, slots, out, secret).serve(stop)


class MatchHost:
    """A match host on the bus: `Host`'s bookkeeping, the session, and the callbacks that answer
    the study server's offers, stops and recording queries."""

    def __init__(self, bus: BusConfig, name: str, slots: int, out: Path, secret: bytes) -> None:
        self.bus, self.name, self.out = bus, name, out
        self.host = Host(keys.check_name(name), slots, out, secret)
        self.drops = Drops(self.host.sender)
        self.played = 0
        try:
            self.z = zenoh.open(bus.to_zenoh())
        except zenoh.ZError as error:
            raise Failure(f"cannot reach the router at {', '.join(bus.connect)}: {why(error)}") from None
        # its sim joins the study's router, so that a seat the server plays reaches the pool's matches
        self.pool = Pool(pool_name(name), out, low_latency=bus.low_latency, peers=bus.connect)

    def serve(self, stop: threading.Event) -> int:
        """Serve until `stop`, end the running matches, close the session; the matches run."""
        z, name = self.z, self.name
        try:
            with (
                self.pool,
                z.declare_queryable(keys.host_offer(name), self._on_offer),
                z.declare_queryable(keys.host_recording(name), self._on_recording),
                subscribe(z, keys.host_stop(name), MatchStop, self._on_stop, self.drops),
                z.liveliness().declare_token(keys.host_alive(name)),
            ):
                log.info(
                    "match host %s serves %d slots through %s",
                    name,
                    self.host.slots,
                    ", ".join(self.bus.connect),
                )
                self._put_status()
                while not stop.wait(1.0):
                    self._put_status()
                with self.host.lock:
                    running = list(self.host.running.values())
                for ended, _ in running:
                    ended.set()
                for _, thread in running:
                    thread.join()
        finally:
            z.close()
        return self.played

    def _put_status(self) -> None:
        self.z.put(keys.host_status(self.name), self.host.status().encode())

    def _play(self, plan: MatchPlan, ended: threading.Event) -> None:
        host, error = self.host, ""
        try:
            self.pool.play(plan, ended)  # unread here: the server judges the recording it fetches
        except Exception as failure:  # noqa: BLE001 - a match that fails is reported, never fatal
            error = (str(failure) or type(failure).__name__)[:300]
        path = recording_path(plan.directory, plan.match)
        size, digest = (path.stat().st_size, sha256(path)) if path.exists() else (0, "")
        with host.lock:
            del host.running[plan.match]
            host.finished[plan.match] = path
        log.info("match %s ended%s; recording %d bytes", plan.match, f": {error}" if error else "", size)
        done = MatchDone(match=plan.match, frame=0, sender=host.sender, error=error, size=size, sha256=digest)
        done = sealed(done, host.secret)
        if not self.z.is_closed():
            self.z.put(keys.host_done(self.name), done.encode())
            self._put_status()

    def _on_offer(self, query: zenoh.Query) -> None:
        host = self.host
        try:
            offer = decode(query.payload.to_bytes() if query.payload else b"", MatchOffer)
            host.check(offer)
        except MessageError as error:
            self.drops.drop(keys.host_offer(self.name), error)
            return
        plan, thread = None, None
        with host.lock:  # checked and taken at once: two offers never share the last slot
            try:
                reason = host.refusal(offer)
                plan = None if reason else plan_of(offer, self.out)
            except ValueError as error:  # a seat this host cannot fill (UsageError)
                reason = str(error)[:300]
            if plan is not None:
                ended = threading.Event()
                thread = threading.Thread(target=self._play, args=(plan, ended), name=f"match-{offer.match}")
                host.running[offer.match] = (ended, thread)
                self.played += 1
        if thread is not None:
            thread.start()
            log.info("runs match %s", offer.match)
        answer = sealed(
            MatchAnswer(
                match=offer.match, frame=0, sender=host.sender, accepted=plan is not None, reason=reason
            ),
            host.secret,
        )
        query.reply(keys.host_offer(self.name), answer.encode())
        self._put_status()

    def _on_stop(self, message: MatchStop) -> None:
        self.host.check(message)
        with self.host.lock:
            ended = self.host.running.get(message.match, (None,))[0]
        if ended is not None:
            log.info("the study server ends match %s", message.match)
            ended.set()

    def _on_recording(self, query: zenoh.Query) -> None:
        try:
            parameters = query.parameters
            chunk = self.host.chunk(
                str(query.key_expr), int(parameters.get("offset", "0")), parameters.get("auth")
            )
        except ValueError as error:
            self.drops.drop(str(query.key_expr), error)
            if getattr(error, "reason", "") != "unauthenticated":  # a peer without the secret learns nothing
                query.reply_err(str(error)[:300].encode())
            return
        query.reply(query.key_expr, chunk.encode())
