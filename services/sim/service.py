"""The sim service: a thin shell that runs the engine on the bus. It owns the clock.

A match (`MatchSim`) is played by a clock (clock.Clock): one loop per process, for its one match
(`tsf sim --match`, `run_sim`) or a pool's many (pool.py). Real-time mode ticks at the game's fps
on a monotonic schedule (tick k is due at start + k/fps, so lateness never accumulates) and
applies each seat's latest action; lockstep mode waits for both seats' answers to each state, but
never longer than `step_timeout`, and never for a seat whose player is gone. State is published
with congestion control *drop*: a frozen subscriber can never stall the sim.
"""

from __future__ import annotations

import contextlib
import logging
import os
import statistics
import threading
import time
from collections import Counter
from collections.abc import Callable

import zenoh

from services.sim.clock import Clock, on_phase
from services.sim.engine import Game
from services.sim.match import Seats, event_messages, start_message, state_message, summary_message
from shared import keys
from shared.bus import BusConfig, Drops, session, subscribe, weakly
from shared.errors import UsageError
from shared.game import ROLES, GameConfig
from shared.messages import Action, Summary, seat_actions
from shared.processes import threads

log = logging.getLogger("tsf.sim")
MODES = ("realtime", "lockstep")


def run_sim(bus: BusConfig, match: str, *args: object, **options: object) -> Summary:
    """Play one match on the bus and return its summary: `Sim(...).play()`."""
    return Sim(bus, match, *args, **options).play()


class Sim:
    """One match's sim on the bus, its own process's only match (`tsf sim --match`): the pool's
    per-match `MatchSim` on a clock of its own, until the match ends or `stop` is set. At the first
    frame it raises its priority by `priority` nice steps (in every thread; where permitted), above
    start-ups and bulk work."""

    def __init__(
        self,
        bus: BusConfig,
        match: str,
        seed: int = 0,
        config: GameConfig | None = None,
        mode: str = "realtime",
        policies: dict[str, str] | None = None,
        stop: threading.Event | None = None,
        wait_players: float = 10.0,
        wait_recorder: float = 0.0,
        step_timeout: float = 1.0,
        wait_adapter: float = 0.0,
        priority: int = 0,
    ) -> None:
        self.bus, self.stop, self.priority = bus, stop or threading.Event(), priority
        self.match = dict(
            match=match, seed=seed, config=config, mode=mode, policies=policies, wait_players=wait_players,
            wait_recorder=wait_recorder, step_timeout=step_timeout, wait_adapter=wait_adapter,
        )  # fmt: skip

    def play(self) -> Summary:
        """Play the match and return its summary (also published on the summary key)."""
        with session(self.bus) as z:
            clock = Clock()
            match = MatchSim(
                z, clock.changed, **self.match, on_first_frame=lambda: _raise_priority(self.priority)
            )
            match.open()
            clock.add(match)
            clock.run(self.stop, until_empty=True)
            assert match.summary is not None  # a closed match has published its summary
            return match.summary


