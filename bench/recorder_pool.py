"""The pool recorder's CPU per second of play per match (issue 33: the whole match's budget is
0.02 CPU-s/s for sim, agent, recorder and adapter together; the recorder's share should be well
under 0.006).

A real `tsf recorder --pool` process, a client of this process's router (as of a pool's sim), is
ordered `--matches` matches; this process then publishes each match's traffic in real time, as the
sim and the agents would (a real game's start, 30 states a second, both seats' actions for each,
its events, the summary), every message pre-encoded. Printed: the recorder's CPU seconds (user +
system, /proc) during play, per second of play per match, beside the same process's CPU while
idle for as long (its floor: zenoh's threads and the wake-ups of its waits), and whether every log
holds every message.

    nice -n 10 .venv/bin/python bench/recorder_pool.py [--matches 4] [--seconds 20]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zenoh
from proc import cpu_seconds

from services.agent.player import Player
from services.recorder.log import read_log
from services.recorder.service import MatchRecording
from services.runtime.launch import service_command
from services.sim.engine import Game
from services.sim.match import event_messages, start_message, state_message, summary_message
from shared import keys
from shared.bus import BusConfig, Drops, free_endpoint, session
from shared.game import FPS, ROLES, GameConfig
from shared.messages import MatchOrder

POOL = "bench"
POLICIES = {"bait": "circle", "shooter": "mirror"}


def frames_of(match: str, frames: int, seed: int) -> list[list[tuple[str, bytes]]]:
    """Each frame's messages of a real game, encoded, in the order the sim and agents send them;
    the start with frame 0's, the summary with the last."""
    game = Game(GameConfig(frames=frames), seed)
    players = {role: Player(role, POLICIES[role], seed) for role in ROLES}
    out, applied = (
        [[(keys.start(match), start_message(game, match, "sim", "realtime", POLICIES).encode())]],
        (0, 0),
    )
    while True:
        state = state_message(game, match, "sim", applied)
        out[-1].append((keys.state(match), state.encode()))
        out[-1] += [(keys.event(match), event.encode()) for event in event_messages(game, match, "sim")]
        if game.done:
            out[-1].append((keys.summary(match), summary_message(game, match, "sim", {}, {}).encode()))
            return out
        answers = [players[role].act(state, f"agent/{role}") for role in ROLES]
        out[-1] += [(keys.action(match, a.role), a.encode()) for a in answers]
        applied = tuple(a.action for a in answers)
        game.step(*applied)
        out.append([])


def wait_for(predicate, what: str, timeout: float = 60.0) -> None:  # noqa: ANN001 - a callable
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            sys.exit(f"bench: {what} not seen within {timeout:g} s")
        time.sleep(0.01)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--matches", type=int, default=4, help="matches recorded at once")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of each match")
    args = parser.parse_args()
    frames = round(args.seconds * FPS)
    matches = [f"m{i}" for i in range(args.matches)]
    traffic = [frames_of(m, frames, seed) for seed, m in enumerate(matches)]
    endpoint = free_endpoint()
    alive: set[str] = set()

    def on_alive(sample: zenoh.Sample) -> None:
        (alive.add if sample.kind == zenoh.SampleKind.PUT else alive.discard)(str(sample.key_expr))

    with (
        tempfile.TemporaryDirectory() as out,
        session(BusConfig("router", (endpoint,), low_latency=True)) as z,
    ):
        client = BusConfig("client", (), (endpoint,), low_latency=True, wait_router=60.0)
        command = service_command("recorder", client, "--pool", POOL, "--out", out)
        recorder = subprocess.Popen(command, stdin=subprocess.DEVNULL)
        try:
            z.liveliness().declare_subscriber("tsf/**", on_alive, history=True)
            wait_for(lambda: keys.pool_alive(POOL, "recorder") in alive, "the pool recorder's token")
            time.sleep(1.0)  # its start-up's last work done
            idle = cpu_seconds(recorder.pid)
            time.sleep(args.seconds)
            idle = cpu_seconds(recorder.pid) - idle
            names = {"bait": "circle", "shooter": "mirror"}
            for m in matches:
                z.put(
                    keys.pool_order(POOL), MatchOrder(match=m, frame=0, sender="bench", names=names).encode()
                )
            wait_for(lambda: all(keys.alive(m, "recorder") in alive for m in matches), "every match's token")
            before, t0 = cpu_seconds(recorder.pid), time.monotonic()
            for frame in range(frames + 1):
                time.sleep(max(0.0, t0 + frame / FPS - time.monotonic()))
                for messages in traffic:
                    for key, data in messages[frame]:
                        z.put(key, data)
            wait_for(
                lambda: not any(keys.alive(m, "recorder") in alive for m in matches), "every recording's end"
            )
            played = cpu_seconds(recorder.pid) - before
        finally:
            recorder.terminate()
            recorder.wait(10)
        complete = all(
            [(r.key, r.data) for r in read_log(Path(out) / f"{m}.tsflog")[0]] == [x for f in t for x in f]
            for m, t in zip(matches, traffic, strict=True)
        )
    messages = sum(len(f) for f in traffic[0])
    per = played / (args.seconds * args.matches)
    print(f"{args.matches} matches of {args.seconds:g} s, {messages / args.seconds:.0f} messages/s each:")
    print(
        f"  recorder CPU during play: {played:.2f} s = {per:.4f} CPU-s per s of play per match (goal < 0.006)"
    )
    print(f"  idle, as long: {idle:.2f} s (the floor, any number of matches)")
    print(f"  every log holds every message in order: {complete}")
    work = min(take_cpu(traffic[0]) for _ in range(5)) / args.seconds
    print(f"  of which validating and writing (in this process, best of 5): {work:.4f} CPU-s per s of play")


def take_cpu(frames: list[list[tuple[str, bytes]]]) -> float:
    """CPU seconds MatchRecording.take spends on a match's messages (no bus): the drain's work."""
    with tempfile.TemporaryDirectory() as out:
        recording = MatchRecording("m0", Path(out) / "m0.tsflog", Drops("bench"))
        t = time.process_time()
        for messages in frames:
            for key, data in messages:
                recording.take(key, data, 0)
        t = time.process_time() - t
        recording.close()
    return t


if __name__ == "__main__":
    main()
