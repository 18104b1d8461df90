"""The agent service: a thin shell that answers each state of a match with its seat's action."""

from __future__ import annotations

import logging
import threading

import zenoh

from services.agent.player import Player
from shared import keys
from shared.bus import BusConfig, Drops, session, stop_on_summary
from shared.messages import MessageError, PolicySwitch, State, decode

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

        def on_state(sample: zenoh.Sample) -> None:
            try:
                state = decode(sample.payload.to_bytes(), State)
            except MessageError as error:
                drops.drop(str(sample.key_expr), error)
                return
            publisher.put(player.act(state, sender).encode())

        def on_switch(sample: zenoh.Sample) -> None:
            try:
                message = decode(sample.payload.to_bytes(), PolicySwitch)
                if message.role != role:
                    raise MessageError("mismatch", f"switch for {message.role} on {role}'s key")
                player.switch(message.policy)
            except MessageError as error:
                drops.drop(str(sample.key_expr), error)
                return
            except ValueError as error:  # a key this seat cannot play
                drops.drop(str(sample.key_expr), MessageError("policy", str(error)))
                return
            log.info("%s switches to %s from the next frame (%s)", sender, message.policy, message.reason)

        subscribers = [
            z.declare_subscriber(keys.state(match), on_state),
            z.declare_subscriber(keys.policy(match, role), on_switch),
            z.declare_subscriber(keys.summary(match), stop_on_summary(stop, drops)),
        ]
        token = z.liveliness().declare_token(keys.alive(match, "agent", role))
        try:
            stop.wait()
        finally:
            token.undeclare()
            for subscriber in subscribers:
                subscriber.undeclare()
    return drops
