"""A pool: long-lived services that play many matches each, kept warm for a study server or a match
host (docs/architecture.md, "Pools").

A pool is one process per service: a sim (the pool's zenoh router, on a loopback port of its own,
its priority raised above everything else on the machine, or, where raising is refused to an
ordinary user, the launcher and the pool's other services stepped as far below it), an agent, a
recorder and, for a pool that may play adaptive matches, an adapter. A match is an order (MatchOrder on
tsf/pool/<pool>/order) that each service plays its part of under the match's own keys, exactly as a
match's own processes do (services/runtime/launch.run_match), so a pooled match's traffic, seat
bridging and recording are those of any match. Starting one costs a message instead of four
interpreters (about 2 CPU-s and 72 MiB each), so a participant's match is ready when they are and
one machine serves many more of them.

A service of the pool that dies is started again at once; its clients reconnect to a restarted sim
by themselves. The matches it was playing fail (`run` sees their tokens go before their summary)
and are offered again by whoever ran them.
"""

from __future__ import annotations

import contextlib
import logging
import secrets
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path

import zenoh

from services.recorder.recording import Recording
from services.recorder.service import recording_path
from services.runtime.launch import (
    RECORDER_NICE,
    SIM_RAISE,
    MatchPlan,
    match_buses,
    read_back,
    service_command,
)
from shared import keys
from shared.bus import free_endpoint, subscribe
from shared.errors import Failure, UsageError
from shared.messages import MatchRefused, MatchStop, Summary
from shared.processes import Processes, may_raise, spawner, step_down

log = logging.getLogger("tsf.pool")
READY = 60.0  # seconds a new pool's services may take to come up (a busy machine, a cold cache)
ORDER_AGAIN = 1.0  # seconds between puts of an order, until every service of the match has taken it
TAKE = 30.0  # seconds every service has to take an order (a restarting service's start-up)
CLOSE = 10.0  # seconds a stopped match's sim has to send its summary, and its recorder to close the log


class Refused(Failure):
    """A service of the pool said it cannot play its part of the match (MatchRefused): the match
    failed at once, and every new attempt of the same match would fail the same way."""


def pool_name(prefix: str) -> str:
    """A pool id that no other pool on a shared router has: pools linked to one router (match hosts)
    would otherwise take each other's orders."""
    return keys.check_match(f"{prefix}-{secrets.token_hex(4)}"[-64:])


