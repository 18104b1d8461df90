"""The sim service: a thin shell that runs the engine on the bus. It owns the clock.

Real-time mode ticks at the game's fps on a monotonic schedule (tick k is due at start + k/fps,
so lateness never accumulates) and applies each seat's latest action; lockstep mode waits for
both seats' answers to each state, but never longer than `step_timeout`, and never for a seat
whose player is gone. State is published with congestion control *drop*: a frozen subscriber
can never stall the sim.
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

from services.sim.engine import Game
from services.sim.match import Seats, event_messages, start_message, state_message, summary_message
from shared import keys
from shared.bus import BusConfig, Drops, session, subscribe
from shared.errors import UsageError
from shared.game import ROLES, GameConfig
from shared.messages import Action, Summary, seat_actions

log = logging.getLogger("tsf.sim")
MODES = ("realtime", "lockstep")


def run_sim(bus: BusConfig, match: str, *args: object, **options: object) -> Summary:
    """Play one match on the bus and return its summary: `Sim(...).play()`."""
    return Sim(bus, match, *args, **options).play()


class Sim:
    """One match's sim on the bus. The fields are what the bus's callbacks share with the frame
    loop (under `changed`); `play` runs the match.

    Waits up to `wait_players` seconds for both seats and up to `wait_recorder` for a recorder
    before the first frame (and `wait_adapter` for an adapter, in adaptive matches); a seat still
    empty then plays no-op until its player arrives. At the first frame it raises its priority by
    `priority` nice steps (in every thread; where permitted), above start-ups and bulk work."""

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
        if mode not in MODES:
            raise UsageError("--sim-mode", mode, "unknown", MODES)
        self.bus, self.match, self.mode = bus, match, mode
        self.policies = {role: (policies or {}).get(role, "") for role in ROLES}  # the contract wants both
        self.stop = stop or threading.Event()
        self.wait_players, self.wait_recorder, self.wait_adapter = wait_players, wait_recorder, wait_adapter
        self.step_timeout, self.priority = step_timeout, priority
        self.game = Game(config, seed)
        self.seats, self.drops = Seats(), Drops("sim")
        self.changed = threading.Condition()
        self.answered_at: dict[tuple[str, int], int] = {}  # (role, frame) -> arrival time, for round trips
        self.observers: Counter[str] = Counter()  # live recorder and adapter tokens

    def play(self) -> Summary:
        """Play the match and return its summary (also published on the summary key)."""
        match, seats = self.match, self.seats
        with session(self.bus) as z:
            fast = {"congestion_control": zenoh.CongestionControl.DROP, "express": True}
            state_pub = z.declare_publisher(keys.state(match), priority=zenoh.Priority.REAL_TIME, **fast)
            event_pub = z.declare_publisher(keys.event(match), **fast)
            liveliness = z.liveliness()
            with (
                liveliness.declare_token(keys.alive(match, "sim")),
                subscribe(z, keys.actions(match), seat_actions(match), self._on_action, self.drops),
                liveliness.declare_subscriber(keys.seats_alive(match), self._on_alive, history=True),
                liveliness.declare_subscriber(keys.alive(match, "recorder"), self._on_alive, history=True),
                liveliness.declare_subscriber(keys.alive(match, "adapter"), self._on_alive, history=True),
            ):
                self._wait(lambda: all(seats.present(r) for r in ROLES), self.wait_players)
                self._wait(lambda: self.observers["recorder"] > 0, self.wait_recorder)
                self._wait(lambda: self.observers["adapter"] > 0, self.wait_adapter)
                # At the states' priority: zenoh orders messages only within one priority, so a start
                # put at the default priority could arrive after state 0.
                start_bytes = start_message(self.game, match, "sim", self.mode, self.policies).encode()
                z.put(keys.start(match), start_bytes, priority=zenoh.Priority.REAL_TIME)
                timing = self._frames(state_pub, event_pub)
                summary = summary_message(self.game, match, "sim", self.drops.counts, timing, seats.failures)
                z.put(keys.summary(match), summary.encode())
                time.sleep(0.2)  # let the last puts leave before the session closes
                return summary

    def _frames(self, state_pub: zenoh.Publisher, event_pub: zenoh.Publisher) -> dict[str, float]:
        """Publish every state and play every frame, on the clock or in lockstep; the timing."""
        game, match, seats, changed = self.game, self.match, self.seats, self.changed
        sent: dict[int, int] = {}
        ticks: list[float] = []
        applied = (0, 0)
        period = 1.0 / game.config.fps
        _raise_priority(self.priority)
        start = time.monotonic()
        while True:
            sent[game.frame] = time.perf_counter_ns()
            state_pub.put(state_message(game, match, "sim", applied).encode())
            with changed:
                failed = seats.failure_events(match, "sim")
            for event in [*event_messages(game, match, "sim"), *failed]:
                event_pub.put(event.encode())
            if game.done or self.stop.is_set():
                break
            if self.mode == "lockstep":
                frame = game.frame
                self._wait(lambda frame=frame: seats.answered(frame), self.step_timeout)
            else:
                due = start + (game.frame + 1) * period
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                ticks.append(time.monotonic())
            with changed:
                applied = seats.actions()
            game.step(*applied)
        with changed:
            trips = [(t - sent[f]) / 1e6 for (_, f), t in self.answered_at.items() if f in sent]
        return _timing(trips, ticks, period)

    def _on_action(self, action: Action) -> None:
        arrived = time.perf_counter_ns()
        with self.changed:
            if self.seats.offer(action):
                self.answered_at.setdefault((action.role, action.frame), arrived)
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

    def _wait(self, condition: Callable[[], bool], timeout: float) -> None:
        """Until `condition` holds, `timeout` passes or the match is stopped."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while not condition() and not self.stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                self.changed.wait(min(left, 0.05))


def _raise_priority(steps: int) -> None:
    """Take `steps` nice steps above this thread's priority, in every thread of this process (Linux
    keeps a nice value per thread). False where it is not permitted (it needs CAP_SYS_NICE: root
    can, a container may not): the threads keep their priority, and it says so in one log line."""
    if steps <= 0:
        return
    nice = max(-20, os.getpriority(os.PRIO_PROCESS, 0) - steps)
    try:
        threads = [int(task) for task in os.listdir("/proc/self/task")]
    except OSError:  # no /proc: this thread alone
        threads = [0]
    try:
        for thread in threads:
            with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
                os.setpriority(os.PRIO_PROCESS, thread, nice)
    except PermissionError:
        log.info("not permitted to raise the priority to nice %d (needs CAP_SYS_NICE): it stays", nice)


def _timing(trips: list[float], ticks: list[float], period: float) -> dict[str, float]:
    """Round trip state -> action, and the tick period's deviation from 1/fps: median and p99, ms."""
    deviations = [abs(b - a - period) * 1e3 for a, b in zip(ticks, ticks[1:], strict=False)]
    timing: dict[str, float] = {}
    for name, values in (("round_trip", trips), ("tick_jitter", deviations)):
        if len(values) >= 2:
            timing[f"{name}_ms_p50"] = statistics.median(values)
            timing[f"{name}_ms_p99"] = statistics.quantiles(values, n=100)[98]
    return timing
