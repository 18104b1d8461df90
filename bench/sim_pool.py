"""A pool's sim playing N matches at once on its one clock: each match's tick jitter and the sim's CPU.

Starts `tsf sim --pool` (a router on a free loopback port, at `--priority`), then for each N orders
N matches of `--seconds` at once (no waits; with `--stagger` spread over one frame) and reads each
match's summary. Seats are absent (they play no-op) or, with `--seats echo`, held by this process,
which answers every state at once (the round trips then come from a peer on another core). Prints
per N: the worst and the median match's tick-jitter p99 and the matches over 5 ms, the median
round trip's p99 (echo), and the sim's CPU-s per second of play per match (its process's
user+system time over the run, start-ups included). Targets (issue 33, 2 cores): every match's
jitter p99 <= 5 ms at N = 12; CPU well under 0.01.

    .venv/bin/python bench/sim_pool.py [--matches 1,4,12] [--seconds 20] [--seats none|echo] [--stagger]
        [--priority 10]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import threading
import time

import zenoh
from proc import cpu_seconds

from services.runtime.launch import service_command
from shared import keys
from shared.bus import BusConfig, free_endpoint, session
from shared.game import FPS, ROLES
from shared.messages import Action, MatchOrder, State, Summary, decode

POOL = "bench"
NAMES = {"bait": "idle", "shooter": "idle"}  # what the Start records call the seats


class Run:
    """N matches ordered at once; their summaries as they come; with `echo`, both seats answered."""

    def __init__(self, z: zenoh.Session, n: int, frames: int, echo: bool, round_: int) -> None:
        self.z, self.summaries, self.done = z, {}, threading.Event()
        self.matches = [f"r{round_}m{i}" for i in range(n)]
        self.held = []
        for match in self.matches:
            self.held.append(z.declare_subscriber(keys.summary(match), self.on_summary))
            if echo:
                self.held += [z.liveliness().declare_token(keys.alive(match, "agent", r)) for r in ROLES]
                self.held.append(z.declare_subscriber(keys.state(match), self.answer))
        self.orders = [
            MatchOrder(
                match=m,
                frame=0,
                sender="bench",
                seed=i,
                frames=frames,
                names=NAMES,
                wait_players=0,
                wait_services=0,
            )
            for i, m in enumerate(self.matches)
        ]

    def on_summary(self, sample: zenoh.Sample) -> None:
        summary = decode(sample.payload.to_bytes(), Summary)
        self.summaries[summary.match] = summary
        if len(self.summaries) == len(self.matches):
            self.done.set()

    def answer(self, sample: zenoh.Sample) -> None:
        state = decode(sample.payload.to_bytes(), State)
        for role in ROLES:
            action = Action(
                match=state.match, frame=state.frame, sender="bench", role=role, action=1, policy="echo"
            )
            self.z.put(keys.action(state.match, role), action.encode())

    def play(self, timeout: float, stagger: bool) -> list[Summary]:
        for order in self.orders:
            self.z.put(keys.pool_order(POOL), order.encode())
            if stagger:  # orders spread over one frame, as matches that start at any time
                time.sleep(1 / FPS / len(self.orders))
        if not self.done.wait(timeout):
            sys.exit(f"only {len(self.summaries)} of {len(self.matches)} summaries within {timeout:.0f} s")
        for held in self.held:
            held.undeclare()
        return list(self.summaries.values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--matches", default="1,4,12", help="numbers of matches at once, comma-separated")
    parser.add_argument("--seconds", type=float, default=20.0, help="each match's length")
    parser.add_argument("--seats", choices=("none", "echo"), default="none")
    parser.add_argument("--stagger", action="store_true", help="spread each N's orders over one frame")
    parser.add_argument("--priority", type=int, default=10, help="the pool sim's --priority (nice steps)")
    args = parser.parse_args()
    frames = round(args.seconds * FPS)
    endpoint = free_endpoint()
    router = BusConfig("router", (endpoint,))
    sim = subprocess.Popen(service_command("sim", router, "--pool", POOL, "--priority", str(args.priority)))
    try:
        with session(BusConfig("client", (), (endpoint,))) as z:
            alive = keys.pool_alive(POOL, "sim")
            deadline = time.monotonic() + 20
            while not any(r.ok for r in z.liveliness().get(alive, timeout=1)):
                if time.monotonic() > deadline:
                    sys.exit("the pool sim did not come up")
            stagger = ", staggered" if args.stagger else ""
            head = f"{args.seconds:.0f}-s matches{stagger}, seats {args.seats}"
            print(f"pool sim raised {args.priority} nice steps; {head}")
            print(
                "matches | jitter p99 worst / median (ms) | over 5 ms | round trip p99 (ms) | CPU s/s/match"
            )
            for round_, n in enumerate(int(v) for v in args.matches.split(",")):
                run = Run(z, n, frames, args.seats == "echo", round_)
                before = cpu_seconds(sim.pid)
                summaries = run.play(args.seconds * 3 + 10, args.stagger)
                cpu = (cpu_seconds(sim.pid) - before) / (n * args.seconds)
                jitter = sorted(s.timing.get("tick_jitter_ms_p99", float("nan")) for s in summaries)
                trips = [s.timing["round_trip_ms_p99"] for s in summaries if "round_trip_ms_p99" in s.timing]
                trip = f"{statistics.median(trips):.2f}" if trips else "-"
                over = sum(j > 5 for j in jitter)
                print(
                    f"{n:7d} | {jitter[-1]:6.2f} / {statistics.median(jitter):5.2f} | {over:3d} of {n:<3d} "
                    f"| {trip:>6} | {cpu:.4f}"
                )
                time.sleep(1)  # the matches' lingering declarations leave
    finally:
        sim.terminate()
        sim.wait(10)


if __name__ == "__main__":
    main()