class Pool:
    """A warm pool of services (the module's docstring): `with Pool(...) as pool: pool.run(plan)`.
    `directory` is where the recorder writes; a plan's directory must be it or a folder in it.
    `peers`: routers the pool's sim also connects to (a match host's study router)."""

    def __init__(
        self,
        name: str,
        directory: Path,
        adaptive: bool = True,
        low_latency: bool = True,
        peers: tuple[str, ...] = (),
    ) -> None:
        self.name, self.directory = keys.check_name(name), Path(directory)
        self.endpoint = free_endpoint()
        self.sim_bus, self.client_bus = match_buses(self.endpoint, low_latency, peers)
        self.services = ("sim", "agent", "recorder", *(("adapter",) if adaptive else ()))
        self.sender = f"pool/{self.name}"
        self.processes = Processes()
        self.restarts: Counter[str] = Counter()
        self.closing = threading.Event()
        self.z: zenoh.Session | None = None
        self.supervisor = threading.Thread(target=self._supervise, name=f"pool-{name}", daemon=True)
        # Where the sim may not raise itself SIM_RAISE steps (an ordinary user), everything else of the
        # pool's and its launcher's steps as far below it: the same order as root's, without a privilege.
        self.below = 0 if may_raise(SIM_RAISE) else SIM_RAISE

    def _start(self, service: str) -> None:
        pool = ("--pool", self.name)
        if service == "sim":
            command = service_command("sim", self.sim_bus, *pool, "--priority", str(SIM_RAISE))
        elif service == "recorder":
            command = service_command("recorder", self.client_bus, *pool, "--out", str(self.directory))
        else:
            command = service_command(service, self.client_bus, *pool)
        nice = 0 if service == "sim" else self.below + (RECORDER_NICE if service == "recorder" else 0)
        self.processes.start(service, command, nice=nice)

    def __enter__(self) -> Pool:
        """Start the services and wait until each is up (Failure if one is not within READY s). Where
        the sim may not raise itself, every thread of this process but the spawner (which starts a
        sim, again or for another pool, at the launcher's first priority: shared/processes.py) then
        steps `below` it (24 participants at once as an ordinary user: docs/architecture.md,
        "Capacity as an ordinary user")."""
        self.directory.mkdir(parents=True, exist_ok=True)
        try:
            for service in self.services:
                self._start(service)
            self.z = zenoh.open(self.client_bus.to_zenoh())
            with Tokens(self.z, keys.pool_alive(self.name), self.services, _service) as up:
                if not up.wait(READY, abort=self._died):  # a service that died will not come up
                    raise Failure(f"pool {self.name}: {', '.join(up.missing())} not up after {READY:g} s")
        except BaseException:
            self.__exit__()
            raise
        self.supervisor.start()
        if self.below:
            step_down(self.below, above=spawner())
            log.info(
                "pool %s: the sim may not raise its priority (needs CAP_SYS_NICE or a nice limit,"
                " docs/human.md): this process and the pool's other services step %d below it instead",
                self.name, self.below,
            )  # fmt: skip
        log.info("pool %s: %s up on %s", self.name, ", ".join(self.services), self.endpoint)
        return self

    def __exit__(self, *exc: object) -> None:
        self.closing.set()
        if self.supervisor.is_alive():
            self.supervisor.join()
        if self.z is not None:
            self.z.close()
        self.processes.__exit__()

    def _died(self) -> bool:
        return any(child.poll() is not None for child in self.processes.children.values())

    def _supervise(self) -> None:
        """Start again, at once, any service of the pool that ends while the pool runs."""
        while not self.closing.wait(0.2):
            for service in self.services:
                child = self.processes.children[service]
                if child.poll() is not None and not self.closing.is_set():
                    self.restarts[service] += 1
                    log.error(
                        "pool %s: the %s exited with status %s; started again (its matches fail)",
                        self.name, service, child.returncode,
                    )  # fmt: skip
                    self._start(service)

    def folder(self, plan: MatchPlan) -> str:
        """The folder of the pool's directory that `plan` records into ("" for the directory itself);
        a UsageError for a directory elsewhere."""
        directory, root = plan.directory.resolve(), self.directory.resolve()
        if directory == root:
            return ""
        if directory.parent != root:
            raise UsageError("--out", plan.directory, f"a pooled match records into {root} or a folder in it")
        return directory.name

    def run(
        self,
        plan: MatchPlan,
        stop: threading.Event | None = None,
        on_taken: Callable[[], None] = lambda: None,
    ) -> Recording:
        """Play `plan` on the pool to its end (`play`) and return its complete recording (its
        summary, its path), read back once, as run_match does; one whose recording is not complete
        is Incomplete."""
        return read_back(self.play(plan, stop, on_taken), plan.match)

    def play(
        self,
        plan: MatchPlan,
        stop: threading.Event | None = None,
        on_taken: Callable[[], None] = lambda: None,
    ) -> Path:
        """Play `plan` on the pool to its end and return the path of its recording, unread: a
        launcher that judges the recording further reads it where it judges (the study's judge, in
        a process of its own). `on_taken` is called once (on zenoh's thread) when every service
        has taken the match: it is ready for its people (the study offers the trial then). A match
        that was stopped or ran past `plan.timeout`, or that some service of the pool did not take
        or left before the end, is a Failure; one that some service refused (MatchRefused: it
        cannot play its part) is Refused, at once. Any recording is kept."""
        stop = stop or threading.Event()
        order = plan.order(self.sender, self.folder(plan))
        path = recording_path(plan.directory, plan.match)
        if path.exists():
            raise UsageError("--match", plan.match, f"{path} exists: a pooled match needs a new id")
        match = plan.match
        deadline = time.monotonic() + plan.timeout if plan.timeout else float("inf")
        with MatchWatch(self.z, match, plan.tokens(), on_taken, keys.pool_refused(self.name)) as watch:
            ordered, put_at, why = time.monotonic(), 0.0, ""
            while not watch.ended.wait(0.05):
                now = time.monotonic()
                if stop.is_set():
                    why = f"match {match} was stopped before its end"
                elif now >= deadline:
                    why = f"match {match} ran past its {plan.timeout:g} s"
                elif watch.refusal is not None:
                    refusal = watch.refusal
                    why = f"match {match}: the pool's {refusal.service} cannot play it: {refusal.reason}"
                elif lost := watch.lost():
                    why = f"match {match}: the pool's {lost} left it before its end"
                elif not watch.tokens.taken() and now - ordered > plan.wait_services + TAKE:
                    missing = ", ".join(watch.tokens.missing())
                    why = f"match {match}: not every service of pool {self.name} took it ({missing})"
                if why:
                    break
                if not watch.tokens.taken() and now - put_at >= ORDER_AGAIN:
                    self.z.put(keys.pool_order(self.name), order.encode())
                    put_at = now
            if why and put_at:  # the sim ends it (with a summary) and the recorder closes its log
                ending = MatchStop(match=match, frame=0, sender=self.sender)
                self.z.put(keys.pool_stop(self.name), ending.encode())
            if put_at:  # else never ordered: nothing to close
                _wait_closed(watch, path)
        if stop.is_set() and not why:  # as run_match: a stop before the recording is closed fails it
            why = f"match {match} was stopped before its end"
        if why:
            raise (Refused if watch.refusal is not None else Failure)(why)
        return path


def _wait_closed(watch: MatchWatch, path: Path) -> None:
    """Wait for the match's recorder to close its log: CLOSE seconds, and on for as long as the log
    still grows. A recorder behind under load writes the match's last records after its end; cut
    off after CLOSE, its complete recording was judged incomplete (139 games at 60 participants on
    two cores). One that writes nothing for CLOSE seconds is given up."""

    def size() -> int:
        return path.stat().st_size if path.exists() else 0

    before = size()
    while not watch.closed.wait(CLOSE):
        if size() == before:
            return
        before = size()


