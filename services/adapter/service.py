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
    adapter, scorer = build(config, table)
    partner_role = config.partner_role
    pairing, drops, lock = Pairing(), Drops(SENDER), threading.Lock()
    agent = {"policy": "", "asked": "", "asked_at": -RESEND_FRAMES}  # what the agent plays; last request
    reported = {"frames": -1, "partner": ""}  # the adapter's frame count and estimate at the last status
    latest = [0]  # the newest frame scored

    with session(bus) as z:
        switch = z.declare_publisher(keys.policy(match, config.role))
        status = z.declare_publisher(keys.adapter(match), congestion_control=zenoh.CongestionControl.DROP)

        def report(frame: int) -> None:
            status.put(AdapterStatus(match=match, frame=frame, sender=SENDER, **adapter.status()).encode())
            reported.update(frames=adapter.frames, partner=adapter.partner)

        def feed(pair: tuple[list[float], int] | None, frame: int) -> None:
            """Score one paired frame, and switch the agent when due (under `lock`)."""
            if pair is not None:
                began = time.perf_counter()
                adapter.update(scorer(*pair), pair[0])
                latest[0] = frame
                if costs is not None:
                    costs.append(time.perf_counter() - began)
            due = adapter.partner and adapter.policy != agent["policy"]
            if due and (adapter.policy != agent["asked"] or frame - agent["asked_at"] >= RESEND_FRAMES):
                reason = f"partner plays like {adapter.partner}" + (
                    " (out of library: best average)" if adapter.out_of_library else ""
                )
                switch.put(
                    PolicySwitch(
                        match=match,
                        frame=frame,
                        sender=SENDER,
                        role=config.role,
                        policy=adapter.policy,
                        reason=reason,
                    ).encode()
                )
                agent.update(asked=adapter.policy, asked_at=frame)
                log.info("frame %d: %s; switching the %s to %s", frame, reason, config.role, adapter.policy)
                report(frame)
            elif adapter.partner != reported["partner"]:  # a new estimate is worth a report at once
                report(frame)

        def on_state(state: State) -> None:
            if state.match != match:
                raise MessageError("mismatch", f"state of {state.match} on {keys.state(match)}")
            with lock:
                feed(pairing.state(state.frame, state.obs[partner_role]), state.frame)

        def on_action(action: Action) -> None:
            with lock:
                if action.role == config.role:
                    agent["policy"] = action.policy
                else:
                    feed(pairing.action(action.frame, action.action), action.frame)

        with (
            subscribe(z, keys.state(match), State, on_state, drops),
            subscribe(z, keys.actions(match), seat_actions(match), on_action, drops),
            stop_on_summary(z, match, stop, drops),
            z.liveliness().declare_token(keys.alive(match, "adapter")),
        ):
            while not stop.wait(1.0 / status_hz):  # a modest report rate, whatever the frame rate
                with lock:
                    if adapter.frames != reported["frames"]:
                        report(latest[0])
    if drops.total:
        log.info("adapter dropped %d bad inputs: %s", drops.total, dict(drops.counts))
    return drops
