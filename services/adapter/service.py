"""The adapter service: a thin shell that feeds the adapter core from a live match and, when the
core's choice differs from what our agent plays, tells the agent to switch.

It scores the partner's paired frames in batches of SCORE_FRAMES frames of the match, never by the
clock, and rules on the last frame of each batch (a `Ruling`, switch or not): the agent plays the
ruling from the next frame, and in a lockstep match waits for it (services/agent/gate.py), so a
switch plays from the frame the in-process evaluation gives, on every run. In real time nothing
waits for it: the sim owns the clock.

It reads what the agent plays from the agent's own actions, so an adapter that (re)starts mid-match
never switches the agent back to the initial policy: it rebuilds its window from live frames and
switches only once it has an estimate. If it dies, the agent keeps its current policy.
"""

from __future__ import annotations

import logging
import threading
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import zenoh

from services.adapter import core
from services.adapter.core import Adapter, Pairing, Payoff, Scorer, threshold
from services.population.adaptive import AdapterConfig
from services.population.seat import SeatSpec
from services.table.table import DEFAULT_TABLE
from shared import keys
from shared.bus import BusConfig, Drops, on_match_end, serve_orders, session, subscribe, woken
from shared.game import FRAMES, SCORE_FRAMES, other
from shared.messages import (
    Action,
    AdapterStatus,
    MatchOrder,
    MessageError,
    PolicySwitch,
    Ruling,
    State,
    seat_actions,
)

log = logging.getLogger("tsf.adapter")
SENDER = "adapter"
RESEND_FRAMES = 30  # ask again if the agent still plays another policy this many frames later
IDLE = 0.2  # seconds the scoring loop waits at most for a due batch (then it looks whether to stop)


def seat_of(role: str, table: Path = DEFAULT_TABLE, partners: str = "library") -> tuple[Payoff, Scorer]:
    """The costly, read-only parts of an adaptive seat: what it chooses by, seen from `role`'s seat
    (the table P, or the grown library's partner groups), and the partner types' policies (scoring
    only reads them, so a pool's matches share them)."""
    payoff = core.payoff_of(role, partners, table)
    return payoff, core.scorer_of(payoff, other(role))


def build(config: AdapterConfig, table: Path = DEFAULT_TABLE) -> tuple[Adapter, Scorer]:
    """The core for one adaptive seat of one match (its own Adapter: the window and estimates)."""
    payoff, scorer = seat_of(config.role, table, config.partners)
    return core.build(config, payoff), scorer


