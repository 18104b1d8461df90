"""Starting a whole match on one machine: sim, two agents and the recorder as separate processes,
and for an adaptive match the adapter that switches one agent's policy.

The sim's session is the match's router: it listens on a loopback port of its own, and every other
process of the match (and a gateway bridging a person's seat) is a client of it, connected to that
endpoint alone. No gossip mesh and no multicast: concurrent matches never meet, a match's processes
never learn of another's, and zenoh's peer routing (whose lock cycle, eclipse-zenoh issue 2581,
wedged sessions when many peers came and went) is not used.
"""

from __future__ import annotations

import re
import secrets
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from services.adapter import core
from services.agent.outside import record_name
from services.population.adaptive import AdapterConfig
from services.population.seat import AdaptiveSeat, PersonSeat, PolicySeat, SeatSpec, check_live
from services.recorder.log import make_way
from services.recorder.recording import Recording, load
from services.recorder.service import recording_path
from shared import keys
from shared.bus import BusConfig, free_endpoint, session, subscribe
from shared.errors import Failure, UsageError
from shared.game import ROLES
from shared.messages import POLICY_NAME, AdapterStatus, MatchOrder, State, Summary
from shared.processes import Processes

# Priorities, in nice steps from the launcher's: the sim raises itself at its first frame (where
# permitted; its start-up runs at the launcher's), so every start-up runs below the live sims and
# one match's start does not take another's frames. The recorder, which drains a queue, runs below
# the rest. Agents and adapter stay at the launcher's: below it, other work on the machine starved
# them (the adapter of a 1.5-s trial sent no report at load 15-20).
SIM_RAISE, RECORDER_NICE = 5, 10


@dataclass(frozen=True)
class MatchPlan:
    """A match to start: its id, seed and length, and what plays each seat (a SeatSpec, parsed
    where its name came in; the adaptive agent's seat carries its whole AdapterConfig)."""

    match: str
    seed: int = 0
    frames: int = 1800
    mode: str = "realtime"
    bait: SeatSpec = PolicySeat("circle")
    shooter: SeatSpec = PolicySeat("mirror")
    directory: Path = Path("recordings")
    low_latency: bool = True
    peers: tuple[str, ...] = ()  # endpoints the sim also connects to (a human gateway's session)
    wait_players: float = 10.0  # seconds the sim waits for both seats (people take longer)
    endpoint: str = ""  # where the sim listens; empty: a free loopback port
    wait_services: float = 10.0  # seconds the sim waits for the recorder (and the adapter)
    timeout: float = 0.0  # seconds the whole match may take, start-up included; 0: no limit

    def __post_init__(self) -> None:
        """Refuse (UsageError) a match whose seats cannot all be filled, before anything starts
        (the AdapterConfig has checked the adaptive seat's options; its out-of-library thresholds
        are checked here, or the adapter would stop with them once the match had begun)."""
        keys.check_match(self.match)
        adaptive = [role for role, spec in self.seats.items() if isinstance(spec, AdaptiveSeat)]
        for role, spec in self.seats.items():
            if role not in adaptive:
                check_live(spec, role, f"--{role}")
        if len(adaptive) > 1:
            raise UsageError("--adaptive", "both seats", "one seat at most is the adaptive agent's")
        if self.adapter is not None:
            core.threshold(self.adapter)
            if not re.fullmatch(POLICY_NAME, self.adapter.name):  # what the Start record names the seat
                raise UsageError(
                    "--adaptive", self.adapter.name, "a name longer than a recording's 64 characters"
                )

    @property
    def seats(self) -> dict[str, SeatSpec]:
        return {role: getattr(self, role) for role in ROLES}

    @property
    def adapter(self) -> AdapterConfig | None:
        """The adaptive agent, in its seat of this match's seed; None for a match without one."""
        return next(filter(None, (spec.adaptive(role, self.seed) for role, spec in self.seats.items())), None)

    def names(self) -> dict[str, str]:
        """What the Start record calls each seat: a policy by its name (a .zip path's name), the
        adaptive seat by the adaptive agent's."""
        names = {role: record_name(key) for role, key in self.policies().items()}
        if self.adapter is not None:
            names[self.adapter.role] = self.adapter.name
        return names

    def order(self, sender: str, folder: str = "") -> MatchOrder:
        """This match as a pool's order (services/runtime/pool.py): the recording goes into
        `folder` of the pool recorder's directory."""
        policies, adapter = self.policies(), self.adapter
        return MatchOrder(
            match=self.match, frame=0, sender=sender, seed=self.seed, frames=self.frames, mode=self.mode,
            **{role: "" if isinstance(self.seats[role], PersonSeat) else policies[role] for role in ROLES},
            names=self.names(), adapter=adapter.name if adapter else "",
            adaptive=adapter.role if adapter else "",
            wait_players=self.wait_players, wait_services=self.wait_services, folder=folder,
        )  # fmt: skip

    def tokens(self) -> set[str]:
        """The liveliness tokens of every service that plays a part of this match (a person's seat
        is no service's): once all are up, the match is ready for its people."""
        match = self.match
        tokens = {keys.alive(match, "sim"), keys.alive(match, "recorder")}
        agents = [role for role, spec in self.seats.items() if not isinstance(spec, PersonSeat)]
        tokens |= {keys.alive(match, "agent", role) for role in agents}
        return tokens | ({keys.alive(match, "adapter")} if self.adapter is not None else set())

    def policies(self) -> dict[str, str]:
        """Each seat's starting policy key; an adaptive seat starts with the adapter's initial policy."""
        keys_ = {role: str(spec) for role, spec in self.seats.items()}
        if self.adapter is not None:
            keys_[self.adapter.role] = core.initial_policy(self.adapter)
        return keys_


