"""The agent service: a thin shell that answers each state of a match with its seat's action.

An agent's seats in one match are a `Seats`; `run_agent` plays the seat a command line names,
`run_agent_pool` the seats of every match a pool's orders name (shared.bus.serve_orders), with the
same class.
"""

from __future__ import annotations

import copy
import functools
import logging
import threading
from contextlib import ExitStack

import zenoh

from services.agent import library
from services.agent.gate import RULING_WAIT, Gate
from services.agent.networks import load
from services.agent.outside import BY_KEY, policy_kind
from services.agent.player import Player, PolicyLoader
from services.agent.seats import check_seat, policy_for
from shared import keys
from shared.bus import BusConfig, Drops, on_match_end, serve_orders, session, subscribe, until_stopped
from shared.game import ROLES, Policy
from shared.messages import MatchOrder, MessageError, PolicySwitch, Ruling, Start, State

log = logging.getLogger("tsf.agent")


class Seats:
    """The seats an agent service plays in one live match (one player a seat): answers each state
    but the last with every player's action (the state decoded once for all), plays the policy a
    switch names from the next state, and holds each seat's token. A seat in `adaptive` plays as
    the adapter rules too: in a lockstep match (its Start says so) it answers the state after a
    scoring frame only once it has the ruling on that frame (gate.py; RULING_WAIT at most), and
    plays the policy it names from there. `ended` is set when the match is over (its summary, or
    its sim gone); `close` undeclares everything, and no answer is put after it (a state's
    callback may still be running)."""

    def __init__(
        self,
        z: zenoh.Session,
        match: str,
        players: list[Player],
        drops: Drops,
        ended: threading.Event | None = None,
        adaptive: str = "",
    ) -> None:
        self.match = match
        self.ended = ended or threading.Event()
        self.lock, self.open = threading.Lock(), True
        self.gates = {p.role: (Gate(), threading.Lock()) for p in players if p.role == adaptive}
        with ExitStack() as declared:
            self.players = [
                (
                    player,
                    f"agent/{player.role}",
                    declared.enter_context(
                        z.declare_publisher(
                            keys.action(match, player.role),
                            congestion_control=zenoh.CongestionControl.DROP,
                            express=True,
                        )
                    ),
                )
                for player in players
            ]
            declared.enter_context(subscribe(z, keys.start(match), Start, self.on_start, drops))
            declared.enter_context(subscribe(z, keys.state(match), State, self.on_state, drops))
            for seat in self.players:
                player = seat[0]
                switch = functools.partial(self.on_switch, player)
                declared.enter_context(
                    subscribe(z, keys.policy(match, player.role), PolicySwitch, switch, drops)
                )
                if player.role in self.gates:
                    ruling = functools.partial(self.on_ruling, seat)
                    declared.enter_context(
                        subscribe(z, keys.ruling(match, player.role), Ruling, ruling, drops)
                    )
            declared.enter_context(on_match_end(z, match, self.ended, drops))
            for player in players:
                declared.enter_context(z.liveliness().declare_token(keys.alive(match, "agent", player.role)))
            self.declared = declared.pop_all()

    def on_start(self, start: Start) -> None:
        """A lockstep match arms the adaptive seat's gate (declared before the seat's token, so
        the sim, which waits for the token, puts its Start after)."""
        for gate, lock in self.gates.values():
            with lock:
                gate.armed = start.mode == "lockstep"

    def on_state(self, state: State) -> None:
        if state.last:
            return
        for seat in self.players:
            if seat[0].role not in self.gates:
                self.answer(seat, state)
                continue
            gate, lock = self.gates[seat[0].role]
            with lock:
                if gate.offer(state):
                    self.answer(seat, state)
                    continue
            threading.Timer(RULING_WAIT, self.expire, (seat, state)).start()

    def on_ruling(self, seat: tuple[Player, str, zenoh.Publisher], ruling: Ruling) -> None:
        """The adapter's ruling: its policy from the next frame, and the held answer it frees."""
        player = seat[0]
        if ruling.role != player.role:
            raise MessageError("mismatch", f"ruling for {ruling.role} on {player.role}'s key")
        gate, lock = self.gates[player.role]
        with lock:
            if not gate.armed:
                return  # in real time the switch message alone switches: nothing waits
            if ruling.policy:
                self.switch(player, ruling.policy, f"ruling on frame {ruling.frame}")
            if (held := gate.rule(ruling.frame)) is not None:
                self.answer(seat, held)

    def expire(self, seat: tuple[Player, str, zenoh.Publisher], state: State) -> None:
        """The wait for a held state's ruling ran out: answer it as the seat plays now."""
        gate, lock = self.gates[seat[0].role]
        with lock:
            if (held := gate.expire(state)) is not None:
                log.warning(
                    "%s: no ruling on frame %d in %.1f s; not waiting for the adapter until its next one",
                    seat[1], state.frame - 1, RULING_WAIT,
                )  # fmt: skip
                self.answer(seat, held)

    def answer(self, seat: tuple[Player, str, zenoh.Publisher], state: State) -> None:
        player, sender, publisher = seat
        action = player.act(state, sender)
        if action.failure and action.failures == 1:  # one line a match; the sim counts the rest
            log.error("%s: the policy failed and plays no-op on such frames: %s", sender, action.failure)
        data = action.encode()
        with self.lock:
            if self.open:
                publisher.put(data)

    def on_switch(self, player: Player, message: PolicySwitch) -> None:
        if message.role != player.role:
            raise MessageError("mismatch", f"switch for {message.role} on {player.role}'s key")
        self.switch(player, message.policy, message.reason)

    def switch(self, player: Player, policy: str, reason: str) -> None:
        if policy == player.next_key:
            return
        try:
            player.switch(policy)
        except ValueError as error:  # a key this seat cannot play
            raise MessageError("policy", str(error)) from error
        log.info("agent/%s switches to %s from the next frame (%s)", player.role, policy, reason)

    def close(self) -> None:
        with self.lock:
            self.open = False
        self.declared.close()


