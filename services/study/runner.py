"""`tsf study`: the study's front door on the human gateway. Each participant's socket stays open
across all their trials; each trial is a match of its own, played by the server's warm pool
(services/runtime/pool.py: one sim, agent, recorder and adapter process for all its matches, kept
for the server's life), the participant's seat bridged from this process over the pool's bus.

Many participants play at once: a match starts with an order to the pool, so it is ready by the
time the participant has read the trial's offer. At most `max_matches` run at once; the other
trials wait in a queue whose place and estimated wait the participant sees. A trial is done only
if its recording is complete (read back and checked); a trial whose match fails to start, runs
past its time or leaves an incomplete recording is marked `failed` and offered again as a new
attempt.

Match hosts on other machines add capacity (`Serving.hosts`: the study's router): once this
machine's `max_matches` are taken, a trial's match is offered to a live host with a free slot
(services/study/remote.py), the participant's seat is bridged over the router, and the host's
recording is fetched into the study directory with its hash checked before the trial is judged.

Study messages (down): `consent` (text), `declined` (text: the participant said no, nothing was
recorded), `participant` (id and resume key, kept by the browser), `check` (an attention check,
services/study/crowd.py), `wait` (reason, seconds: a game is being set up), `trial` (session,
trial, role, the agent's label; what to read first), `queue` (place, seconds to wait, while the
trial waits for a free match), then the gateway's `state`/`end` frames, and at last `done` (the
end text, code and redirect), `screened` or `problem`. Up: `hello` (optionally with the
participant id and key to resume, the link's parameters and signature), `consent` or `decline`,
`answer`, `ready`, `keys`. The experimenter's dashboard is served beside it
(services/study/dashboard.py).

The shell is three small classes: `Front` admits each participant (consent or resume, rate limits),
`Visit` is one participant's session (practice, attention checks, trials in order, a failed one
again) and `TrialRunner` runs one trial's match (slot, start, seat, Ready, judgement).

Each trial's metadata goes into a sidecar `<match>.study.json` beside its recording, rather than
onto the bus: the participant id is nobody's business but the study's (bus traffic may cross a lab
network), no service needs it, and the contract stays as it is; the match id names study,
participant, session and trial too, so a recording alone still says where it belongs.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import json
import logging
import os
import threading
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import IO, NamedTuple

import websockets
import zenoh
from websockets.asyncio.server import ServerConnection
from websockets.protocol import State

from services.human.core import BadInput, Controls, PerAddress, Quiet, RateLimit, points
from services.human.gateway import Bridge, Gateway, Outbox, Web, client_address, receive_first, refuse
from services.population.seat import PersonSeat
from services.recorder.service import recording_path
from services.runtime.launch import MatchPlan
from services.runtime.pool import Pool, pool_name
from services.study.core import (
    AROUND,
    SET_UP,
    Admission,
    Lag,
    Participant,
    Study,
    StudyConfig,
    Trial,
    worker_id,
)
from services.study.crowd import FAILS, attention_check, write_bonuses
from services.study.dashboard import Dashboard, about, overview
from services.study.judge import Judge, judge
from services.study.remote import Remote
from shared import page
from shared.bus import BusConfig, until_stopped
from shared.errors import UsageError
from shared.game import FPS, ROLES, GameConfig, other
from shared.messages import State as GameState
from shared.page import (
    Answer,
    ConsentText,
    Declined,
    Done,
    Hello,
    Keys,
    PageMessage,
    ParticipantId,
    Problem,
    Queue,
    Screened,
    Stopped,
    Wait,
)
from shared.secret import same_secret, signature

log = logging.getLogger("tsf.study")
PROBLEM = "The game could not be started. Please tell the experimenter."
RETRIES = 3  # failed attempts in a row before the participant is told of a problem
READ_TIMEOUT = 900.0  # seconds a participant may take to read the consent text or the instructions
THREADS = 512  # threads for blocking work off the event loop: two per running match, and more
DRAIN = 60.0  # seconds the stopping server waits for its matches to end and be written down
WARM_UP = 60.0  # seconds to wait for a match's services to take it before offering its trial anyway
ARRIVAL_BURST = 20  # participant ids issued at once, beyond the rate
ADDRESS_BURST = 5  # ... to one address
RECONNECT_BURST = 5  # reconnects of one participant at once (reloads), and failed resumes of one address
SCREENED = "Thank you. This study cannot go on: two attention checks were not passed."
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
SETTING_UP = "Your next game is being set up."
UNSIGNED = "This link is not signed for its worker id. Please open the link exactly as the study gave it."
RECONNECTS = "Too many reconnects. Please wait a minute, then reload the page."
STOPPED = (
    "The study has stopped for now. Everything you did so far is kept: open your study link again "
    "later to go on where you left off (a game cut short is played again)."
)


@dataclass(frozen=True)
class Serving:
    """How the server runs the study (not part of the protocol: changing it keeps the journal)."""

    max_matches: int = 4  # matches at once; more trials wait in a queue
    trial_timeout: float = 120.0  # seconds a match may take beyond its length, start-up included
    low_latency: bool = True  # zenoh's low-latency transport within each match
    test_token: str = ""  # a hello with this `test` token may ask for the observation values (stand-ins)
    arrivals: float = 1.0  # new participant ids a second, on average (bursts of ARRIVAL_BURST)
    # ... and from one address (bursts of ADDRESS_BURST; 0: none), so that one client cannot drain
    # the ids of all; behind a reverse proxy, the address it forwards (Web.trusted)
    arrivals_per_address: float = 0.1
    # Reconnects (a reload resumes, and cuts the trial being played) of one participant a second,
    # and failed resumes (an unknown id or key) of one address (bursts of RECONNECT_BURST; 0: none)
    reconnects: float = 0.1
    # Seconds the running matches' frames may reach the server late (Lag, the worst of the last 5 s)
    # before no new match starts on this machine until they catch up (0: no hold)
    max_lag: float = 0.025
    ready_timeout: float = 120.0  # seconds an offered trial waits for Ready; then its match and slot go
    hosts: BusConfig | None = None  # the router where match hosts offer their slots; None: local only
    # A signed link's secret: new participants need a worker id and its signature (`sig`, the
    # HMAC-SHA256 of the id with this secret, shared.secret.signature); b"": links are not signed.
    link_secret: bytes = b""
    host_secret: bytes = b""  # shared with the match hosts: every message between them is sealed with it
    dashboard: Web | None = None  # where the experimenter's dashboard is served (services/study/dashboard.py)
    dashboard_token: str = ""  # ... to whoever shows this token


SERVING, WEB = Serving(), Web()


class Socket:
    """One participant's connection: its input read in the background, its output through an outbox."""

    def __init__(self, ws: ServerConnection) -> None:
        self.ws = ws
        self.controls = Controls()
        self.outbox = Outbox(asyncio.get_running_loop())
        self.events: asyncio.Queue[str] = asyncio.Queue()
        self.gone = asyncio.Event()
        self.answer = ""  # the last answer to an attention check
        self.tasks = [asyncio.ensure_future(self._read()), asyncio.ensure_future(self._pump())]

    def send(self, message: PageMessage) -> None:
        self.outbox.offer(message.encode(), control=True)

    @property
    def closed(self) -> bool:
        """Whether the participant has gone, or is going: a close frame received counts at once,
        before the reader has seen the end."""
        return self.gone.is_set() or self.ws.state is not State.OPEN

    async def _read(self) -> None:
        try:
            async for text in self.ws:
                message = self.controls.receive(text, ("consent", "decline", "ready", "keys", "answer"))
                if isinstance(message, Answer):
                    self.answer = message.answer
                if message is not None and not isinstance(message, Keys):
                    self.events.put_nowait(message.TYPE)
        except BadInput as error:
            await self.ws.close(1008, str(error))
        except websockets.ConnectionClosed:
            pass
        finally:
            self.gone.set()

    async def _pump(self) -> None:
        with contextlib.suppress(websockets.ConnectionClosed):
            await self.outbox.pump(self.ws)

    async def wait_for(self, kind: str | tuple[str, ...], timeout: float = READ_TIMEOUT) -> str:
        """Wait for the participant's `kind` message (or one of the kinds) and return its kind; ""
        if the socket closed first or it took longer than `timeout` seconds (the socket is then
        closed: an idle socket holds nothing)."""
        event: asyncio.Future | None = None
        try:
            async with asyncio.timeout(timeout):
                while True:
                    event = asyncio.ensure_future(self.events.get())
                    await first(event, self.gone.wait())
                    if not event.done():
                        return ""
                    if event.result() in ((kind,) if isinstance(kind, str) else kind):
                        return event.result()
        except TimeoutError:
            await self.ws.close(1008, "idle for too long")
            self.gone.set()
            return ""
        finally:
            if event is not None and not event.done():  # never a get left pending on the loop
                event.cancel()

    async def close(self) -> None:
        """Let the outbox empty (what was just offered is queued after one turn of the loop), then close."""
        await asyncio.sleep(0)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self.outbox.flushed.wait(), 2.0)
        await self.ws.close()
        for task in self.tasks:
            task.cancel()