class MatchSim:
    """One match on an open session, played by a `Clock` (alone, or with a pool's other matches).
    The fields are what the bus's callbacks share with the clock (under `changed`, the clock's).

    Waits up to `wait_players` seconds for both seats, then up to `wait_recorder` for a recorder
    and `wait_adapter` for an adapter (in adaptive matches); a seat still empty then plays no-op
    until its player arrives. Real time ticks at the game's fps (tick k due at the first frame +
    k/fps) with each seat's latest action; lockstep steps once both present seats have answered,
    or `step_timeout` after the state. State is put with congestion control *drop*: a frozen
    subscriber can never stall the clock. After the summary it keeps its declarations `LINGER`
    seconds (the last puts leave before its token goes), then undeclares them all (`closed`)."""

    LINGER = 0.2

    def __init__(
        self,
        z: zenoh.Session,
        changed: threading.Condition,
        match: str,
        seed: int = 0,
        config: GameConfig | None = None,
        mode: str = "realtime",
        policies: dict[str, str] | None = None,
        wait_players: float = 10.0,
        wait_recorder: float = 0.0,
        step_timeout: float = 1.0,
        wait_adapter: float = 0.0,
        on_first_frame: Callable[[], None] = lambda: None,
    ) -> None:
        if mode not in MODES:
            raise UsageError("--sim-mode", mode, "unknown", MODES)
        self.z, self.changed, self.match, self.mode = z, changed, match, mode
        self.policies = {role: (policies or {}).get(role, "") for role in ROLES}  # the contract wants both
        self.step_timeout, self.on_first_frame = step_timeout, on_first_frame
        self.game = Game(config, seed)
        self.period = 1.0 / self.game.config.fps
        self.seats, self.drops = Seats(), Drops("sim")
        self.answered_at: dict[tuple[str, int], int] = {}  # (role, frame) -> arrival time, for round trips
        self.observers: Counter[str] = Counter()  # live recorder and adapter tokens
        self.waits: list[tuple[Callable[[], bool], float]] = [
            (lambda: all(self.seats.present(r) for r in ROLES), wait_players),
            (lambda: self.observers["recorder"] > 0, wait_recorder),
            (lambda: self.observers["adapter"] > 0, wait_adapter),
        ]
        self.deadline: float | None = None  # of the first wait left, from when it began
        self.started: float | None = None  # monotonic time of the first frame, on the clock's phase
        self.phase = 0.0  # clock.Played.phase
        self.sent: dict[int, int] = {}  # frame -> when its state was put (perf_counter_ns)
        self.sent_at = self.summary_at = 0.0  # monotonic time of the last state put, and of the summary
        self.ticks: list[float] = []  # monotonic time of each real-time tick
        self.applied = (0, 0)
        self.ended = False
        self.summary: Summary | None = None
        self.closed = False
        self.declared = contextlib.ExitStack()

    def open(self) -> None:
        """Declare the match's token, subscribers and publishers on the session."""
        z, match, on = self.z, self.match, self.declared.enter_context
        fast = {"congestion_control": zenoh.CongestionControl.DROP, "express": True}
        self.state_pub = z.declare_publisher(keys.state(match), priority=zenoh.Priority.REAL_TIME, **fast)
        self.event_pub = z.declare_publisher(keys.event(match), **fast)
        self.declared.callback(self.state_pub.undeclare)
        self.declared.callback(self.event_pub.undeclare)
        liveliness = z.liveliness()
        on(liveliness.declare_token(keys.alive(match, "sim")))
        on(subscribe(z, keys.actions(match), seat_actions(match), weakly(self._on_action), self.drops))
        for key in (keys.seats_alive(match), keys.alive(match, "recorder"), keys.alive(match, "adapter")):
            on(liveliness.declare_subscriber(key, weakly(self._on_alive), history=True))

    def end(self) -> None:
        self.ended = True

    def due(self, now: float) -> float:
        if self.summary is not None:
            return self.summary_at + self.LINGER
        if self.ended:
            return now
        if self.started is None:
            while self.waits:
                condition, timeout = self.waits[0]
                self.deadline = self.deadline if self.deadline is not None else now + timeout
                if not condition() and now < self.deadline:
                    return self.deadline
                self.waits.pop(0)
                self.deadline = None
            return now
        if self.mode == "lockstep":
            return now if self.seats.answered(self.game.frame) else self.sent_at + self.step_timeout
        return self.started + (self.game.frame + 1) * self.period

    def tick(self) -> None:
        if self.summary is not None:
            self.closed = True
            self.declared.close()
        elif self.started is None:
            self._start()
        elif self.ended:
            self._finish()
        else:
            if self.mode == "realtime":
                self.ticks.append(time.monotonic())
            with self.changed:
                self.applied = self.seats.actions()
            self.game.step(*self.applied)
            self._publish()

    def _start(self) -> None:
        # At the states' priority: zenoh orders messages only within one priority, so a start put
        # at the default priority could arrive after state 0.
        start = start_message(self.game, self.match, "sim", self.mode, self.policies)
        self.z.put(keys.start(self.match), start.encode(), priority=zenoh.Priority.REAL_TIME)
        self.on_first_frame()
        self.started = on_phase(time.monotonic(), self.period, self.phase)  # the first frame is put now
        self._publish()

    def _publish(self) -> None:
        """Put the state and the events of the frame just played; the summary after the last."""
        game, match = self.game, self.match
        self.sent_at, self.sent[game.frame] = time.monotonic(), time.perf_counter_ns()
        self.state_pub.put(state_message(game, match, "sim", self.applied).encode())
        with self.changed:
            failed = self.seats.failure_events(match, "sim")
        for event in [*event_messages(game, match, "sim"), *failed]:
            self.event_pub.put(event.encode())
        if game.done or self.ended:
            self._finish()

    def _finish(self) -> None:
        with self.changed:
            trips = {
                role: [
                    (t - self.sent[f]) / 1e6
                    for (r, f), t in self.answered_at.items()
                    if r == role and f in self.sent
                ]
                for role in ROLES
            }
        timing = _timing(trips, self.ticks, self.period)
        summary = summary_message(
            self.game, self.match, "sim", self.drops.counts, timing, self.seats.failures
        )
        self.z.put(keys.summary(self.match), summary.encode())
        self.summary_at, self.summary = time.monotonic(), summary

    def _on_action(self, action: Action) -> None:
        arrived = time.perf_counter_ns()
        with self.changed:
            if self.seats.offer(action):
                self.answered_at.setdefault((action.role, action.frame), arrived)
            if self.mode == "lockstep":
                self.changed.notify_all()

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            key = keys.parse(sample.key_expr)
        except ValueError:  # a token none of our services declares
            return
        with self.changed:
            if key.role:
                (self.seats.arrive if sample.kind == zenoh.SampleKind.PUT else self.seats.leave)(key.role)
            elif key.service in ("recorder", "adapter"):
                self.observers[key.service] += 1 if sample.kind == zenoh.SampleKind.PUT else -1
            self.changed.notify_all()


