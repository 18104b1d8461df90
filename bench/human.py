"""A person's seat through the human gateway, against an agent's seat, in one real-time match.

A WebSocket client stands in for the browser (it holds keys and reads every frame). Measured: the
sim's round trip over both seats; per seat, from the recording, the recorder's receive time of
each action minus the state's send time (both on this machine's clock; the recorder runs at low
CPU priority, so its tail shows the machine's load as much as the seat's); and how many of the
match's frames reached the client.

    .venv/bin/python bench/human.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import websockets

from services.human.play import play_with_people
from services.recorder.recording import load
from services.runtime.launch import MatchPlan
from shared.game import FPS, HUMAN


async def browser(link: str) -> int:
    """Join, start, hold thrust and count the frames received until the match's end."""
    query = parse_qs(urlsplit(link).query)
    frames = 0
    async with websockets.connect(f"ws://{urlsplit(link).netloc}/ws") as ws:
        await ws.send(json.dumps({"type": "join", "role": "bait", "token": query["token"][0]}))
        keys = {"left": False, "right": False, "thrust": True, "fire": False}
        await ws.send(json.dumps({"type": "keys", **keys}))
        await ws.send(json.dumps({"type": "ready"}))
        while (message := json.loads(await ws.recv()))["type"] != "end":
            frames += message["type"] == "state"
    return frames


def answer_ms(recording, role: str) -> list[float]:  # noqa: ANN001 - a Recording
    sent = {state.frame: state.sent_ns for state in recording.states}
    return [(t - sent[a.frame]) / 1e6 for t, a in recording.actions if a.role == role and a.frame in sent]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="length of the match")
    args = parser.parse_args()
    frames = round(args.seconds * FPS)
    links: list[dict[str, str]] = []
    ready = threading.Event()
    with tempfile.TemporaryDirectory() as directory, ThreadPoolExecutor(1) as pool:
        plan = MatchPlan("bench-human", frames=frames, bait=HUMAN, shooter="S5", directory=Path(directory))
        running = pool.submit(
            play_with_people, plan, port=0, on_links=lambda urls: (links.append(urls), ready.set())
        )
        ready.wait(30)
        received = asyncio.run(browser(links[0]["bait"]))
        summary, path = running.result(60)
        recording = load(path)
        print(f"real time, {summary.frame} frames; the client received {received} frames")
        t = summary.timing
        print(
            f"  both seats, as the sim measures (state -> action -> sim): median "
            f"{t['round_trip_ms_p50']:.2f} ms, p99 {t['round_trip_ms_p99']:.2f} ms"
        )
        for role, who in (("bait", "person via the gateway"), ("shooter", "agent S5")):
            times = answer_ms(recording, role)
            p99 = statistics.quantiles(times, n=100)[98]
            print(
                f"  {role} ({who}): state sent -> action at the recorder: median "
                f"{statistics.median(times):.2f} ms, p99 {p99:.2f} ms over {len(times)} actions"
            )


if __name__ == "__main__":
    main()