class AdapterShell:
    """One adaptive seat's shell in a live match: the fields are what the callbacks share, the
    methods the callbacks (on_state, on_action from the bus; `rule` and `report_if_new` from the
    scoring loop). It declares its subscriptions, publishers and the adapter's token when made;
    `ended` is set when the match is over (its summary, or its sim gone), `wake` once the batch of a
    scoring frame is paired (the loop then scores it: frames of the match pace it, never the
    clock); `close` undeclares everything, and nothing is put after it."""

    def __init__(
        self,
        z: zenoh.Session,
        match: str,
        config: AdapterConfig,
        seat: tuple[Payoff, Scorer],
        drops: Drops,
        costs: list[float] | None = None,
        ended: threading.Event | None = None,
        wake: threading.Event | None = None,
    ) -> None:
        self.match, self.config, self.costs = match, config, costs
        payoff, self.scorer = seat
        self.adapter = core.build(config, payoff)
        self.pairing, self.lock, self.open = Pairing(), threading.Lock(), True
        self.ended, self.wake = ended or threading.Event(), wake or threading.Event()
        self.playing = ""  # what the agent plays, from its own actions
        self.asked, self.asked_at = "", -RESEND_FRAMES  # the last switch requested, and when
        self.reported_frames = -1  # the core's frames at the last status
        self.reported_partner = ""  # and its estimate
        self.latest = 0  # the newest frame scored
        self.due = self.ruled = -1  # the last scoring frame paired, and the last one ruled on
        self.decided = -1  # the frame on which the core made its present choice
        self.frames = FRAMES.high  # the game's length, from its states
        self.paired: list[tuple[tuple[list[float], int], int]] = []  # (values, action), frame: not scored yet
        with ExitStack() as declared:
            self.switch = declared.enter_context(z.declare_publisher(keys.policy(match, config.role)))
            self.rulings = declared.enter_context(
                z.declare_publisher(keys.ruling(match, config.role), express=True)
            )
            self.status = declared.enter_context(
                z.declare_publisher(keys.adapter(match), congestion_control=zenoh.CongestionControl.DROP)
            )
            declared.enter_context(subscribe(z, keys.state(match), State, self.on_state, drops))
            declared.enter_context(
                subscribe(z, keys.actions(match), seat_actions(match), self.on_action, drops)
            )
            declared.enter_context(on_match_end(z, match, self.ended, drops))
            declared.enter_context(z.liveliness().declare_token(keys.alive(match, "adapter")))
            self.declared = declared.pop_all()

    def close(self) -> None:
        """End the match's part: the frames paired since the last batch scored and a last status
        sent if they changed it (a match may end between two scoring frames), then undeclare all."""
        score_paired([self], last=True)
        self.report_if_new()
        with self.lock:
            self.open = False
        self.declared.close()

    def report(self, frame: int) -> None:
        adapter = self.adapter
        self.status.put(
            AdapterStatus(match=self.match, frame=frame, sender=SENDER, **adapter.status()).encode()
        )
        self.reported_frames, self.reported_partner = adapter.frames, adapter.partner

    def report_if_new(self) -> None:
        """A status when the core has seen frames since the last one."""
        with self.lock:
            if self.open and self.adapter.frames != self.reported_frames:
                self.report(self.latest)

    def feed(self, pair: tuple[list[float], int] | None, frame: int) -> None:
        """Keep a paired frame for its batch; once a scoring frame's batch is paired (or a later
        frame is, where a message was lost), wake the loop to score it (under `lock`)."""
        if pair is None:
            return
        self.paired.append((pair, frame))
        last = frame - (frame + 1) % SCORE_FRAMES  # the last scoring frame up to this one
        if last > self.due:
            self.due = last
            self.wake.set()

    def scored(self, scores: np.ndarray, pair: tuple[list[float], int], frame: int) -> None:
        """Update the core with one paired frame (the partner's values and action) and its scores
        (under `lock`)."""
        if self.adapter.update(scores, *pair):
            self.decided = frame
        self.latest = frame

    def rule(self, frame: int) -> None:
        """The ruling on scoring frame `frame`, every frame up to it scored: what the agent plays
        from the next frame (the core's choice once it has an estimate; before, "": it goes on
        with what it plays, so a restarted adapter never switches it back to the initial policy),
        a switch where that is not what it plays, and a status if the core changed (under `lock`).
        No ruling is put on the game's last answered frame: its next state is the last, which no
        seat answers, and a ruling then would reach the recording or not by timing."""
        adapter, self.ruled = self.adapter, frame
        if frame < self.frames - 1:
            self.put_ruling(frame)
        if adapter.frames != self.reported_frames or adapter.partner != self.reported_partner:
            self.report(frame)

    def put_ruling(self, frame: int) -> None:
        """The ruling on `frame`, and the switch it may need (under `lock`)."""
        adapter = self.adapter
        ruling = Ruling(
            match=self.match,
            frame=frame,
            sender=SENDER,
            role=self.config.role,
            policy=adapter.policy if adapter.partner else "",
            partner=adapter.partner,
        )
        self.rulings.put(ruling.encode())
        self.decide(frame)

    def decide(self, frame: int) -> None:
        """Switch the agent when the core's choice differs from what it plays (again after
        RESEND_FRAMES if it has not followed)."""
        adapter = self.adapter
        due = adapter.partner and adapter.policy != self.playing
        if due and (adapter.policy != self.asked or frame - self.asked_at >= RESEND_FRAMES):
            reason = f"partner plays like {adapter.partner}" + (
                " (out of library: best average)" if adapter.out_of_library else ""
            )
            switch = PolicySwitch(
                match=self.match,
                frame=frame,
                sender=SENDER,
                role=self.config.role,
                policy=adapter.policy,
                reason=reason,
            )
            self.switch.put(switch.encode())
            self.asked, self.asked_at = adapter.policy, frame
            log.info(
                "frame %d: %s (decided on frame %d); the %s plays %s from frame %d",
                frame, reason, self.decided, self.config.role, adapter.policy, frame + 1,
            )  # fmt: skip

    def on_state(self, state: State) -> None:
        if state.match != self.match:
            raise MessageError("mismatch", f"state of {state.match} on {keys.state(self.match)}")
        with self.lock:
            if self.open:
                self.frames = state.frames
                self.feed(self.pairing.state(state.frame, state.obs[self.config.partner_role]), state.frame)

    def on_action(self, action: Action) -> None:
        with self.lock:
            if not self.open:
                return
            if action.role == self.config.role:
                self.playing = action.policy
            else:
                self.feed(self.pairing.action(action.frame, action.action), action.frame)


Row = tuple[AdapterShell, tuple[list[float], int], int]  # a shell, a paired frame and its number


