"""The recorder service: a thin shell that writes everything a match puts on the bus to its log.

The zenoh callback only timestamps and queues the bytes (it never blocks the session's receive
thread); a drain thread validates, writes and tracks gaps. Bad input is counted and dropped.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from pathlib import Path

import zenoh

from services.agent import library
from services.provenance import provenance, sidecar
from services.recorder.log import GapTracker, LogWriter, read_log
from shared import keys
from shared.bus import BusConfig, Drops, session, until_stopped
from shared.errors import Failure, UsageError
from shared.game import ROLES, GameConfig
from shared.messages import Message, MessageError, Start, State, Summary, decode_any

log = logging.getLogger("tsf.recorder")
_DONE = object()


def recording_path(directory: str | Path, match: str) -> Path:
    return Path(directory) / f"{keys.check_match(match)}.tsflog"


def run_recorder(
    bus: BusConfig,
    match: str,
    directory: str | Path = "recordings",
    stop: threading.Event | None = None,
    wait_seats: float = 10.0,
) -> Path:
    """Record `match` until its summary is written or `stop` is set; returns the log's path.
    Restarted on the same directory during the match, it appends to the same log after cutting any
    torn tail; the log of a finished match (one with a summary) is never appended to (UsageError),
    and a second start of the id ends the recording before it is written (Failure): one log, one match.

    Its liveliness token (which the sim waits for) says that the seats' first actions will reach
    it. A client (run_match's topology: the sim is the router) declares it as soon as it has
    subscribed: every action passes the router, which has the subscription before the token
    (declared in order on the one link), so the token can come long before the seats' players do,
    and a study can offer the trial without waiting for a person's Ready. A peer declares it once
    both seats' players are seen, or after `wait_seats` seconds: it learns of the other peers over
    gossip after the sim has seen them, so a token declared at once could start the match before
    the seats' first actions reach this recorder."""
    stop = stop or threading.Event()
    path = recording_path(directory, match)
    if path.exists() and any(r.key == keys.summary(match) for r in read_log(path)[0]):
        raise UsageError(
            "--match", match, f"{path} holds a finished match of this id; give the new one another id"
        )
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    drops = Drops("recorder")

    def on_sample(sample: zenoh.Sample) -> None:
        inbox.put((str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))

    second: list[Start] = []  # a start after the log's first: another match under this id

    def drain(writer: LogWriter, gaps: GapTracker, started: bool) -> None:
        while True:
            item = inbox.get()
            if item is _DONE:
                return
            key, data, t = item
            try:
                message = decode_any(data)
                _check_key(key, message, match)
            except MessageError as error:
                drops.drop(key, error)
                continue
            if isinstance(message, Start) and started:
                second.append(message)
                stop.set()
                return
            if isinstance(message, Start) and not started:
                _write_provenance(path, message)
            started = started or isinstance(message, Start)
            if isinstance(message, State) and (gap := gaps.see(message.frame)):
                writer.write_gap(*gap)
            writer.write(key, data, t)
            if isinstance(message, Summary):
                stop.set()

    with LogWriter(path) as writer:
        last = max((_frame(r.data) for r in writer.last_records if r.key == keys.state(match)), default=-1)
        if writer.cut_bytes:
            log.warning("cut a torn tail of %d bytes from %s", writer.cut_bytes, path)
        started = any(r.key == keys.start(match) for r in writer.last_records)
        drainer = threading.Thread(target=drain, args=(writer, GapTracker(last), started), daemon=True)
        drainer.start()
        with session(bus) as z, z.declare_subscriber(keys.everything(match), on_sample):
            if bus.mode != "client":
                _wait_for_seats(z, match, wait_seats, stop)
            with z.liveliness().declare_token(keys.alive(match, "recorder")):
                until_stopped(stop)
                time.sleep(0.5)  # actions still in flight after the summary (they come over other links)
        inbox.put(_DONE)
        drainer.join()
    if second:
        raise Failure(f"{path}: a second match started under the id {match}; it was not recorded")
    return path


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
    """Name what made the recording beside it (services/provenance.py), with the match's rules."""
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
    try:
        parts = keys.parse(key)  # each kind of key is named for the type it carries
    except ValueError:
        parts = None
    if parts is None or parts.kind != message.TYPE:
        raise MessageError("type", f"{message.TYPE} on {key}")
    if message.match != match or (parts.role and getattr(message, "role", None) != parts.role):
        raise MessageError("mismatch", f"{message.TYPE} for {message.match} on {key}")