async def first(*waits: Awaitable) -> None:
    """Return when the first of `waits` is done; pending coroutines are cancelled, futures given
    are left running."""
    futures = [asyncio.ensure_future(w) for w in waits]
    try:
        await asyncio.wait(futures, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for wait, future in zip(waits, futures, strict=True):
            if future is not wait:
                future.cancel()


class Judged(NamedTuple):
    """How a trial's match ended: its recording's kills and problems (the judge's verdict), and
    the launcher's own failure line, if the match failed before its end ("" if not)."""

    kills: int | None
    problems: list[str]
    failure: str


def run_trial(
    plan: MatchPlan,
    role: str,
    stop: threading.Event,
    pool: Pool,
    remote: Remote | None = None,
    host: str = "",
    on_taken: Callable[[], None] = lambda: None,
    judged: Callable[[Path, str], tuple[int | None, list[str]]] = judge,
) -> Judged:
    """Run a trial's match (on this server's `pool`, or on match `host`, whose recording `remote`
    fetches) and judge its recording (`judged`: the server's Judge, in a process of its own). A
    complete recording with the participant's seat played from this server has no problems.
    `on_taken` is called once every service has taken the match (the launcher's watch of its
    tokens). The recording is read once, by the judge, whether the match ended or failed."""
    path, failure = recording_path(plan.directory, plan.match), ""
    try:
        if host and remote is not None:
            remote.run(host, plan, stop, on_taken)
        else:
            pool.play(plan, stop, on_taken)
    except Exception as error:  # noqa: BLE001 - any failure fails the trial, never the server
        failure = str(error) or type(error).__name__
    return Judged(*judged(path, role), failure)


class Metered(Bridge):
    """A seat's bridge that times each frame's arrival for the machine's Lag."""

    def __init__(self, lag: Lag, *args: object) -> None:
        self.lag = lag
        super().__init__(*args)

    def _on_state(self, state: GameState) -> None:
        self.lag.frame(self.match, state.frame, time.monotonic())
        super()._on_state(state)


class Matches:
    """The running matches: slots (Admission), a stop per match, and each participant's one match."""

    def __init__(self, cap: int) -> None:
        self.admission = Admission(cap)
        self.lag = Lag()  # how late this machine's matches' frames arrive: new ones wait while it is high
        self.stops: dict[str, threading.Event] = {}  # match -> its stop
        self.endpoints: dict[str, str] = {}  # match -> its sim's endpoint, "" on a match host (spectators)
        self.of: dict[str, tuple[asyncio.Future, threading.Event]] = {}  # participant -> their match
        self.running: set[asyncio.Future] = set()
        self.lock = threading.Lock()  # stops is read by stop_all from another thread
        self.closed = False  # set by stop_all: a match added later is stopped at once
        self.changed = asyncio.Event()  # replaced after each change; waiters hold the old one

    def notify(self) -> None:
        self.changed.set()
        self.changed = asyncio.Event()

    def add(self, trial: Trial, running: asyncio.Future, stop: threading.Event, endpoint: str) -> None:
        self.endpoints[trial.match] = endpoint
        with self.lock:
            self.stops[trial.match] = stop
            if self.closed:
                stop.set()
        self.of[trial.participant] = (running, stop)
        self.running.add(running)

        def ended(_: asyncio.Future) -> None:
            self.running.discard(running)
            self.endpoints.pop(trial.match, None)
            with self.lock:
                del self.stops[trial.match]
            if self.of.get(trial.participant, (None,))[0] is running:
                del self.of[trial.participant]
            self.admission.end(trial.match)
            self.lag.end(trial.match)
            self.notify()

        running.add_done_callback(ended)

    async def end_previous(self, participant: str) -> None:
        """One match per participant: a cut match still running out is ended first, and settled
        (its attempt `done` or `failed`) before the next trial is chosen."""
        if participant in self.of:
            running, stop = self.of[participant]
            stop.set()
            await asyncio.wait({running})

    async def drained(self) -> None:
        """Every match has ended and been written down (a cut one's sidecar comes last)."""
        while self.running:
            await asyncio.wait(set(self.running))
            await asyncio.sleep(0)  # the done callbacks run

    def stop_all(self) -> None:
        """From any thread: end every running match and its processes."""
        with self.lock:
            self.closed = True
            for stop in self.stops.values():
                stop.set()


def settle(study: Study, trial: Trial, kills: int | None, problems: list[str]) -> dict:
    """Write down how an attempt ended, `done` without problems, else `failed` (offered again),
    and its sidecar beside its recording; returns the sidecar."""
    status = "failed" if problems else "done"
    if problems:
        log.error("trial %s failed: %s", trial.match, "; ".join(problems))
    sidecar = study.record(trial, status, kills)
    recordings = study.directory / "recordings"
    recordings.mkdir(parents=True, exist_ok=True)
    (recordings / f"{trial.match}.study.json").write_text(json.dumps(sidecar, indent=1))
    log.info("%s: %s, %s kills", trial.match, status, kills)
    return sidecar


def reconcile(study: Study) -> list[dict]:
    """Settle every attempt an earlier server left `running` or `dropped` (killed mid-trial, or
    just after one) by its recording, before anyone is served: a complete one is `done` and never
    played again, any other `failed`; each gets its sidecar. Returns the sidecars."""
    recordings = study.directory / "recordings"
    return [
        settle(study, trial, *judge(recording_path(recordings, trial.match), trial.role))
        for trial in study.unsettled()
    ]


class TrialRunner:
    """Runs one participant's trial at a time on the study's matches: waits for a free slot, starts
    the match (on this server's pool, or on a match host of `remote`), bridges the participant's
    seat to it, and judges and writes down how it ended. Shared by every participant; its fields
    are the study's and the server's settings."""

    def __init__(
        self,
        study: Study,
        serving: Serving,
        matches: Matches,
        pool: Pool,
        judge: Judge,
        remote: Remote | None = None,
    ) -> None:
        self.study, self.serving, self.matches, self.pool, self.remote = study, serving, matches, pool, remote
        self.judge = judge
        config = study.config
        self.recordings, self.practice = study.directory / "recordings", study.directory / "practice"
        self.practice_frames = round(config.practice_seconds * FPS)
        self.match_seconds = config.trial_seconds + AROUND  # a slot's time: a queue's estimated wait
        self.limit = config.trial_seconds + serving.trial_timeout  # seconds a trial may play

    async def slot(self, socket: Socket, match: str) -> bool:
        """Wait for a free match, telling the participant their place; False if they leave."""
        admission, told, lag = self.matches.admission, None, self.serving.max_lag
        while True:
            admission.hosts = self.remote.hosts() if self.remote else {}
            late = self.matches.lag.worst(time.monotonic())
            if admission.held != (held := bool(lag) and late > lag):
                what = ("fall behind", "wait") if held else ("have caught up", "start again")
                log.warning("this machine's matches %s (frames up to %.0f ms late): new ones %s", what[0],
                            late * 1e3, what[1])  # fmt: skip
            admission.held = held
            if admission.start(match):
                break
            place = admission.place(match)
            if place != told:
                wait = round(admission.wait(place, self.match_seconds))
                socket.send(Queue(place=place, wait=wait))
                told = place
            with contextlib.suppress(TimeoutError):  # held: asked again as the lag falls
                async with asyncio.timeout(1.0 if admission.held else None):
                    await first(self.matches.changed.wait(), socket.gone.wait())
            if socket.gone.is_set():
                admission.end(match)
                self.matches.notify()
                return False
        return True

    def plan(self, trial: Trial) -> MatchPlan:
        """The trial's match: the participant's seat a person's, the other the variant's agent."""
        agent = other(trial.role)
        seats = {trial.role: PersonSeat(), agent: trial.variant.seat(agent)}
        config, serving = self.study.config, self.serving
        frames, directory = (
            (self.practice_frames, self.practice) if trial.practice else (config.frames, self.recordings)
        )
        return MatchPlan(
            trial.match, trial.seed, frames, directory=directory, low_latency=serving.low_latency,
            wait_players=serving.ready_timeout + self.limit, wait_services=30.0,
            timeout=serving.ready_timeout + self.limit, **seats,
        )  # fmt: skip

    async def bridge(
        self,
        socket: Socket,
        trial: Trial,
        hosted: bool,
        obs: bool,
        stop: threading.Event,
        taken: asyncio.Event,
        running: asyncio.Future,
    ) -> Bridge:
        """The participant's seat in the trial's match, from the pool's session (for a `hosted`
        match, the router's), once every service has taken the match (`taken`, set by its
        launcher, which watches the match's tokens): then a Ready starts the game at once. The
        wait ends early when the match has ended (`running`) or the participant left (the match
        is then stopped)."""
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(WARM_UP):
                await first(taken.wait(), running, socket.gone.wait())
        if socket.gone.is_set():  # left during set-up: the match ends
            stop.set()
        if not (taken.is_set() or running.done() or stop.is_set()):
            log.warning("trial %s: not every service has taken its match after %g s", trial.match, WARM_UP)
        if hosted and self.remote:  # another machine's frames: not this one's lag
            return Bridge(self.remote.z, trial.match, trial.role, socket.controls, socket.outbox, obs)
        return Metered(
            self.matches.lag, self.pool.z, trial.match, trial.role, socket.controls, socket.outbox, obs
        )

    async def play(self, socket: Socket, trial: Trial, obs: bool, offer: page.Trial) -> dict | None:
        """Run one trial: wait for a free match, start it (its processes start while the participant
        reads the `offer`, and its sim waits for them: a warm start), then play it from their Ready
        for at most its length and `trial_timeout`. Returns the sidecar and `played` (whether the
        participant played the game to its end), or None if the participant left (a match they
        started runs out with their ship idle; one they had not is ended; either is marked dropped)."""
        try:
            plan = self.plan(trial)
        except ValueError as error:  # its variant names a policy that cannot play the seat (UsageError)
            # Before any slot is taken; told at once, since every new attempt would fail the same way
            # (the participant may resume once the study is mended).
            if not trial.practice:
                settle(self.study, trial, None, [f"its match cannot be set up: {error}"])
            else:
                log.error("the practice game %s cannot be set up: %s", trial.match, error)
            socket.send(Problem(text=PROBLEM))
            await socket.close()
            return None
        if not await self.slot(socket, trial.match):
            return None
        try:
            if socket.closed:  # left as the slot came: nothing starts
                self.matches.admission.end(trial.match)
                self.matches.notify()
                return None
            socket.send(Wait(reason=SETTING_UP, seconds=round(SET_UP)))
            host = self.matches.admission.running[trial.match]  # Admission.LOCAL: this machine
            if not trial.practice:
                self.study.record(trial, "running")
            stop, taken, loop = threading.Event(), asyncio.Event(), asyncio.get_running_loop()
            if host:
                log.info("trial %s runs on match host %s", trial.match, host)
            running = asyncio.ensure_future(
                asyncio.to_thread(
                    run_trial, plan, trial.role, stop, self.pool, self.remote, host,
                    lambda: loop.call_soon_threadsafe(taken.set), self.judge,
                )
            )  # fmt: skip
            self.matches.add(trial, running, stop, "" if host else self.pool.endpoint)
        except BaseException:  # the slot goes back: matches.add frees it from here on, when the match ends
            self.matches.admission.end(trial.match)
            self.matches.notify()
            raise
        seat = await self.bridge(socket, trial, bool(host), obs, stop, taken, running)
        ready = await self.live(socket, trial, seat, offer, running, stop)
        seat.close()
        dropped = socket.gone.is_set() and not (ready and running.done())
        if dropped and not trial.practice:  # resumable at once; the sidecar follows when the match has ended
            self.study.record(trial, "dropped")
            running.add_done_callback(lambda done: self.outcome(trial, done, dropped))
            return None
        await asyncio.wait({running})  # ended by the stop, if not over
        # played to its end: Ready came, and the match ended with its summary (no launcher's failure)
        played = ready and not running.cancelled() and not running.result().failure
        return {**self.outcome(trial, running, dropped), "played": played}

    async def live(
        self,
        socket: Socket,
        trial: Trial,
        seat: Bridge,
        offer: page.Trial,
        running: asyncio.Future,
        stop: threading.Event,
    ) -> bool:
        """Offer the trial and play it from the participant's Ready until the match ends, they
        leave, or it runs past its limit; False (the match ended at once) if no Ready came."""
        socket.send(offer)
        if not await socket.wait_for("ready", self.serving.ready_timeout):
            stop.set()  # not started: ended at once; a silent participant frees the slot
            return False
        seat.live()
        try:
            async with asyncio.timeout(self.limit):
                await first(running, socket.gone.wait())
        except TimeoutError:
            log.error("trial %s ran past its %g s: ended", trial.match, self.limit)
            stop.set()
            await asyncio.wait({running})
        return True

    def outcome(self, trial: Trial, done: asyncio.Future, dropped: bool) -> dict:
        """How the ended match went: a practice game's status and kills, a trial's sidecar."""
        if done.cancelled():
            kills, problems = None, ["cancelled"]
        else:
            kills, problems, failure = done.result()
            if failure and not dropped:  # the page went: the recording alone says whether it was played
                problems = [failure, *problems]
        if trial.practice:  # no trial: nothing written down
            return {"status": "failed" if problems else "done", "kills": kills}
        return settle(self.study, trial, kills, problems)


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
        self.reconnects = PerAddress(serving.reconnects, RECONNECT_BURST)  # by participant, or address
        self.quiet = Quiet()  # refusals over a limit: logged once per address and minute

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
        study, config = self.study, self.study.config
        address = client_address(socket.ws, self.trusted)
        if hello.participant is not None:
            participant = study.resume(hello.participant, hello.key or "")
            if participant is None:
                if not self.reconnects.allow(address):
                    await self.over_limit(socket, address, RECONNECTS, "too many failed resumes")
                    return None
                await self.refuse(socket, study.participants.get(hello.participant), UNKNOWN, "resume key")
            elif not self.reconnects.allow(f"participant {participant.id}"):
                await self.over_limit(socket, address, RECONNECTS, f"too many reconnects of {participant.id}")
                return None
            return participant
        ids = [worker_id(v) for v in config.crowd.ids(hello.link or {})]
        worker = ids[0] or worker_id(hello.worker)
        if worker is None or None in ids:
            await refuse(socket.ws, NO_WORKER)
            return None
        if self.serving.link_secret and not (
            worker and same_secret(hello.sig, signature(self.serving.link_secret, worker))
        ):
            await refuse(socket.ws, UNSIGNED)
            return None
        link = {k: v for k, v in zip(("study", "session"), ids[1:], strict=True) if v}
        if study.taken(worker):  # back through the platform's link: another tab, browser or device
            return await self.returning(socket, study.by_worker(worker), link)
        socket.send(ConsentText(text=config.consent_text()))
        answer = await socket.wait_for(("consent", "decline"))
        if answer == "decline":  # no id, nothing written
            socket.send(Declined(text=DECLINED))
            await socket.close()
        if answer != "consent":
            return None
        if study.taken(worker):  # a second window of the same worker consented first
            return await self.returning(socket, study.by_worker(worker), link)
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
        self, socket: Socket, participant: Participant, link: dict[str, str]
    ) -> Participant | None:
        """A worker id that has taken part comes back through a link (a crashed tab, another
        browser, a phone): resumed where they left off if the link is proven theirs (a finished
        or screened-out one is shown their end again), else refused, journalled and logged."""
        if self.proven(participant, link):
            log.info("participant %s resumes through the platform's link", participant.id)
            socket.send(ParticipantId(participant=participant.id, key=participant.key))
            return participant
        finished = self.study.next_trial(participant) is None or participant.screened
        await self.refuse(
            socket, participant, TAKEN if finished else NOT_YOURS, "taken" if finished else "unproven"
        )
        return None

    async def refuse(self, socket: Socket, participant: Participant | None, text: str, why: str) -> None:
        """Refuse a returning participant with whom to contact; journalled (the dashboard shows it)
        and logged."""
        contact = self.study.config.crowd.contact or CONTACT
        if participant is not None:
            self.study.refused(participant, why)
        log.warning(
            "refused %s from %s: %s",
            participant.id if participant else "a resume",
            socket.ws.remote_address[0],
            why,
        )
        await refuse(socket.ws, f"{text.rstrip('.')}. If this is wrong, please contact {contact}.")


