"""The pool's sim: one long-lived process that plays every match a launcher orders on one clock
(`tsf sim --pool P`), each match exactly as a match's own sim plays it (service.MatchSim)."""

from __future__ import annotations

import contextlib
import logging
import sys
import threading

import zenoh

from services.sim.clock import Clock
from services.sim.service import MatchSim, _raise_priority, real_time
from shared import keys
from shared.bus import BusConfig, Drops, Seen, session, subscribe
from shared.game import GameConfig
from shared.messages import MatchOrder, MatchStop
from shared.processes import step_down

log = logging.getLogger("tsf.sim")
PHASES = 8  # of the period, in which the pool's matches tick (clock.py: measured against 1, 4 and 12)
BUS_BELOW = 3  # nice steps the bus's threads take below the clock where the real-time class is refused
SWITCH_INTERVAL = 0.001  # seconds a thread holds the GIL before it must offer it (Python's: 0.005)


class PoolSim:
    """Starts a match per order (a repeated order, for a match it has or had, is ignored) and ends
    one on its stop; the clock plays them. Bad orders and stops are counted in `drops`."""

    def __init__(self, z: zenoh.Session, pool: str, clock: Clock) -> None:
        self.z, self.pool, self.clock = z, pool, clock
        self.seen, self.drops = Seen(), Drops("sim")
        self.lock = threading.Lock()

    def declare(self, stack: contextlib.ExitStack) -> None:
        """Subscribe to the pool's orders and stops, then declare the pool's sim token."""
        stack.enter_context(subscribe(self.z, keys.pool_order(self.pool), MatchOrder, self.order, self.drops))
        stack.enter_context(subscribe(self.z, keys.pool_stop(self.pool), MatchStop, self.stop, self.drops))
        stack.enter_context(self.z.liveliness().declare_token(keys.pool_alive(self.pool, "sim")))

    def order(self, order: MatchOrder) -> None:
        with self.lock:
            if not self.seen.add(order.match):
                return
        match = MatchSim(
            self.z, self.clock.changed, order.match, order.seed, GameConfig(frames=order.frames), order.mode,
            order.names, order.wait_players, order.wait_services,
            wait_adapter=order.wait_services if order.adapter else 0.0,
        )  # fmt: skip
        match.open()
        self.clock.add(match)
        log.info(
            "pool %s: match %s ordered (%d frames, %s)", self.pool, order.match, order.frames, order.mode
        )

    def stop(self, stop: MatchStop) -> None:
        with self.lock:
            self.seen.add(stop.match)  # an order that comes after its stop is not played
        self.clock.end(stop.match)


def run_pool(bus: BusConfig, pool: str, stop: threading.Event, priority: int = 0) -> PoolSim:
    """Play the pool's matches until `stop` is set, then end those running (their summaries are
    published) and return. Raises the priority by `priority` nice steps at once (every thread of
    the process, the session's included) and, if it raises it at all, puts them in the real-time
    class (service.real_time). Where that is refused (an ordinary user), every thread but the
    clock's steps BUS_BELOW below it instead (the session's, the callbacks' and those they start),
    so that a due tick is not held up by the bus's work between ticks (24 at once as an ordinary
    user: docs/architecture.md, "Capacity as an ordinary user"). Offers the GIL more often so that
    the bus's callbacks delay the clock less. The pool's name is checked where it enters
    (options.in_pool)."""
    with session(bus) as z, contextlib.ExitStack() as stack:
        clock = Clock(PHASES)
        sim = PoolSim(z, pool, clock)
        _raise_priority(priority)
        below = priority > 0 and not real_time()
        sys.setswitchinterval(SWITCH_INTERVAL)
        sim.declare(stack)
        if below:  # once the orders' subscriber is declared: the threads it starts are the bus's
            step_down(BUS_BELOW, above=threading.get_native_id())
        log.info("pool %s: the sim is ready for orders", pool)
        clock.run(stop)
        return sim
