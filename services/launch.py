"""Starting a whole match on one machine: sim, two agents and the recorder as separate processes,
and for an adaptive match the adapter that switches one agent's policy.

The sim listens on a free loopback port; every other process connects to it in peer mode and
listens on a port of its own, so zenoh's gossip links them all directly. No router, no multicast.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from services.adapter.core import AdapterConfig
from services.recorder.recording import load
from services.recorder.service import recording_path
from shared import keys
from shared.bus import BusConfig, free_endpoint, session, subscribe
from shared.messages import AdapterStatus, State, Summary

HUMAN = "human"  # a seat's policy key for a person: no agent is started, a gateway plays it


@dataclass(frozen=True)
class MatchPlan:
    match: str
    seed: int = 0
    frames: int = 1800
    mode: str = "realtime"
    bait: str = "circle"
    shooter: str = "mirror"
    directory: Path = Path("recordings")
    low_latency: bool = True
    peers: tuple[str, ...] = ()  # endpoints the sim also connects to (a human gateway's session)
    wait_players: float = 10.0  # seconds the sim waits for both seats (people take longer)
    adapter: AdapterConfig | None = None  # the adaptive agent, in the seat it names (that key is ignored)

    def policies(self) -> dict[str, str]:
        """Each seat's starting policy key; an adaptive seat starts with the adapter's initial policy."""
        keys_ = {"bait": self.bait, "shooter": self.shooter}
        if self.adapter is not None:
            keys_[self.adapter.role] = self.adapter.initial_policy()
        return keys_


def service_command(name: str, bus: BusConfig, *args: str) -> list[str]:
    """The command line that starts one service of the `tsf` CLI in a new Python process."""
    return [sys.executable, "-m", "services.cli", name, *bus.to_args(), *args]


class Processes:
    """The child processes of a match; all are ended (SIGTERM, then SIGKILL) on exit."""

    def __init__(self) -> None:
        self.children: dict[str, subprocess.Popen] = {}

    def start(self, name: str, command: list[str], nice: int = 0) -> subprocess.Popen:
        """Start a child; `nice` > 0 lowers its CPU priority (for work off the latency path)."""
        self.children[name] = subprocess.Popen(
            command, stdin=subprocess.DEVNULL, preexec_fn=(lambda: os.nice(nice)) if nice else None
        )
        return self.children[name]

    def wait(self, name: str, timeout: float) -> int | None:
        try:
            return self.children[name].wait(timeout)
        except subprocess.TimeoutExpired:
            return None

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc: object) -> None:
        for child in self.children.values():
            if child.poll() is None:
                child.terminate()
        for child in self.children.values():
            try:
                child.wait(5)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()


def run_match(
    plan: MatchPlan,
    on_state: Callable[[State], None] = lambda state: None,
    on_adapter: Callable[[AdapterStatus], None] = lambda status: None,
) -> tuple[Summary, Path]:
    """Run the match to its end; `on_state` sees up to 10 states a second and `on_adapter` the
    adapter's reports (for a live scoreboard)."""
    endpoint = free_endpoint()
    sim_bus = BusConfig(listen=(endpoint,), connect=plan.peers, low_latency=plan.low_latency)
    peer_bus = BusConfig(connect=(endpoint,), low_latency=plan.low_latency)
    summary: list[Summary] = []
    done = threading.Event()

    def on_summary(message: Summary) -> None:
        summary.append(message)
        done.set()

    shown = [0.0]

    def on_state_shown(state: State) -> None:
        """At most 10 updates a second: the scoreboard shares the CPU with the match."""
        if time.monotonic() - shown[0] >= 0.1:
            on_state(state)
            shown[0] = time.monotonic()

    match = ["--match", plan.match]
    policies = plan.policies()
    recorded = dict(policies)
    if plan.adapter is not None:
        recorded[plan.adapter.role] = plan.adapter.name
    with Processes() as processes:
        processes.start(
            "sim",
            service_command(
                "sim", sim_bus, *match, "--seed", str(plan.seed), "--frames", str(plan.frames),
                "--sim-mode", plan.mode, "--bait", recorded["bait"], "--shooter", recorded["shooter"],
                "--wait-recorder", "10", "--wait-players", str(plan.wait_players),
                "--wait-adapter", "10" if plan.adapter else "0",
            ),
        )  # fmt: skip
        recorder = service_command("recorder", peer_bus, *match, "--out", str(plan.directory))
        processes.start("recorder", recorder, nice=10)  # it drains a queue: latency is not its job
        if plan.adapter is not None:
            processes.start("adapter", service_command("adapter", peer_bus, *match, *plan.adapter.to_args()))
        for role, policy in policies.items():
            if policy == HUMAN:
                continue
            processes.start(
                f"agent-{role}",
                service_command(
                    "agent", peer_bus, *match, "--role", role, "--policy", policy, "--seed", str(plan.seed)
                ),
            )
        with (
            session(peer_bus) as z,
            subscribe(z, keys.state(plan.match), State, on_state_shown),
            subscribe(z, keys.summary(plan.match), Summary, on_summary),
            subscribe(z, keys.adapter(plan.match), AdapterStatus, on_adapter),
        ):
            while not done.wait(0.2):
                if processes.children["sim"].poll() is not None:
                    break
        processes.wait("sim", 10)
        processes.wait("recorder", 10)
    path = recording_path(plan.directory, plan.match)
    if not summary and path.exists():  # the live view can miss it; the recording cannot
        summary = [s for s in [load(path).summary] if s is not None]
    if not summary:
        code = processes.children["sim"].returncode
        raise RuntimeError(f"match {plan.match} ended without a summary (sim exit code {code})")
    return summary[0], path


def new_match_id() -> str:
    return time.strftime("m%Y%m%d-%H%M%S")