def _raise_priority(steps: int) -> None:
    """Take `steps` nice steps above this thread's priority, in every thread of this process (Linux
    keeps a nice value per thread). False where it is not permitted (it needs CAP_SYS_NICE, which
    root has and a container may not, or a nice limit that allows it, RLIMIT_NICE): the threads
    keep their priority, and it says so in one log line."""
    if steps <= 0:
        return
    nice = max(-20, os.getpriority(os.PRIO_PROCESS, 0) - steps)
    try:
        for thread in threads():
            with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
                os.setpriority(os.PRIO_PROCESS, thread, nice)
    except PermissionError:
        log.info(
            "not permitted to raise the priority to nice %d (needs CAP_SYS_NICE or RLIMIT_NICE): it stays",
            nice,
        )


def real_time() -> bool:
    """Put every thread of this process (a pool's sim: its clock and the bus's threads it waits on)
    in the real-time class, at its lowest priority (SCHED_FIFO 1); threads started later inherit
    it. A due tick then runs at once, whatever else the machine runs, where a nice value only
    weighs a share among ordinary processes: 12 matches beside three busy processes had a tick
    jitter p99 of 7.8 ms with the clock's thread alone real-time (the others held it up), 4.9 ms
    with all (bench/sim_pool.py), 20-30 ms at nice -5 beside other work. A pool's sim sleeps
    between ticks and uses a few % of a core, and Linux keeps 5 % of each second for ordinary
    processes in any case. False where it is not permitted (CAP_SYS_NICE, or a real-time limit of
    at least 1, RLIMIT_RTPRIO; a container may have neither): the threads stay, and it says so in
    one line."""
    try:
        for thread in threads():
            with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
                os.sched_setscheduler(thread, os.SCHED_FIFO, os.sched_param(1))
    except (PermissionError, AttributeError, OSError):  # not permitted, or not Linux
        log.info(
            "not permitted to run the clock in the real-time class (needs CAP_SYS_NICE or RLIMIT_RTPRIO):"
            " it stays"
        )
        return False
    return True


def _timing(trips: dict[str, list[float]], ticks: list[float], period: float) -> dict[str, float]:
    """Round trip state -> action (of both seats, and of each: an agent's and a person's differ), and
    the tick period's deviation from 1/fps: median and p99, ms."""
    deviations = [abs(b - a - period) * 1e3 for a, b in zip(ticks, ticks[1:], strict=False)]
    timing: dict[str, float] = {}
    every = [trip for role in ROLES for trip in trips[role]]
    seats = [(f"round_trip_{role}", trips[role]) for role in ROLES]
    for name, values in (("round_trip", every), *seats, ("tick_jitter", deviations)):
        if len(values) >= 2:
            timing[f"{name}_ms_p50"] = statistics.median(values)
            timing[f"{name}_ms_p99"] = statistics.quantiles(values, n=100)[98]
    return timing
