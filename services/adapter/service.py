"""The adapter service: a thin shell that feeds the adapter core from a live match and, when the
core's choice differs from what our agent plays, tells the agent to switch.

It reads what the agent plays from the agent's own actions, so an adapter that (re)starts mid-match
never switches the agent back to the initial policy: it rebuilds its window from live frames and
switches only once it has an estimate. If it dies, the agent keeps its current policy.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable
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
from shared.bus import BusConfig, Drops, on_match_end, serve_orders, session, subscribe
from shared.game import other
from shared.messages import Action, AdapterStatus, MatchOrder, MessageError, PolicySwitch, State, seat_actions

log = logging.getLogger("tsf.adapter")
SENDER = "adapter"
RESEND_FRAMES = 30  # ask again if the agent still plays another policy this many frames later
SCORE_HZ = 5  # how often the paired frames are scored, in one batch (docs/adapter.md, "Benchmark")


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
    methods the callbacks (on_state, on_action from the bus; report_if_new from the status loop).
    It declares its subscriptions, publishers and the adapter's token when made; `ended` is set
    when the match is over (its summary, or its sim gone); `close` undeclares everything, and
    nothing is put after it."""

    def __init__(
        self,
        z: zenoh.Session,
        match: str,
        config: AdapterConfig,
        seat: tuple[Payoff, Scorer],
        drops: Drops,
        costs: list[float] | None = None,
        ended: threading.Event | None = None,
    ) -> None:
        self.match, self.config, self.costs = match, config, costs
        payoff, self.scorer = seat
        self.adapter = core.build(config, payoff)
        self.pairing, self.lock, self.open = Pairing(), threading.Lock(), True
        self.ended = ended or threading.Event()
        self.playing = ""  # what the agent plays, from its own actions
        self.asked, self.asked_at = "", -RESEND_FRAMES  # the last switch requested, and when
        self.reported_frames = -1  # the core's frames at the last status
        self.reported_partner = ""  # and its estimate
        self.latest = 0  # the newest frame scored
        self.paired: list[tuple[tuple[list[float], int], int]] = []  # (values, action), frame: not scored yet
        with ExitStack() as declared:
            self.switch = declared.enter_context(z.declare_publisher(keys.policy(match, config.role)))
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
        sent if they changed it (a short match may end between two reports), then undeclare all."""
        score_paired([self])
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
        """A status when the core has seen frames since the last one (the status loop's tick)."""
        with self.lock:
            if self.open and self.adapter.frames != self.reported_frames:
                self.report(self.latest)

    def feed(self, pair: tuple[list[float], int] | None, frame: int) -> None:
        """Keep a paired frame for the next batch (score_paired), and switch the agent when due
        (under `lock`)."""
        if pair is not None:
            self.paired.append((pair, frame))
        self.decide(frame)

    def scored(self, scores: np.ndarray, pair: tuple[list[float], int], frame: int) -> None:
        """Update the core with one paired frame (the partner's values and action) and its scores,
        and switch the agent when due (under `lock`)."""
        self.adapter.update(scores, *pair)
        self.latest = frame
        self.decide(frame)

    def decide(self, frame: int) -> None:
        """Switch the agent when the core's choice differs from what it plays (again after
        RESEND_FRAMES if it has not followed); report a new estimate at once."""
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
            log.info("frame %d: %s; switching the %s to %s", frame, reason, self.config.role, adapter.policy)
            self.report(frame)
        elif adapter.partner != self.reported_partner:  # a new estimate is worth a report at once
            self.report(frame)

    def on_state(self, state: State) -> None:
        if state.match != self.match:
            raise MessageError("mismatch", f"state of {state.match} on {keys.state(self.match)}")
        with self.lock:
            if self.open:
                self.feed(self.pairing.state(state.frame, state.obs[self.config.partner_role]), state.frame)

    def on_action(self, action: Action) -> None:
        with self.lock:
            if not self.open:
                return
            if action.role == self.config.role:
                self.playing = action.policy
            else:
                self.feed(self.pairing.action(action.frame, action.action), action.frame)


def score_paired(shells: list[AdapterShell]) -> None:
    """Score every frame the shells have paired since the last call, in one batch per scorer (a
    pool's matches of one seat share it: the networks' passes cost per call far more than per
    row), and update each shell's core in its frames' order. A shell's `costs` receives each
    frame's share of the batch and its own update."""
    batches: dict[int, list[tuple[AdapterShell, tuple[list[float], int], int]]] = {}
    for shell in shells:
        with shell.lock:
            rows, shell.paired = shell.paired, []
        if rows:
            batches.setdefault(id(shell.scorer), []).extend((shell, pair, frame) for pair, frame in rows)
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


def adapting(status_hz: float) -> Callable[[list[AdapterShell]], None]:
    """The adapter's one loop, called SCORE_HZ times a second: score what was paired since (a
    switch is then at most 1 / SCORE_HZ s later than with a score per frame; a batch of six frames
    costs about what one does), and at `status_hz` report each core that saw frames since its last
    status."""
    calls, every = itertools.count(), max(1, round(SCORE_HZ / status_hz))

    def tick(shells: list[AdapterShell]) -> None:
        score_paired(shells)
        if next(calls) % every == 0:
            for shell in shells:
                shell.report_if_new()

    return tick


def run_adapter(
    bus: BusConfig,
    match: str,
    config: AdapterConfig,
    stop: threading.Event | None = None,
    status_hz: float = 5.0,
    table: Path = DEFAULT_TABLE,
    costs: list[float] | None = None,
) -> Drops:
    """Adapt the agent of `config.role` until the match is over (its summary, or its sim gone) or
    `stop` is set. `costs`, if given, receives the seconds each scored frame took (scoring and
    update)."""
    stop = stop or threading.Event()
    drops = Drops(SENDER)
    tick = adapting(status_hz)
    with session(bus) as z:
        shell = AdapterShell(
            z, match, config, seat_of(config.role, table, config.partners), drops, costs, stop
        )
        try:
            while not stop.wait(1.0 / SCORE_HZ):
                tick([shell])
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
    bus: BusConfig,
    pool: str,
    stop: threading.Event | None = None,
    status_hz: float = 5.0,
    table: Path = DEFAULT_TABLE,
) -> Drops:
    """Adapt the agent of every adaptive match `pool`'s orders name until `stop` is set, with one
    status loop for all; returns the drop counts (bad orders and bad input of every match)."""
    stop = stop or threading.Event()
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
            return [AdapterShell(z, order.match, config, seats[seat], drops)]

        serve_orders(z, pool, SENDER, start, drops, stop, 1.0 / SCORE_HZ, adapting(status_hz))
    if drops.total:
        log.info("adapter dropped %d bad inputs: %s", drops.total, dict(drops.counts))
    return drops
