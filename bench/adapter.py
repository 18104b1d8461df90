"""The adapter's per-frame cost with the full library at T = 800 (goal: <= 1 ms per frame).

(a) In-process: one frame's scoring (every library policy of the partner's role, or every member
of the grown library's partner groups: `groups`) and update, for each adaptive seat and strategy,
over the frames of a recorded game: mean, p50 and p99 (a -skill strategy in the shooter seat at
T = 400, where its model was measured; its frames every second read the window's keys).
(b) As a service under a real-time match: the adapter service (in this process) adapts the
shooter while a sim and two agents run as processes at 30 Hz, as the study library's cem agent and
as the grown library's default; the same per-frame cost as measured inside the service, and how
many frames it scored.

    .venv/bin/python bench/adapter.py [--frames 900]
"""

from __future__ import annotations

import argparse
import threading
import time

import numpy as np

from services.adapter.service import build, run_adapter
from services.evaluation.evaluate import play_games
from services.population.adaptive import STRATEGIES, AdapterConfig
from services.population.seat import seats_of
from services.runtime.launch import service_command
from shared.bus import BusConfig, free_endpoint
from shared.game import FPS
from shared.processes import Processes

WINDOW = 800
GROUPS = ("cem", "bayes-dwell-ood-guard")  # measured with the grown library's partner groups too


def in_process(role: str, strategy: str, frames: int, partners: str = "library") -> np.ndarray:
    """Seconds per frame of scoring + update for a partner's recorded game."""
    partner = "B5" if role == "shooter" else "S5"
    teammate = "S5" if role == "shooter" else "B5"
    stream = play_games([(*seats_of([partner, teammate]), 0)], role, record=True)[0]
    window = AdapterConfig.window if "skill" in strategy else WINDOW  # the skill model's T
    adapter, scorer = build(AdapterConfig(role, window, strategy, partners=partners))
    costs = []
    for values, action in list(zip(stream.values, stream.actions, strict=True))[:frames]:
        began = time.perf_counter()
        adapter.update(scorer(values, action), values, action)
        costs.append(time.perf_counter() - began)
    return np.array(costs)


def as_service(frames: int, config: AdapterConfig) -> tuple[np.ndarray, float]:
    """Per-frame costs inside the adapter service during a real-time match, and the match's seconds."""
    match, endpoint = "bench-adapter", free_endpoint()
    costs: list[float] = []
    stop = threading.Event()
    thread = threading.Thread(
        target=run_adapter,
        args=(BusConfig(connect=(endpoint,)), match, config, stop),
        kwargs={"costs": costs},
    )
    began = time.monotonic()
    with Processes() as processes:
        sim = service_command("sim", BusConfig(listen=(endpoint,)), "--match", match, "--frames", str(frames),
                              "--wait-adapter", "20")  # fmt: skip
        processes.start("sim", sim)
        thread.start()
        for role, policy in (("bait", "B5"), ("shooter", "S5")):
            agent = service_command("agent", BusConfig(connect=(endpoint,)), "--match", match, "--role", role,
                                    "--policy", policy)  # fmt: skip
            processes.start(role, agent)
        processes.wait("sim", frames / FPS + 60)
    stop.set()
    thread.join()
    return np.array(costs), time.monotonic() - began


def line(label: str, costs: np.ndarray) -> str:
    ms = costs * 1e3
    return (
        f"{label:38s} mean {ms.mean():.3f} ms  p50 {np.percentile(ms, 50):.3f} ms  "
        f"p99 {np.percentile(ms, 99):.3f} ms  ({len(ms)} frames)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=900, help="frames of the real-time match")
    args = parser.parse_args()
    print(f"adapter per-frame cost, full library, T = {WINDOW} (goal <= 1 ms)")
    for role in ("shooter", "bait"):
        for strategy in STRATEGIES:
            if "skill" in strategy and role != "shooter":
                continue  # a skill model is shipped for the shooter seat only
            print(line(f"in-process, {role} seat, {strategy}", in_process(role, strategy, 1800)))
        for strategy in GROUPS:
            costs = in_process(role, strategy, 1800, "groups")
            print(line(f"in-process, {role} seat, {strategy}, groups", costs))
    for config in (AdapterConfig("shooter", WINDOW, "cem"), AdapterConfig(window=WINDOW, partners="groups")):
        costs, seconds = as_service(args.frames, config)
        print(line(f"service, real-time match, shooter, {config.strategy}, {config.partners}", costs))
        print(f"  the match: {args.frames} frames at 30 Hz in {seconds:.1f} s (with start-up)")


if __name__ == "__main__":
    main()
