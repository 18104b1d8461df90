"""The recorder service: a thin shell that writes everything a match puts on the bus to its log.

One match given on the command line (run_recorder), or a pool's matches as their orders come
(run_pool_recorder): the same per-match code (MatchRecording, _record) either way. The zenoh
callbacks only timestamp and queue the bytes (they never block the session's receive thread); one
drain thread validates, writes and tracks gaps for every match of the process. Bad input is
counted and dropped.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from services.agent import library
from services.recorder.log import GapTracker, LogWriter, read_log
from shared import keys
from shared.bus import BusConfig, Drops, Seen, refuse_order, session, subscribe, until_stopped
from shared.errors import Failure, UsageError
from shared.game import ROLES, GameConfig
from shared.messages import MatchOrder, Message, MessageError, Start, State, Summary, decode_any
from shared.provenance import provenance, sidecar

log = logging.getLogger("tsf.recorder")
_DONE = object()
BATCH = 0.05  # seconds the drain lets messages gather


def recording_path(directory: str | Path, match: str) -> Path:
    return Path(directory) / f"{keys.check_match(match)}.tsflog"


class MatchRecording:
    """One match's log, fed by the drain thread: what it hands in is validated against the match,
    written, and its state frames tracked for gaps. Reopened during the match (a restarted recorder)
    it appends after cutting any torn tail; the log of a finished match (one with a summary) is
    refused (UsageError). `ended` is set by the summary, by a second start of the id (another match:
    it and all that follows is not written, `second` holds it), or by whoever ends the recording."""

    def __init__(self, match: str, path: Path, drops: Drops, ended: threading.Event | None = None) -> None:
        if path.exists() and any(r.key == keys.summary(match) for r in read_log(path)[0]):
            raise UsageError(
                "--match", match, f"{path} holds a finished match of this id; give the new one another id"
            )
        self.match, self.path, self.drops = match, path, drops
        self.ended = ended or threading.Event()
        self.closed = threading.Event()
        self.second: Start | None = None
        self.writer = LogWriter(path)
        if self.writer.cut_bytes:
            log.warning("cut a torn tail of %d bytes from %s", self.writer.cut_bytes, path)
        state = keys.state(match)
        self.gaps = GapTracker(
            max((_frame(r.data) for r in self.writer.last_records if r.key == state), default=-1)
        )
        self.started = any(r.key == keys.start(match) for r in self.writer.last_records)
        self.writer.last_records = []  # read for the above only: a pool keeps many logs open for hours

    def take(self, key: str, data: bytes, t: int) -> None:
        if self.closed.is_set() or self.second is not None:
            return
        try:
            message = decode_any(data)
            _check_key(key, message, self.match)
        except MessageError as error:
            self.drops.drop(key, error)
            return
        if isinstance(message, Start):
            if self.started:
                self.second = message
                self.ended.set()
                return
            self.started = True
            _write_provenance(self.path, message)
        if isinstance(message, State) and (gap := self.gaps.see(message.frame)):
            self.writer.write_gap(*gap)
        self.writer.write(key, data, t)
        if isinstance(message, Summary):
            self.ended.set()

    def close(self) -> None:
        self.writer.close()
        self.closed.set()

    def fail(self, error: OSError) -> None:
        """The log cannot be written: the recording ends here (logged once; nothing more is taken)."""
        log.error("recording %s failed: %s", self.path, error)
        self.ended.set()
        with contextlib.suppress(OSError):
            self.writer.close()
        self.closed.set()


class Drain:
    """The one thread that writes every match's log: zenoh callbacks queue (recording, key, bytes,
    receive time) items, and a recording's close is queued behind what it received. Once the queue
    is empty it sleeps BATCH seconds, so that it wakes for a batch, not for each message (measured
    with bench/recorder_pool.py: 10-20% less CPU; a record reaches the OS that much later)."""

    def __init__(self) -> None:
        self.inbox: queue.SimpleQueue = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._run, name="recorder-drain", daemon=True)

    def feed(self, recording: MatchRecording) -> Callable[[zenoh.Sample], None]:
        put = self.inbox.put
        return lambda sample: put(
            (recording, str(sample.key_expr), sample.payload.to_bytes(), time.time_ns())
        )

    def close(self, recording: MatchRecording) -> None:
        """Close the log once everything queued before is written (call after undeclaring its feed)."""
        self.inbox.put((recording, None, b"", 0))
        recording.closed.wait()

    def _run(self) -> None:
        while (item := self.inbox.get()) is not _DONE:
            recording, key, data, t = item
            try:
                recording.take(key, data, t) if key is not None else recording.close()
            except OSError as error:  # a full disk, say: this match's recording ends, not the others'
                recording.fail(error)
            if self.inbox.empty():
                time.sleep(BATCH)

    def __enter__(self) -> Drain:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.inbox.put(_DONE)
        self.thread.join()


def run_recorder(
    bus: BusConfig,
    match: str,
    directory: str | Path = "recordings",
    stop: threading.Event | None = None,
    wait_seats: float = 10.0,
) -> Path:
    """Record `match` until its summary is written, its sim's token goes away, or `stop` is set;
    returns the log's path. Restarted on the same directory during the match, it appends to the same
    log after cutting any torn tail; the log of a finished match (one with a summary) is never
    appended to (UsageError), and a second start of the id ends the recording before it is written
    (Failure): one log, one match."""
    recording = MatchRecording(match, recording_path(directory, match), Drops("recorder"), stop)
    with Drain() as drain, session(bus) as z:
        _record(z, bus.mode == "client", recording, drain, wait_seats)
    if recording.second is not None:
        raise Failure(f"{recording.path}: a second match started under the id {match}; it was not recorded")
    return recording.path


def _record(
    z: zenoh.Session, client: bool, recording: MatchRecording, drain: Drain, wait_seats: float
) -> None:
    """Record one match on `z` until `recording.ended`, then close its log; everything declared for
    it is undeclared (a pool records for hours). The match also ends when the sim's token goes away
    (a killed sim: the log stays as it is, incomplete).

    Its token goes only once the log is closed (a launcher that sees it go reads the log whole:
    samples still queued when the subscriptions end are written first).

    The recorder's liveliness token (which the sim waits for) says that the seats' first actions will
    reach it. A client (run_match's and a pool's topology: the sim is the router) declares it as soon
    as it has subscribed: every action passes the router, which has the subscription before the token
    (declared in order on the one link), so the token can come long before the seats' players do,
    and a study can offer the trial without waiting for a person's Ready. A peer declares it once
    both seats' players are seen, or after `wait_seats` seconds: it learns of the other peers over
    gossip after the sim has seen them, so a token declared at once could start the match before
    the seats' first actions reach this recorder."""
    match, ended = recording.match, recording.ended

    def on_sim(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            ended.set()

    with contextlib.ExitStack() as token:  # undeclared last: once it goes, the log is closed
        try:
            with (
                z.declare_subscriber(keys.everything(match), drain.feed(recording)),
                z.liveliness().declare_subscriber(keys.alive(match, "sim"), on_sim, history=True),
            ):
                if not client:
                    _wait_for_seats(z, match, wait_seats, ended)
                token.enter_context(z.liveliness().declare_token(keys.alive(match, "recorder")))
                until_stopped(ended)
                time.sleep(0.5)  # actions still in flight after the summary (they come over other links)
        finally:
            drain.close(recording)


class PoolRecorder:
    """A pool's recorder: each new order's match is recorded by _record in a thread of its own, into
    `<out>/<order.folder>/<match>.tsflog`. An order for a match it has or had is ignored (the
    launcher re-puts orders until every service answers; shared.bus.Seen)."""

    def __init__(
        self, z: zenoh.Session, client: bool, out: Path, drain: Drain, drops: Drops, pool: str = ""
    ) -> None:
        self.z, self.client, self.out, self.drain, self.drops = z, client, out, drain, drops
        self.pool = pool  # where an order it cannot record is refused ("": nowhere)
        self.seen = Seen()
        self.open: dict[str, tuple[MatchRecording, threading.Thread]] = {}
        self.closing = False
        self.lock = threading.Lock()

    def order(self, order: MatchOrder) -> None:
        with self.lock:
            if self.closing or not self.seen.add(order.match):
                return
        threading.Thread(
            target=self._record, args=(order,), name=f"recorder-{order.match}", daemon=True
        ).start()

    def _record(self, order: MatchOrder) -> None:
        try:
            path = recording_path(self.out / order.folder, order.match)
            recording = MatchRecording(order.match, path, self.drops)
        except (UsageError, OSError) as error:
            log.warning("match %s not recorded: %s", order.match, error)
            if self.pool:
                refuse_order(self.z, self.pool, "recorder", order, error)
            return
        with self.lock:
            if self.closing:  # SIGTERM came while its log opened
                recording.ended.set()
            self.open[order.match] = (recording, threading.current_thread())
        try:
            _record(self.z, self.client, recording, self.drain, order.wait_players)
        finally:
            with self.lock:
                del self.open[order.match]
        if recording.second is not None:
            log.warning("%s: a second match started under the id %s; it was not recorded", path, order.match)
        log.info("match %s recorded to %s", order.match, path)

    def close(self) -> None:
        """End every open recording (each log flushed and closed) and take no more orders."""
        with self.lock:
            self.closing = True
            now = list(self.open.values())
        for recording, _ in now:
            recording.ended.set()
        for _, thread in now:
            thread.join()


def run_pool_recorder(
    bus: BusConfig, pool: str, out: str | Path, stop: threading.Event | None = None
) -> None:
    """Record every match the pool `pool` orders until `stop` is set; then every open log is
    flushed and closed. Its pool token is declared once it has subscribed to the orders."""
    stop = stop or threading.Event()
    drops = Drops("recorder")
    with Drain() as drain, session(bus) as z:
        recorder = PoolRecorder(z, bus.mode == "client", Path(out), drain, drops, pool)
        try:
            with (
                subscribe(z, keys.pool_order(pool), MatchOrder, recorder.order, drops),
                z.liveliness().declare_token(keys.pool_alive(pool, "recorder")),
            ):
                until_stopped(stop)
        finally:
            recorder.close()


def _wait_for_seats(z: zenoh.Session, match: str, timeout: float, stop: threading.Event) -> None:
    """Return once a player of each seat is seen (by its liveliness token), after `timeout` seconds,
    or when `stop` is set."""
    seen: set[str] = set()

    def on_seat(sample: zenoh.Sample) -> None:
        role = keys.parse(sample.key_expr).role
        (seen.add if sample.kind == zenoh.SampleKind.PUT else seen.discard)(role)

    deadline = time.monotonic() + timeout
    with z.liveliness().declare_subscriber(keys.seats_alive(match), on_seat, history=True):
        while not seen >= set(ROLES) and time.monotonic() < deadline and not stop.wait(0.005):
            pass


def _write_provenance(path: Path, start: Start) -> None:
    """Name what made the recording beside it (shared/provenance.py), with the match's rules."""
    try:
        record = provenance(**library.provenance_hashes(), config=GameConfig.from_dict(start.config))
        sidecar(path).write_text(json.dumps(record, indent=1) + "\n")
    except (OSError, ValueError) as error:  # the log matters more than its label
        log.warning("could not write the provenance of %s: %s", path, error)


def _frame(data: bytes) -> int:
    try:
        return decode_any(data).frame
    except MessageError:
        return -1


def _check_key(key: str, message: Message, match: str) -> None:
    """A valid message is still bad input on a key that does not carry its type, or for another match
    or seat (as the sim and agents judge it): recorded, it would pass for a state, action, ..."""
    parts = _parsed(key)  # each kind of key is named for the type it carries
    if parts is None or parts.kind != message.TYPE:
        raise MessageError("type", f"{message.TYPE} on {key}")
    if message.match != match or (parts.role and getattr(message, "role", None) != parts.role):
        raise MessageError("mismatch", f"{message.TYPE} for {message.match} on {key}")


@functools.lru_cache(maxsize=1024)
def _parsed(key: str) -> keys.Key | None:
    """keys.parse, once per key (a match puts a handful, each many times a second)."""
    try:
        return keys.parse(key)
    except ValueError:
        return None
