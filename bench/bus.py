"""Bus latency and throughput with every service up as its own process (sim, 2 agents, recorder).

Real time: the state -> action -> sim round trip (median, p99; goal p99 <= 2 ms) and the sim's
tick-period jitter (p99 deviation from 33.3 ms; goal <= 2 ms). Lockstep: frames per second.

    .venv/bin/python bench/bus.py [--seconds 20] [--lockstep-frames 1800]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from services.recorder.recording import load
from services.runtime.launch import MatchPlan, run_match
from shared.game import FPS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="length of the real-time match")
    parser.add_argument("--lockstep-frames", type=int, default=1800)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        plan = MatchPlan("bench-rt", frames=round(args.seconds * FPS), directory=Path(directory))
        summary, _ = run_match(plan)
        t = summary.timing
        print(f"real time, {summary.frame} frames:")
        print(
            f"  round trip state->action->sim: median {t['round_trip_ms_p50']:.2f} ms, "
            f"p99 {t['round_trip_ms_p99']:.2f} ms (goal p99 <= 2)"
        )
        print(
            f"  tick period jitter: median {t['tick_jitter_ms_p50']:.2f} ms, "
            f"p99 {t['tick_jitter_ms_p99']:.2f} ms (goal p99 <= 2)"
        )
        plan = MatchPlan("bench-ls", frames=args.lockstep_frames, mode="lockstep", directory=Path(directory))
        _, path = run_match(plan)
        sent = [state.sent_ns for state in load(path).states]
        rate = (len(sent) - 1) / ((sent[-1] - sent[0]) / 1e9)
        print(f"lockstep: {rate:,.0f} frames/s over {len(sent) - 1} frames (first to last state)")


if __name__ == "__main__":
    main()