class Visit:
    """One participant's session: their practice game, attention checks and trials in order, a
    failed trial offered again, until the study is done for them or they leave."""

    def __init__(
        self, study: Study, runner: TrialRunner, socket: Socket, participant: Participant, obs: bool
    ) -> None:
        self.study, self.runner, self.socket, self.participant, self.obs = (
            study,
            runner,
            socket,
            participant,
            obs,
        )

    def offer(self, trial: Trial, last: int | None, again: bool) -> page.Trial:
        """The `trial` message: where the game sits in the study, what to read first."""
        config = self.study.config
        return page.Trial(
            role=trial.role, agent=trial.agent, last=last, session=trial.session,
            sessions=len(config.variants), trial=trial.trial, trials=config.trials, again=again,
            practice=trial.practice,
            instructions=config.instructions.get(trial.role, ""),
            points=points(GameConfig()) if config.show_points else None,
        )  # fmt: skip

    async def attend(self, trial: Trial) -> bool:
        """The attention check due before `trial`, if any; False (the page sent on to the
        screened-out address) once the participant has failed FAILS, or if they left."""
        config, socket, participant = self.study.config, self.socket, self.participant
        if config.crowd.check_due(trial.session, trial.trial, len(participant.checks)):
            check, word = attention_check(f"{config.seed}/{participant.id}/check/{len(participant.checks)}")
            socket.send(check)
            if not await socket.wait_for("answer"):
                return False
            self.study.check(participant, socket.answer == word)
        if participant.screened:
            redirect = config.crowd.redirect(config.crowd.screened_out_url, participant.code)
            socket.send(Screened(text=SCREENED, redirect=redirect))
            log.info("participant %s is screened out: %d attention checks failed", participant.id, FAILS)
            await socket.close()
            return False
        return True

    async def run(self) -> None:
        """The participant's remaining trials, after a practice game if the study has one and they
        have not begun; a failed trial is offered again, and a problem is shown once RETRIES in a
        row failed before the participant could play them to the end: a game played to its end and
        judged failed (under overload, the server's recorder fell behind; or the page stopped
        answering) never sends its player away, it is offered again."""
        study, socket, participant, matches = self.study, self.socket, self.participant, self.runner.matches
        last, failures, again = None, 0, False
        await matches.end_previous(participant.id)  # a reload's practice game still running out
        practice = study.practice(participant)
        if (
            practice is not None
            and await self.runner.play(socket, practice, self.obs, self.offer(practice, None, False)) is None
        ):
            return
        while True:
            await matches.end_previous(participant.id)  # settled first: never a trial twice
            trial = study.next_trial(participant)
            if trial is None:
                break
            if not await self.attend(trial):
                return
            sidecar = await self.runner.play(socket, trial, self.obs, self.offer(trial, last, again))
            if sidecar is None:
                return
            if sidecar["status"] == "failed":
                failures, again = failures + (not sidecar["played"]), True
                if failures < RETRIES:
                    continue
                socket.send(Problem(text=PROBLEM))
                await socket.close()
                return
            last, failures, again = sidecar["kills"], 0, False
        crowd = study.config.crowd
        code = crowd.code(participant.code)
        redirect = crowd.redirect(crowd.completion_url, code)
        text = study.config.end_text(bool(redirect))
        socket.send(Done(text=text, code=code, redirect=redirect))
        log.info("participant %s is done", participant.id)
        await socket.close()


