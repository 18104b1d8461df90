"""The floor the bus puts under a pooled match's CPU: a pool's messages alone, with no game, no
policy, no recording and no validation.

Four processes on loopback, connected as a study's pool is (services/runtime/pool.py, the same
`BusConfig`s): a router that puts each match's state (1.5 KB, the size of a real one) every frame
on `tsf/<match>/state`, in the clock's phases, with the sim's publisher options, and takes both
seats' actions; an "agent" client that answers each state with an action for one seat; a
"recorder" client that takes every state and action of every match; and a "participant" client
(the study server's bridge of the person's seat: answers each state for the other seat; its CPU is
the server's, not the pool's, as in bench/study.py). Each callback does nothing but count. Printed:
CPU-s per second of play per match of the router, the agent and the recorder, and their sum,
against what a pooled match costs with its work (bench/study.py) and the target (0.02).

    nice .venv/bin/python bench/bus_floor.py [--matches 12] [--seconds 20]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import zenoh

from services.runtime.launch import match_buses
from services.sim.clock import on_phase
from services.sim.pool import PHASES
from shared import keys
from shared.bus import free_endpoint, session
from shared.game import FPS, ROLES

STATE = bytes(1500)  # a state message's size (msgpack of a frame's world views)
ACTION = bytes(60)
PARTS = ("router", "agent", "recorder", "participant")
SEATS = {"agent": "bait", "participant": "shooter"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--matches", type=int, default=12)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--phases", type=int, default=PHASES, help="of the period (the pool's clock: 4)")
    parser.add_argument("--part", choices=PARTS, help=argparse.SUPPRESS)
    parser.add_argument("--endpoint", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.part:
        print(json.dumps(play(args.part, args.endpoint, args.matches, args.seconds, args.phases)))
        return
    per_match, samples = floor(args.matches, args.seconds, args.phases)
    print(f"{args.matches} matches, {args.seconds:.0f} s, {FPS} frames/s, states in {args.phases} phases:")
    for part in PARTS:
        print(f"  {part:11s} {per_match[part]:.4f} CPU-s per s of play per match, {samples[part]} samples in")
    pool = per_match["pool"]
    print(f"  the pool's processes (router, agent, recorder): {pool:.4f} CPU-s per s of play per match")


def floor(matches: int, seconds: float, phases: int = PHASES) -> tuple[dict[str, float], dict[str, int]]:
    """Play the four parts at once: each part's CPU-s per second of play per match (and "pool", the
    sum of the pool's three), and the samples each took in. bench/study.py runs it beside its load
    test, so that a participant's cost reads as a multiple of the floor of the same hour."""
    endpoint = free_endpoint()
    command = [sys.executable, __file__, "--matches", str(matches), "--seconds", str(seconds)]
    command += ["--phases", str(phases), "--endpoint", endpoint]
    parts = {part: subprocess.Popen([*command, "--part", part], stdout=subprocess.PIPE) for part in PARTS}
    results = {part: json.loads(process.communicate()[0]) for part, process in parts.items()}
    per_match = {part: r["cpu"] / r["seconds"] / matches for part, r in results.items()}
    per_match["pool"] = sum(per_match[part] for part in ("router", "agent", "recorder"))
    return per_match, {part: r["samples"] for part, r in results.items()}


def play(part: str, endpoint: str, matches: int, seconds: float, phases: int) -> dict:
    """Play one part for `seconds` once every part is connected; return its CPU and samples in."""
    router, client = match_buses(endpoint, low_latency=True)
    ids = [f"floor-{n:02d}" for n in range(matches)]
    received = 0

    def count(_: zenoh.Sample) -> None:
        nonlocal received
        received += 1

    with session(router if part == "router" else client) as z:
        declared = []
        if part in SEATS:
            role = SEATS[part]
            actions = {m: z.declare_publisher(keys.action(m, role), express=True) for m in ids}

            def answer(sample: zenoh.Sample, actions: dict = actions) -> None:
                count(sample)
                actions[str(sample.key_expr).split("/")[1]].put(ACTION)

            declared += [z.declare_subscriber(keys.state(m), answer) for m in ids]
        elif part == "recorder":
            declared += [z.declare_subscriber(keys.everything(m), count) for m in ids]
        else:
            declared += [z.declare_subscriber(keys.action(m, role), count) for m in ids for role in ROLES]
        token = z.liveliness().declare_token(f"tsf/floor/{part}")
        others = {f"tsf/floor/{p}" for p in PARTS}
        while {str(r.ok.key_expr) for r in z.liveliness().get("tsf/floor/*") if r.ok} != others:
            time.sleep(0.05)
        time.sleep(0.5)  # every subscriber declared and routed
        start, received = time.process_time(), 0
        if part == "router":
            states(z, ids, seconds, phases)
        else:
            time.sleep(seconds)
        cpu = time.process_time() - start
        time.sleep(0.5)  # the others finish their window before anyone leaves
        token.undeclare()
        return {"cpu": cpu, "seconds": seconds, "samples": received}


def states(z: zenoh.Session, ids: list[str], seconds: float, phases: int) -> None:
    """Put each match's state every frame on its phase of the grid, as the pool's clock does."""
    period = 1.0 / FPS
    publishers = [
        z.declare_publisher(keys.state(m), congestion_control=zenoh.CongestionControl.DROP, express=True,
                            priority=zenoh.Priority.REAL_TIME)
        for m in ids
    ]  # fmt: skip
    groups = [[p for n, p in enumerate(publishers) if n % phases == phase] for phase in range(phases)]
    begin = time.monotonic()
    frame = 0
    while time.monotonic() - begin < seconds:
        for phase, group in enumerate(groups):
            due = on_phase(begin, period, 0.0) + frame * period + phase * period / phases
            time.sleep(max(0.0, due - time.monotonic()))
            for publisher in group:
                publisher.put(STATE)
        frame += 1


if __name__ == "__main__":
    main()
