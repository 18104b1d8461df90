"""Running one trial against the study's matches: a slot (Admission: this machine's pool or a match
host), the match started on the server's warm pool (services/runtime/pool.py) or on a match host
(services/study/remote.py), the participant's seat bridged to it, their Ready, and the judgement
of its recording, written down in the journal and in a sidecar `<match>.study.json` beside it.

A trial is done only if its recording is complete (read back and checked); a trial whose match
fails to start, runs past its time or leaves an incomplete recording is marked `failed` and
offered again as a new attempt (services/study/visit.py)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from services.human.gateway import Bridge
from services.population.seat import PersonSeat
from services.recorder.service import recording_path
from services.runtime.launch import MatchPlan
from services.runtime.pool import Pool, Refused
from services.study.connection import Socket, first
from services.study.core import AROUND, SET_UP, Admission, Lag, Study, Trial
from services.study.judge import Judge, judge
from services.study.remote import Remote
from services.study.serving import Serving
from shared import page
from shared.game import FPS, other
from shared.messages import State as GameState
from shared.page import Problem, Queue, Wait

log = logging.getLogger("tsf.study")
PROBLEM = "The game could not be started. Please tell the experimenter."
WARM_UP = 60.0  # seconds to wait for a match's services to take it before offering its trial anyway
SETTING_UP = "Your next game is being set up."


class Judged(NamedTuple):
    """How a trial's match ended: its recording's kills and problems (the judge's verdict), the
    launcher's own failure line, if the match failed before its end ("" if not), and whether a
    service of the pool refused the match (it cannot play its part: every attempt would fail)."""

    kills: int | None
    problems: list[str]
    failure: str
    refused: bool = False


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
    path, failure, refused = recording_path(plan.directory, plan.match), "", False
    try:
        if host and remote is not None:
            remote.run(host, plan, stop, on_taken)
        else:
            pool.play(plan, stop, on_taken)
    except Exception as error:  # noqa: BLE001 - any failure fails the trial, never the server
        failure, refused = str(error) or type(error).__name__, isinstance(error, Refused)
    return Judged(*judged(path, role), failure, refused)


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
    sidecar = {**study.record(trial, status, kills), **({"problems": problems} if problems else {})}
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
        self.cut: set[str] = set()  # the matches an earlier server left cut short (run_study's reconcile)

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

    async def cannot_play(self, socket: Socket, trial: Trial, why: str) -> None:
        """Tell the participant at once that their trial cannot be played (every new attempt would
        fail the same way; they may resume once the study is mended), a trial's attempt written
        down as failed with `why`."""
        if not trial.practice:
            settle(self.study, trial, None, [why])
        else:
            log.error("the practice game %s cannot be set up: %s", trial.match, why)
        socket.send(Problem(text=PROBLEM))
        await socket.close()

    async def set_up(self, socket: Socket, trial: Trial) -> MatchPlan | None:
        """The trial's match plan; None (the participant told, the attempt failed) where its
        variant names a policy that cannot play the seat (a UsageError) or that fails to load
        however it fails (OSError: its weights file gone), before any slot is taken."""
        try:
            return self.plan(trial)
        except Exception as error:  # noqa: BLE001 - a policy from outside may raise anything as it loads
            why = str(error) if isinstance(error, ValueError) else f"{type(error).__name__}: {error}"
            await self.cannot_play(socket, trial, f"its match cannot be set up: {why}")
            return None

    async def start(
        self, socket: Socket, trial: Trial, plan: MatchPlan
    ) -> tuple[asyncio.Future, threading.Event, asyncio.Event, str] | None:
        """Take a free slot (telling the participant their place) and start the trial's match
        there: its future (run_trial's Judged), its stop, its `taken` (every service took it) and
        its host ("" for this machine); None if the participant left first (nothing started)."""
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
        return running, stop, taken, host

    async def play(self, socket: Socket, trial: Trial, obs: bool, offer: page.Trial) -> dict | None:
        """Run one trial: wait for a free match, start it (its processes start while the participant
        reads the `offer`, and its sim waits for them: a warm start), then play it from their Ready
        for at most its length and `trial_timeout`. Returns the sidecar and `played` (whether the
        participant played the game to its end), or None if the participant left (a match they
        started runs out with their ship idle; one they had not is ended; either is marked dropped)
        or was told the trial cannot be played (its match refused by a service of the pool: the
        attempt is failed at once, and its slot free)."""
        plan = await self.set_up(socket, trial)
        started = plan and await self.start(socket, trial, plan)
        if not started:
            return None
        running, stop, taken, host = started
        seat = await self.bridge(socket, trial, bool(host), obs, stop, taken, running)
        if running.done() and not running.cancelled() and running.result().refused:  # never offered
            seat.close()
            await self.cannot_play(socket, trial, running.result().failure)
            return None
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
            kills, problems, failure, _ = done.result()
            if failure and not dropped:  # the page went: the recording alone says whether it was played
                problems = [failure, *problems]
        if trial.practice:  # no trial: nothing written down
            return {"status": "failed" if problems else "done", "kills": kills}
        return settle(self.study, trial, kills, problems)