def one_server(directory: Path) -> IO[str]:
    """The study directory's lock (`server.lock`, holding the server's pid), held until the file is
    closed, or the process ends however it ends. A second server on the same directory is refused
    (UsageError, naming the first one's pid): both ran, handed out the same participant ids and
    overwrote each other's records. An advisory lock (flock): on a shared file system that does not
    carry flock across machines, run one server per directory yourself."""
    directory.mkdir(parents=True, exist_ok=True)
    file = (directory / "server.lock").open("a+")
    try:
        fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        file.seek(0)
        other = file.read().strip() or "unknown"
        file.close()
        raise UsageError(
            "--out", directory, f"another study server (pid {other}) serves this study; stop it first"
        ) from None
    file.truncate(0)
    file.write(f"{os.getpid()}\n")
    file.flush()
    return file


def run_study(
    config: StudyConfig,
    directory: str | Path,
    web: Web = WEB,
    stop: threading.Event | None = None,
    on_ready: Callable[[Gateway], None] = lambda gateway: None,
    serving: Serving = SERVING,
) -> Study:
    """Serve the study until `stop` is set, then end every match it started; participants'
    progress lives in `directory` (a restarted server resumes everyone)."""
    stop = stop or threading.Event()
    lock = one_server(Path(directory))  # before anything is read or started
    study = Study(config, directory)
    for sidecar in reconcile(study):
        log.info("attempt %s left %s by an earlier server", sidecar["match"], sidecar["status"])
    matches = Matches(serving.max_matches)
    remote = Remote(serving.hosts, serving.host_secret) if serving.hosts else None
    adaptive = any(v.adaptive(role, 0) for v in config.variants for role in ROLES)
    pool = Pool(pool_name("study"), study.directory, adaptive, serving.low_latency)
    judging = None
    try:
        pool.__enter__()
        judging = Judge()
        runner = TrialRunner(study, serving, matches, pool, judging, remote)
        front = Front(study, serving, runner, web.trusted)
        gateway = Gateway(None, front.handle, web)
        # A running match holds a thread (run_trial) for its length, its start-up another: asyncio's
        # default pool (cores + 4 threads) would cap the matches at a handful, whatever hosts add.
        gateway.loop.set_default_executor(ThreadPoolExecutor(THREADS, thread_name_prefix="study"))
        if remote is not None:  # a host that comes or goes changes the room in the queue
            remote.on_change = lambda: gateway.loop.call_soon_threadsafe(matches.notify)
        board = serving.dashboard and Dashboard(
            serving.dashboard_token, serving.dashboard, gateway.loop,
            lambda: overview(study, matches.admission, front.playing), matches.endpoints.get,
            serving.low_latency, remote and remote.z, lambda match: about(study, match),
        )  # fmt: skip
        with gateway, board or contextlib.nullcontext():
            on_ready(gateway)
            until_stopped(stop)
            with contextlib.suppress(TimeoutError):  # the pages say so before their matches end
                asyncio.run_coroutine_threadsafe(front.stopping(), gateway.loop).result(5.0)
            matches.stop_all()
            with contextlib.suppress(TimeoutError):  # a match's thread that hangs: leave it to exit
                asyncio.run_coroutine_threadsafe(matches.drained(), gateway.loop).result(DRAIN)
    finally:
        pool.__exit__()
        if judging is not None:
            judging.close()
        if remote is not None:
            remote.close()
        study.close()
        bonuses = write_bonuses(study.config.crowd.bonus, study.participants.values(), study.directory)
        if bonuses is not None:
            log.info("bonuses written to %s", bonuses)
        lock.close()
    return study