def due_rows(shell: AdapterShell, last: bool) -> tuple[list[Row], int | None]:
    """The shell's paired frames up to its due scoring frame (all of them, `last`), in frame
    order, and the scoring frame to rule on after them (None: none is due)."""
    with shell.lock:
        until = max((f for _, f in shell.paired), default=-1) if last else shell.due
        rows = sorted((r for r in shell.paired if r[1] <= until), key=lambda r: r[1])
        shell.paired = [r for r in shell.paired if r[1] > until]
        ruling = shell.due if shell.due > shell.ruled and not last else None
    return [(shell, pair, frame) for pair, frame in rows], ruling


def score_paired(shells: list[AdapterShell], last: bool = False) -> None:
    """Score every frame the shells have paired up to their due scoring frames (all, `last`: the
    match is over), in one batch per scorer (a pool's matches of one seat share it: the
    networks' passes cost per call far more than per row), update each shell's core in its
    frames' order and then rule on each due scoring frame. A shell's `costs` receives each
    frame's share of the batch and its own update."""
    batches: dict[int, list[Row]] = {}
    rulings: list[tuple[AdapterShell, int]] = []
    for shell in shells:
        rows, ruling = due_rows(shell, last)
        if rows:
            batches.setdefault(id(shell.scorer), []).extend(rows)
        if ruling is not None:
            rulings.append((shell, ruling))
    for rows in batches.values():
        began = time.perf_counter()
        scores = rows[0][0].scorer.batch([pair[0] for _, pair, _ in rows], [pair[1] for _, pair, _ in rows])
        share = (time.perf_counter() - began) / len(rows)
        for (shell, pair, frame), row in zip(rows, scores, strict=True):
            began = time.perf_counter()
            with shell.lock:
                if shell.open:
                    shell.scored(row, pair, frame)
            if shell.costs is not None:
                shell.costs.append(share + time.perf_counter() - began)
    for shell, frame in rulings:
        with shell.lock:
            if shell.open:
                shell.rule(frame)


def run_adapter(
    bus: BusConfig,
    match: str,
    config: AdapterConfig,
    stop: threading.Event | None = None,
    table: Path = DEFAULT_TABLE,
    costs: list[float] | None = None,
) -> Drops:
    """Adapt the agent of `config.role` until the match is over (its summary, or its sim gone) or
    `stop` is set. `costs`, if given, receives the seconds each scored frame took (scoring and
    update)."""
    stop, wake = stop or threading.Event(), threading.Event()
    drops = Drops(SENDER)
    with session(bus) as z:
        seat = seat_of(config.role, table, config.partners)
        shell = AdapterShell(z, match, config, seat, drops, costs, stop, wake)
        try:
            while not woken(stop, wake, IDLE):
                score_paired([shell])
        finally:
            shell.close()
    if drops.total:
        log.info("adapter dropped %d bad inputs: %s", drops.total, dict(drops.counts))
    return drops


def config_of(order: MatchOrder) -> AdapterConfig | None:
    """The adaptive agent of an order, in its seat and seed; None for an order without one. An
    order whose `adapter` names no adaptive agent is a MessageError."""
    if not order.adapter:
        return None
    try:
        config = SeatSpec.parse(order.adapter, "adapter").adaptive(order.adaptive, order.seed)
        if config is None:
            raise ValueError(f"{order.adapter} is not an adaptive agent")
        threshold(config)  # the out-of-library thresholds, checked before anything is declared
    except ValueError as error:
        raise MessageError("adapter", f"{order.match}: {error}") from error
    return config


def run_adapter_pool(
    bus: BusConfig, pool: str, stop: threading.Event | None = None, table: Path = DEFAULT_TABLE
) -> Drops:
    """Adapt the agent of every adaptive match `pool`'s orders name until `stop` is set, with one
    scoring loop for all (woken by any match's due batch); returns the drop counts (bad orders and
    bad input of every match)."""
    stop, wake = stop or threading.Event(), threading.Event()
    drops = Drops(SENDER)
    seats: dict[tuple[str, str], tuple[Payoff, Scorer]] = {}  # each seat's, built at its first match
    with session(bus) as z:

        def start(order: MatchOrder) -> list[AdapterShell]:
            config = config_of(order)
            if config is None:
                return []
            seat = (config.role, config.partners)
            if seat not in seats:
                seats[seat] = seat_of(config.role, table, config.partners)
            log.info("match %s: adapting the %s as %s", order.match, config.role, config.name)
            return [AdapterShell(z, order.match, config, seats[seat], drops, wake=wake)]

        serve_orders(z, pool, SENDER, start, drops, stop, IDLE, score_paired, wake)
    if drops.total:
        log.info("adapter dropped %d bad inputs: %s", drops.total, dict(drops.counts))
    return drops