def match_buses(endpoint: str, low_latency: bool, peers: tuple[str, ...] = ()) -> tuple[BusConfig, BusConfig]:
    """The sim's bus (the match's router, listening on `endpoint`) and its clients' bus. Clients wait
    up to a minute for the sim: on a busy machine a match's processes start slowly and in any order."""
    sim = BusConfig(mode="router", listen=(endpoint,), connect=peers, low_latency=low_latency)
    client = BusConfig(
        mode="client", listen=(), connect=(endpoint,), low_latency=low_latency, wait_router=60.0
    )
    return sim, client


def watcher_bus(endpoint: str, low_latency: bool) -> BusConfig:
    """A session that only watches the match: a peer that dials the sim and listens nowhere, so it
    opens at once and joins whenever the sim listens (a client's open would wait, and fail if the
    match were over by then)."""
    return BusConfig(listen=(), connect=(endpoint,), low_latency=low_latency)


def service_command(name: str, bus: BusConfig, *args: str) -> list[str]:
    """The command line that starts one service of the `tsf` CLI in a new Python process."""
    return [sys.executable, "-m", "services.commands", name, *bus.to_args(), *args]


def run_match(
    plan: MatchPlan,
    on_state: Callable[[State], None] = lambda state: None,
    on_adapter: Callable[[AdapterStatus], None] = lambda status: None,
    overwrite: bool = False,
    stop: threading.Event | None = None,
) -> tuple[Summary, Path]:
    """Run the match to its end; `on_state` sees up to 10 states a second and `on_adapter` the
    adapter's reports (for a live scoreboard). A recording of the same id is never appended to:
    refused, or with `overwrite` renamed aside (log.make_way). `stop` (stop_on_signals: SIGINT,
    SIGTERM, SIGHUP) ends the match and every process it started, as does running past
    `plan.timeout`. A match that was stopped or timed out, or one of whose services failed, is a
    Failure; one whose recording is not complete (a summary included) is Incomplete."""
    stop = stop or threading.Event()
    path = recording_path(plan.directory, plan.match)
    make_way(path, overwrite)
    deadline = time.monotonic() + plan.timeout if plan.timeout else float("inf")
    endpoint = plan.endpoint or free_endpoint()
    sim_bus, peer_bus = match_buses(endpoint, plan.low_latency, plan.peers)
    done = threading.Event()  # the summary came
    shown = [0.0]

    def on_state_shown(state: State) -> None:
        """At most 10 updates a second: the scoreboard shares the CPU with the match."""
        if time.monotonic() - shown[0] >= 0.1:
            on_state(state)
            shown[0] = time.monotonic()

    match = ["--match", plan.match]
    policies = plan.policies()
    recorded = plan.names()
    with Processes() as processes:
        processes.start(
            "sim",
            service_command(
                "sim", sim_bus, *match, "--seed", str(plan.seed), "--frames", str(plan.frames),
                "--sim-mode", plan.mode, "--bait", recorded["bait"], "--shooter", recorded["shooter"],
                "--wait-recorder", str(plan.wait_services), "--wait-players", str(plan.wait_players),
                "--wait-adapter", str(plan.wait_services) if plan.adapter else "0",
                "--priority", str(SIM_RAISE),
            ),
        )  # fmt: skip
        recorder = service_command("recorder", peer_bus, *match, "--out", str(plan.directory))
        processes.start("recorder", recorder, nice=RECORDER_NICE)
        if plan.adapter is not None:
            processes.start("adapter", service_command("adapter", peer_bus, *match, *plan.adapter.to_args()))
        for role, policy in policies.items():
            if isinstance(plan.seats[role], PersonSeat):
                continue
            if plan.adapter is not None and role == plan.adapter.role:
                policy = plan.adapter.name  # the agent starts with its initial policy, and plays as ruled
            processes.start(
                f"agent-{role}",
                service_command(
                    "agent", peer_bus, *match, "--role", role, "--policy", policy, "--seed", str(plan.seed)
                ),
            )
        with (
            session(watcher_bus(endpoint, plan.low_latency)) as z,
            subscribe(z, keys.state(plan.match), State, on_state_shown),
            subscribe(z, keys.summary(plan.match), Summary, lambda _: done.set()),
            subscribe(z, keys.adapter(plan.match), AdapterStatus, on_adapter),
        ):
            while not done.wait(0.2) and not stop.is_set() and time.monotonic() < deadline:
                if processes.children["sim"].poll() is not None:
                    break
        late = not done.is_set() and time.monotonic() >= deadline
        if not stop.is_set() and not late:
            processes.wait("sim", 10)
            processes.wait("recorder", 10)
    if stop.is_set():
        raise Failure(f"match {plan.match} was stopped before its end; its processes ended")
    if late:
        raise Failure(f"match {plan.match} ran past its {plan.timeout:g} s; its processes ended")
    if failed := processes.failed():
        statuses = ", ".join(f"{name} exited with status {code}" for name, code in failed.items())
        raise Failure(f"match {plan.match}: {statuses}")
    recording = read_back(path, plan.match)  # complete: with its summary (the live view can miss it)
    return recording.summary, path


