"""The adapter service: a thin shell that feeds the adapter core from a live match and, when the
core's choice differs from what our agent plays, tells the agent to switch.

It reads what the agent plays from the agent's own actions, so an adapter that (re)starts mid-match
never switches the agent back to the initial policy: it rebuilds its window from live frames and
switches only once it has an estimate. If it dies, the agent keeps its current policy.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import zenoh

from services.adapter.core import Adapter, AdapterConfig, Pairing, Payoff, Scorer
from services.agent import networks
from services.table.table import DEFAULT_TABLE
from shared import keys
from shared.bus import BusConfig, Drops, session, stop_on_summary, subscribe
from shared.messages import Action, AdapterStatus, MessageError, PolicySwitch, State, seat_actions

log = logging.getLogger("tsf.adapter")
SENDER = "adapter"
RESEND_FRAMES = 30  # ask again if the agent still plays another policy this many frames later


def build(config: AdapterConfig, table: Path = DEFAULT_TABLE) -> tuple[Adapter, Scorer]:
    """The core for one adaptive seat: the table's view from that seat and the partner's library."""
    payoff = Payoff.load(config.role, table)
    return config.build(payoff), Scorer([networks.load(k) for k in payoff.partners])


class AdapterShell:
    """One adaptive seat's shell in a live match: the fields are what the callbacks share, the
    methods the callbacks (on_state, on_action from the bus; report from the status loop)."""

    def __init__(
        self, z: zenoh.Session, match: str, config: AdapterConfig, table: Path, costs: list[float] | None
    ) -> None:
        self.match, self.config, self.costs = match, config, costs
        self.adapter, self.scorer = build(config, table)
        self.pairing, self.lock = Pairing(), threading.Lock()
        self.switch = z.declare_publisher(keys.policy(match, config.role))
        self.status = z.declare_publisher(
            keys.adapter(match), congestion_control=zenoh.CongestionControl.DROP
        )
        self.playing = ""  # what the agent plays, from its own actions
        self.asked, self.asked_at = "", -RESEND_FRAMES  # the last switch requested, and when
        self.reported_frames, self.reported_partner = (
            -1,
            "",
        )  # the core's frames and estimate at the last status
        self.latest = 0  # the newest frame scored

    def report(self, frame: int) -> None:
        adapter = self.adapter
        self.status.put(
            AdapterStatus(match=self.match, frame=frame, sender=SENDER, **adapter.status()).encode()
        )
        self.reported_frames, self.reported_partner = adapter.frames, adapter.partner

    def report_if_new(self) -> None:
        """A status when the core has seen frames since the last one (the status loop's tick)."""
        with self.lock:
            if self.adapter.frames != self.reported_frames:
                self.report(self.latest)

    def feed(self, pair: tuple[list[float], int] | None, frame: int) -> None:
        """Score one paired frame, and switch the agent when due (under `lock`)."""
        adapter = self.adapter
        if pair is not None:
            began = time.perf_counter()
            adapter.update(self.scorer(*pair), *pair)
            self.latest = frame
            if self.costs is not None:
                self.costs.append(time.perf_counter() - began)
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
            self.feed(self.pairing.state(state.frame, state.obs[self.config.partner_role]), state.frame)

    def on_action(self, action: Action) -> None:
        with self.lock:
            if action.role == self.config.role:
                self.playing = action.policy
            else:
                self.feed(self.pairing.action(action.frame, action.action), action.frame)


def run_adapter(
    bus: BusConfig,
    match: str,
    config: AdapterConfig,
    stop: threading.Event | None = None,
    status_hz: float = 5.0,
    table: Path = DEFAULT_TABLE,
    costs: list[float] | None = None,
) -> Drops:
    """Adapt the agent of `config.role` until the match's summary arrives or `stop` is set.
    `costs`, if given, receives the seconds each scored frame took (scoring and update)."""
    stop = stop or threading.Event()
    drops = Drops(SENDER)
    with session(bus) as z:
        shell = AdapterShell(z, match, config, table, costs)
        with (
            subscribe(z, keys.state(match), State, shell.on_state, drops),
            subscribe(z, keys.actions(match), seat_actions(match), shell.on_action, drops),
            stop_on_summary(z, match, stop, drops),
            z.liveliness().declare_token(keys.alive(match, "adapter")),
        ):
            while not stop.wait(1.0 / status_hz):  # a modest report rate, whatever the frame rate
                shell.report_if_new()
    if drops.total:
        log.info("adapter dropped %d bad inputs: %s", drops.total, dict(drops.counts))
    return drops
