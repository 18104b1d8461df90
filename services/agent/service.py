"""The agent service: a thin shell that answers each state of a match with its seat's action."""

from __future__ import annotations

import logging
import threading

import zenoh

from services.agent.player import Player
from shared import keys
from shared.bus import BusConfig, Drops, session, stop_on_summary, subscribe, until_stopped
from shared.messages import MessageError, PolicySwitch, State

log = logging.getLogger("tsf.agent")


def run_agent(
    bus: BusConfig, match: str, role: str, policy: str, seed: int = 0, stop: threading.Event | None = None
) -> Drops:
    """Play `role` until the match's summary arrives or `stop` is set; returns the drop counts."""
    stop = stop or threading.Event()
    player = Player(role, policy, seed)
    drops = Drops(f"agent/{role}")
    sender = f"agent/{role}"

    with session(bus) as z:
        publisher = z.declare_publisher(
            keys.action(match, role), congestion_control=zenoh.CongestionControl.DROP, express=True
        )

        def on_state(state: State) -> None:
            if state.last:
                return
            action = player.act(state, sender)
            if action.failure and action.failures == 1:  # one line a match; the sim counts the rest
                log.error("%s: the policy failed and plays no-op on such frames: %s", sender, action.failure)
            publisher.put(action.encode())

        def on_switch(message: PolicySwitch) -> None:
            if message.role != role:
                raise MessageError("mismatch", f"switch for {message.role} on {role}'s key")
            try:
                player.switch(message.policy)
            except ValueError as error:  # a key this seat cannot play
                raise MessageError("policy", str(error)) from error
            log.info("%s switches to %s from the next frame (%s)", sender, message.policy, message.reason)

        with (
            subscribe(z, keys.state(match), State, on_state, drops),
            subscribe(z, keys.policy(match, role), PolicySwitch, on_switch, drops),
            stop_on_summary(z, match, stop, drops),
            z.liveliness().declare_token(keys.alive(match, "agent", role)),
        ):
            until_stopped(stop)
    return drops