def run_agent(
    bus: BusConfig,
    match: str,
    role: str,
    policy: str,
    seed: int = 0,
    stop: threading.Event | None = None,
    adaptive: bool = False,
) -> Drops:
    """Play `role` until the match is over (its summary, or its sim gone) or `stop` is set, as the
    adapter rules where the seat is `adaptive` (Seats); returns the drop counts."""
    stop = stop or threading.Event()
    drops = Drops(f"agent/{role}")
    player = Player(role, policy, seed)
    with session(bus) as z:
        seats = Seats(z, match, [player], drops, stop, role if adaptive else "")
        try:
            until_stopped(stop)
        finally:
            seats.close()
    return drops


class Library:
    """A policy loader (Player's `load`) that reads each library policy's weights once a process:
    every seat plays a shallow copy. Only the network is shared, which playing never changes; what
    a policy changes as it plays (its random stream, a proxy's last actions) is set anew by the
    reset the Player gives every policy before it plays. Other keys load as policy_for does (a
    scripted rule costs nothing to make; a policy from outside may hold anything)."""

    def __init__(self) -> None:
        self.loaded: dict[str, Policy] = {}
        self.lock = threading.Lock()

    def __call__(self, key: str, role: str) -> Policy:
        if policy_kind(key) != BY_KEY or key not in library.registry():
            return policy_for(key, role)
        check_seat(key, role)
        with self.lock:
            if key not in self.loaded:
                self.loaded[key] = load(key)
            return copy.copy(self.loaded[key])


def players_of(order: MatchOrder, load: PolicyLoader) -> list[Player]:
    """A player for each seat of the order an agent plays ("" names a person's seat); an order
    naming a policy that cannot play its seat is a MessageError."""
    try:
        return [Player(role, key, order.seed, load) for role in ROLES if (key := order.policy(role))]
    except Exception as error:  # noqa: BLE001 - a policy from outside may raise anything as it loads
        raise MessageError("policy", f"{order.match}: {type(error).__name__}: {error}") from error


def run_agent_pool(bus: BusConfig, pool: str, stop: threading.Event | None = None) -> Drops:
    """Play every agent seat of the matches `pool`'s orders name until `stop` is set; returns the
    drop counts (bad orders and bad input of every match)."""
    stop = stop or threading.Event()
    drops, load = Drops("agent"), Library()
    with session(bus) as z:

        def start(order: MatchOrder) -> list[Seats]:
            players = players_of(order, load)
            if not players:
                return []
            log.info("match %s: playing %s", order.match, {p.role: p.key for p in players})
            return [Seats(z, order.match, players, drops, adaptive=order.adaptive)]

        serve_orders(z, pool, "agent", start, drops, stop)
    return drops