def read_recording(path: Path) -> tuple[Recording | None, list[str]]:
    """The recording at `path`, read once, and what makes it less than a complete match
    (Recording.problems), one phrase each; (None, [why]) for a missing or unreadable file. The one
    check of a recording: the launchers' (read_back) and the study's judge (services/study/judge.py)."""
    try:
        recording = load(path)
    except FileNotFoundError:
        return None, ["no such file"]
    except (OSError, ValueError) as error:
        return None, [str(error)]
    return recording, recording.problems()


class Incomplete(Failure):
    """A match that ended, but whose recording is not complete: its problems, each said once."""

    def __init__(self, match: str, path: Path, problems: list[str]) -> None:
        super().__init__(f"match {match}: its recording {path} is incomplete: {'; '.join(problems)}")
        self.problems = problems


def read_back(path: Path, match: str) -> Recording:
    """A launcher's last check of an ended match: its complete recording, else Incomplete (once,
    every process exited 0 and a recorder cut off under load had left an 8-byte log)."""
    recording, problems = read_recording(path)
    if problems:
        raise Incomplete(match, path, problems)
    return recording


def new_match_id() -> str:
    """The clock for reading, and a random suffix for uniqueness: matches started in the same second
    never share an id, and so never a recording."""
    return time.strftime("m%Y%m%d-%H%M%S-") + secrets.token_hex(3)
