"""The wall time of the whole `tsf library grow` pipeline on this machine, stage by stage (goal:
under 4 hours on 2 cores).

It runs the pipeline (resuming whatever OUT already holds: a run may span sessions, and each
session's seconds add up in OUT/timing.json) and prints each stage's wall seconds and the total.

    .venv/bin/python bench/grow.py [--out tsf-grown] [--workers 2] [--population FILE]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

GOAL = 4 * 3600


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("tsf-grown"))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--population", type=Path)
    args = parser.parse_args()
    command = [sys.executable, "-m", "services.commands", "library", "grow", "--out", str(args.out)]
    command += ["--workers", str(args.workers)]
    command += ["--population", str(args.population)] if args.population else []
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    timing = json.loads((args.out / "timing.json").read_text())
    for stage, seconds in timing.items():
        print(f"{stage:>12}: {seconds / 60:6.1f} min")
    total = sum(timing.values())
    verdict = "meets" if total < GOAL else "misses"
    line = f"{total / 60:6.1f} min with {args.workers} workers ({verdict} the goal of {GOAL // 3600} h)"
    print(f"{'total':>12}: {line}")


if __name__ == "__main__":
    main()
