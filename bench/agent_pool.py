"""The cost of playing seats in a pool: CPU-s per second of play per seat of one `tsf agent --pool`
process (and, with --adaptive, per match of one `tsf adapter --pool`), answering N real-time
matches at once. The bench is the pool's router and plays the sim: it publishes each match's states
(a real game's, built beforehand) at 30 Hz and counts the answers. Goal: an agent seat well under
0.008 CPU-s per second of play (a whole match, sim + agents + recorder + adapter, <= 0.02).

    .venv/bin/python bench/agent_pool.py [--matches 12] [--seconds 20] [--adaptive]

The CPU is the service process's own (user + system, /proc), from the first state to the last;
its start-up and each match's set-up are outside. Resident memory is read at the end.
"""

from __future__ import annotations

import argparse
import subprocess
import time

from proc import cpu_seconds, rss_kib

from services.adapter.core import initial_policy
from services.population.adaptive import AdapterConfig
from services.runtime.launch import match_buses, service_command
from services.sim.engine import Game
from services.sim.match import state_message, summary_message
from shared import keys
from shared.bus import free_endpoint, session
from shared.game import FPS, ROLES, GameConfig
from shared.messages import MatchOrder

POOL = "bench"


def states(match: str, seed: int, frames: int) -> list[bytes]:
    """Every state of a game whose seats play no-op, encoded (the answers' content costs the same)."""
    game, out = Game(GameConfig(frames=frames), seed), []
    while not game.done:
        out.append(state_message(game, match, "sim", (0, 0)).encode())
        game.step(0, 0)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--matches", type=int, default=12)
    parser.add_argument("--seconds", type=float, default=20.0, help="of play, each match")
    parser.add_argument(
        "--adaptive", action="store_true", help="each match's shooter adapted by an adapter pool"
    )
    args = parser.parse_args()
    frames = round(args.seconds * FPS)
    endpoint = free_endpoint()
    router, client = match_buses(endpoint, low_latency=True)
    config = AdapterConfig("shooter")
    matches = [f"m{i}" for i in range(args.matches)]
    played = {m: states(m, i, frames) for i, m in enumerate(matches)}
    with session(router) as z:
        names = ["agent", *(["adapter"] if args.adaptive else [])]
        services = {name: subprocess.Popen(service_command(name, client, "--pool", POOL)) for name in names}
        try:
            alive = [keys.pool_alive(POOL, name) for name in names]
            while not all(any(r.ok for r in z.liveliness().get(key, timeout=1)) for key in alive):
                time.sleep(0.1)
            answers = {m: 0 for m in matches}

            def count(sample) -> None:  # noqa: ANN001 - a zenoh Sample
                answers[keys.parse(sample.key_expr).match] += 1

            counted = z.declare_subscriber("tsf/*/action/*", count)
            adaptive = {"adapter": config.name, "adaptive": "shooter"} if args.adaptive else {}
            shooter = initial_policy(config) if args.adaptive else "S5"
            for i, match in enumerate(matches):
                order = MatchOrder(
                    match=match, frame=0, sender="bench", seed=i, frames=frames, bait="B3", shooter=shooter,
                    names={"bait": "B3", "shooter": "S5"}, **adaptive,
                )  # fmt: skip
                z.put(keys.pool_order(POOL), order.encode())
            tokens = [keys.alive(m, "agent", r) for m in matches for r in ROLES]
            tokens += [keys.alive(m, "adapter") for m in matches] if args.adaptive else []
            while not all(any(r.ok for r in z.liveliness().get(t, timeout=1)) for t in tokens):
                time.sleep(0.1)
            publishers = {m: z.declare_publisher(keys.state(m), express=True) for m in matches}
            began = {name: cpu_seconds(p.pid) for name, p in services.items()}
            start = time.perf_counter()
            for frame in range(frames):
                time.sleep(max(0.0, start + frame / FPS - time.perf_counter()))
                for match in matches:
                    publishers[match].put(played[match][frame])
            time.sleep(0.2)  # the last answers
            play = time.perf_counter() - start
            spent = {name: cpu_seconds(p.pid) - began[name] for name, p in services.items()}
            memory = {name: rss_kib(p.pid) / 1024 for name, p in services.items()}
            for match in matches:
                z.put(
                    keys.summary(match),
                    summary_message(Game(GameConfig(frames=frames)), match, "sim", {}, {}).encode(),
                )
            counted.undeclare()
        finally:
            for process in services.values():
                process.terminate()
            codes = {name: p.wait(10) for name, p in services.items()}
    seats = 2 * args.matches
    answered = sum(answers.values())
    print(f"{args.matches} matches, {seats} agent seats, {play:.1f} s of play at {FPS} Hz")
    print(f"  answers: {answered} of {seats * frames} states ({answered / (seats * frames):.1%})")
    agent = spent["agent"] / play / seats
    print(f"  agent pool: {spent['agent']:.2f} CPU-s, {agent:.4f} CPU-s per second of play per seat "
          f"(goal < 0.008), {memory['agent']:.0f} MiB resident")  # fmt: skip
    if args.adaptive:
        adapter = spent["adapter"] / play / args.matches
        print(f"  adapter pool: {spent['adapter']:.2f} CPU-s, {adapter:.4f} CPU-s per second of play "
              f"per match, {memory['adapter']:.0f} MiB resident")  # fmt: skip
    print(f"  exit status on SIGTERM: {codes}")


if __name__ == "__main__":
    main()
