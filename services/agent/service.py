"""The agent service: a thin shell that answers each state of a match with its seat's action.

An agent's seats in one match are a `Seats`; `run_agent` plays the seat a command line names,
`run_agent_pool` the seats of every match a pool's orders name (shared.bus.serve_orders), with the
same class. A pool's agent takes its matches' frames from the pool's Tick, one message a pass of
the sim's clock (shared.messages.Tick), and answers every seat of every match in it with one
evaluation per policy (`Tick`, player.play_together).
"""

from __future__ import annotations

import contextlib
import copy
import functools
import logging
import threading
from contextlib import ExitStack

import numpy as np
import zenoh

from services.agent import library
from services.agent.gate import RULING_WAIT, Gate
from services.agent.networks import load
from services.agent.outside import BY_KEY, policy_kind
from services.agent.player import Frame, Player, PolicyLoader, play_together
from services.agent.policy import FEW_ROWS
from services.agent.scripted import scripted_keys
from services.agent.seats import check_seat, policy_for
from services.sim import observation as ob
from services.sim.observation import as_observations
from shared import keys
from shared.bus import BusConfig, Drops, on_match_end, serve_orders, session, subscribe, until_stopped
from shared.game import OBS_SIZE, ROLES, Policy
from shared.messages import Action, MatchOrder, MessageError, PolicySwitch, Ruling, Start, State, Tick

log = logging.getLogger("tsf.agent")
Seat = tuple[Player, str, zenoh.Publisher]  # a seat's player, its sender name and its action's publisher