def _service(key: str) -> str:
    """The service a token names: `sim`, `recorder`, ... (`agent/bait` for a seat's)."""
    parsed = keys.parse(key)
    return f"{parsed.service}/{parsed.role}" if parsed.role else parsed.service


class Tokens:
    """The liveliness tokens under `key_expr` that are up and those that have been, each known by
    `name(key)` (the key by default), against the `needed` ones: the one wait of a launcher for
    services to come up (`wait`), and what it watches of them (`taken`, `lost`). `on_change` runs
    after each change and `on_taken` once, when every needed token has been up, both on zenoh's
    thread outside the lock. A context manager: its subscriber is declared and undeclared on the
    calling thread, never on zenoh's."""

    def __init__(
        self,
        z: zenoh.Session,
        key_expr: str,
        needed: Iterable[str],
        name: Callable[[str], str] = str,
        on_change: Callable[[], None] = lambda: None,
        on_taken: Callable[[], None] = lambda: None,
    ) -> None:
        self.z, self.key_expr, self.needed, self.name = z, key_expr, set(needed), name
        self.on_change, self.on_taken, self.told = on_change, on_taken, False
        self.up, self.seen = set[str](), set[str]()
        self.changed = threading.Condition()
        self.subscriber: zenoh.Subscriber | None = None

    def __enter__(self) -> Tokens:
        self.subscriber = self.z.liveliness().declare_subscriber(self.key_expr, self._on_alive, history=True)
        return self

    def __exit__(self, *exc: object) -> None:
        self.subscriber.undeclare()

    def _on_alive(self, sample: zenoh.Sample) -> None:
        name = self.name(str(sample.key_expr))
        with self.changed:
            if sample.kind == zenoh.SampleKind.PUT:
                self.up.add(name)
                self.seen.add(name)
            else:
                self.up.discard(name)
            tell = not self.told and self.seen >= self.needed
            self.told |= tell
            self.changed.notify_all()
        self.on_change()
        if tell:
            self.on_taken()

    def wait(self, timeout: float, abort: Callable[[], bool] = lambda: False) -> bool:
        """Wait until every needed token is up: False if some are still missing after `timeout`
        seconds, or once `abort()` is true (asked every tenth of a second)."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while not self.up >= self.needed:
                if abort() or time.monotonic() >= deadline:
                    return False
                self.changed.wait(0.1)
            return True

    def state(self) -> tuple[set[str], set[str]]:
        """Copies of the tokens up and of those seen."""
        with self.changed:
            return set(self.up), set(self.seen)

    def taken(self) -> bool:
        """Whether every needed token has been up (each service took the match)."""
        with self.changed:
            return self.seen >= self.needed

    def missing(self) -> list[str]:
        """The needed tokens not up, sorted."""
        with self.changed:
            return sorted(self.needed - self.up)

    def lost(self) -> list[str]:
        """The needed tokens that were up and went, sorted."""
        with self.changed:
            return sorted((self.needed & self.seen) - self.up)


class MatchWatch:
    """What a launcher sees of one pooled match: its services' tokens (Tokens), its summary, and
    whether it is closed: its recorder's token gone after the summary (the log closed), or every
    token it had gone (a killed service's match, or one stopped early). A context manager."""

    def __init__(
        self,
        z: zenoh.Session,
        match: str,
        needed: set[str],
        on_taken: Callable[[], None],
        refusals: str = "",
    ) -> None:
        self.z, self.match, self.refusals = z, match, refusals
        self.tokens = Tokens(z, keys.services_alive(match), needed, on_change=self._close, on_taken=on_taken)
        self.summary: Summary | None = None
        self.refusal: MatchRefused | None = None  # a service's word that it cannot play its part
        self.ended, self.closed = threading.Event(), threading.Event()
        self.stack = contextlib.ExitStack()

    def __enter__(self) -> MatchWatch:
        self.stack.enter_context(self.tokens)
        self.stack.enter_context(subscribe(self.z, keys.summary(self.match), Summary, self.on_summary))
        if self.refusals:  # the pool's refusals: this match's
            self.stack.enter_context(subscribe(self.z, self.refusals, MatchRefused, self.on_refused))
        return self

    def __exit__(self, *exc: object) -> None:
        self.stack.close()

    def on_summary(self, summary: Summary) -> None:
        self.summary = summary
        self._close()
        self.ended.set()

    def on_refused(self, refusal: MatchRefused) -> None:
        if refusal.match == self.match and self.refusal is None:
            self.refusal = refusal

    def _close(self) -> None:
        """Either callback reads what the other wrote before its own _close (the tokens under their
        lock, the summary at once): the last of the two sees both."""
        up, seen = self.tokens.state()
        if (self.summary is not None and keys.alive(self.match, "recorder") not in up) or (seen and not up):
            self.closed.set()

    def lost(self) -> str:
        """The first service (`agent/bait`, `recorder`, ...) whose token went before the summary."""
        gone = self.tokens.lost()
        return _service(gone[0]) if gone else ""
