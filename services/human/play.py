"""Matches with people in them on one machine: the gateway in this process, the rest as processes."""

from __future__ import annotations

import dataclasses
import secrets
import threading
from collections.abc import Callable
from pathlib import Path

from services.human.core import SeatBook
from services.human.gateway import Gateway, Web, seat_handler
from services.population.seat import PersonSeat
from services.runtime.launch import MatchPlan, run_match
from shared.bus import BusConfig, free_endpoint
from shared.messages import State, Summary


def seat_links(url: str, tokens: dict[str, str]) -> dict[str, str]:
    """The link each person opens: the page, with the seat and its token."""
    return {role: f"{url}?role={role}&token={token}" for role, token in tokens.items()}


def play_with_people(
    plan: MatchPlan,
    host: str = "127.0.0.1",
    port: int = 8000,
    on_links: Callable[[dict[str, str]], None] = lambda links: None,
    on_state: Callable[[State], None] = lambda state: None,
    stop: threading.Event | None = None,
) -> tuple[Summary, Path]:
    """Run `plan`, whose seats with the policy `human` are played from browsers: each such seat gets
    a fresh token, and `on_links` the links to open, before the sim waits for the players. `stop`
    ends the match and its processes (run_match)."""
    people = [role for role, spec in plan.seats.items() if isinstance(spec, PersonSeat)]
    if not people:
        raise ValueError("no seat of this match is played by a person")
    tokens = {role: secrets.token_urlsafe(9) for role in people}
    endpoint = free_endpoint()
    bus = BusConfig(listen=(endpoint,), low_latency=plan.low_latency)
    with Gateway(bus, seat_handler(plan.match, SeatBook(tokens)), Web(host, port)) as gateway:
        on_links(seat_links(gateway.url, tokens))
        return run_match(dataclasses.replace(plan, peers=(endpoint,)), on_state, stop=stop)