class Seats:
    """The seats an agent service plays in one live match (one player a seat): answers each state
    but the last with every player's action (the state decoded once for all), plays the policy a
    switch names from the next state, and holds each seat's token. A seat in `adaptive` plays as
    the adapter rules too: in a lockstep match (its Start says so) it answers the state after a
    scoring frame only once it has the ruling on that frame (gate.py; RULING_WAIT at most), and
    plays the policy it names from there. `ended` is set when the match is over (its summary, or
    its sim gone); `close` undeclares everything, and no answer is put after it (a state's
    callback may still be running). In a pool (`ticks`), its frames come from the pool's Tick, and
    it is added to the pool's answers before its tokens are declared."""

    def __init__(
        self,
        z: zenoh.Session,
        match: str,
        players: list[Player],
        drops: Drops,
        ended: threading.Event | None = None,
        adaptive: str = "",
        ticks: TickAnswers | None = None,
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
            if ticks is None:  # else the pool's Tick brings its frames
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
            if ticks is not None:  # before the tokens: the sim's first frame may come right after them
                ticks.add(self)
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
        if not state.last:
            for seat in self.due(state):
                self.answer(seat, state)

    def due(self, state: State | Frame) -> list[Seat]:
        """The seats that answer `state` now; an adaptive seat's gate may hold its answer for the
        adapter's ruling (a timer answers it, at the latest, after RULING_WAIT)."""
        due = []
        for seat in self.players:
            if seat[0].role not in self.gates:
                due.append(seat)
                continue
            gate, lock = self.gates[seat[0].role]
            with lock:
                if gate.offer(state):
                    due.append(seat)
                    continue
            threading.Timer(RULING_WAIT, self.expire, (seat, state)).start()
        return due

    def on_ruling(self, seat: Seat, ruling: Ruling) -> None:
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

    def expire(self, seat: Seat, state: State) -> None:
        """The wait for a held state's ruling ran out: answer it as the seat plays now."""
        gate, lock = self.gates[seat[0].role]
        with lock:
            if (held := gate.expire(state)) is not None:
                log.warning(
                    "%s: no ruling on frame %d in %.1f s; not waiting for the adapter until its next one",
                    seat[1], state.frame - 1, RULING_WAIT,
                )  # fmt: skip
                self.answer(seat, held)

    def answer(self, seat: Seat, state: State | Frame) -> None:
        self.put(seat, seat[0].act(state, seat[1]))

    def put(self, seat: Seat, action: Action) -> None:
        publisher = seat[2]
        if action.failure and action.failures == 1:  # one line a match; the sim counts the rest
            log.error("%s: the policy failed and plays no-op on such frames: %s", seat[1], action.failure)
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
    """Play every agent seat of the matches `pool`'s orders name until `stop` is set, their frames
    from the pool's Tick (TickAnswers); returns the drop counts (bad orders and bad input of every
    match). Every library policy is loaded and played once first (numba's compiled rules loaded,
    or compiled where the cache is cold), before the pool's token says the agent is up."""
    stop = stop or threading.Event()
    drops, load = Drops("agent"), Library()
    warm(load)
    with session(bus) as z:
        answers = TickAnswers()

        def start(order: MatchOrder) -> list[Seats]:
            players = players_of(order, load)
            if not players:
                return []
            log.info("match %s: playing %s", order.match, {p.role: p.key for p in players})
            return [Seats(z, order.match, players, drops, adaptive=order.adaptive, ticks=answers)]

        with subscribe(z, keys.pool_tick(pool), Tick, answers.on_tick, drops):
            serve_orders(z, pool, "agent", start, drops, stop, tick=answers.keep)
    return drops


class TickAnswers:
    """A pool's agent's answers to its Ticks: the seats of every match it plays that a tick's frame
    is due for, grouped by the policy they play (its key), each group's policy evaluated once for
    all its rows (player.play_together; a policy from outside acts seat by seat), and each answer
    put on its match's own action key."""

    def __init__(self) -> None:
        self.playing: dict[str, Seats] = {}
        self.lock = threading.Lock()

    def add(self, seats: Seats) -> None:
        with self.lock:
            self.playing[seats.match] = seats

    def keep(self, _parts: list[Seats]) -> None:
        """Forget the matches that ended (serve_orders's tick). Not by the parts it is given: a
        match being ordered is added here before serve_orders holds it as a part."""
        with self.lock:
            self.playing = {match: seats for match, seats in self.playing.items() if not seats.ended.is_set()}

    def on_tick(self, tick: Tick) -> None:
        views = np.frombuffer(tick.views, "<f8").reshape(-1, len(ROLES), OBS_SIZE)
        with self.lock:
            playing = [(self.playing.get(match), n) for n, match in enumerate(tick.matches)]
        groups: dict[tuple, list[tuple[Seats, Seat, Frame, Policy]]] = {}
        for seats, n in playing:
            if seats is None or tick.last[n]:
                continue
            frame = Frame(tick.matches[n], tick.frames[n], dict(zip(ROLES, views[n], strict=True)))
            for seat in seats.due(frame):
                policy = seat[0].ready(frame.frame)
                groups.setdefault((type(policy), policy.key), []).append((seats, seat, frame, policy))
        for group in groups.values():
            self.answer(group)

    @staticmethod
    def answer(group: list[tuple[Seats, Seat, Frame, Policy]]) -> None:
        view = group[0][3].view
        rows = np.stack([frame.obs[seat[0].role] for _, seat, frame, _ in group])
        try:
            actions = play_together([policy for *_, policy in group], as_observations(rows, view))
        except Exception:  # noqa: BLE001 - a policy's batch that fails: each seat acts alone, and says why
            actions = None
        for n, (seats, seat, frame, policy) in enumerate(group):
            if actions is None:
                obs = as_observations(rows[n : n + 1], view)[0]
                action = seat[0].answer(frame, seat[1], policy, lambda p=policy, o=obs: p.act(o))
            else:
                action = seat[0].answer(frame, seat[1], policy, lambda a=actions[n]: a)
            seats.put(seat, action)


def warm(load: Library) -> None:
    """Play every library and scripted policy of either seat once, in a batch of rows in which the
    ship plays alone (so that the compiled end of a stalled round, for more than FEW_ROWS rows, is
    played too): numba's compiled rules are loaded, or compiled where its cache is cold, before the
    pool's token, not when a seat first plays one mid-match (the adapter switches seats to the
    grown library's policies, whose rule heads are the same compiled rules; 10 s and more at load
    12, every match of the pool unanswered meanwhile)."""
    rows = np.zeros((FEW_ROWS + 1, OBS_SIZE))
    rows[:, ob.SELF + ob.ALIVE] = rows[:, ob.FORTRESS + ob.F_ALIVE] = 1.0
    for role in ROLES:
        for key in (*library.keys(role), *scripted_keys(role)):
            with contextlib.suppress(Exception):  # one that does not load is refused by its order
                policy = load(key, role)
                play_together([policy] * len(rows), as_observations(rows, policy.view))
