"""`tsf eval` speed: the wall time of the default evaluation (`tsf eval --role shooter --seeds 8
--identify-seeds 3`: identification, team games of every partner of the population with every
agent, the figures), run as the command on the job system's local workers, for each number of
workers asked (default 1 and 2: the speed-up of a second worker). Goal: <= 4 minutes with 2
workers (it took 36 minutes when each game was played on its own); 2 workers >= 1.8x one.

    .venv/bin/python bench/eval.py [--workers 1,2] [--partners N] [--out DIR]

With --partners N only every k-th partner of the population plays its team games (N of them, across
the groups), and the whole population's time is extrapolated: identification and figures as
measured, team games scaled by the number of partners. Run alone: other load skews the figure.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

from services.adapter.partners import population


def tsf_eval(workers: int, out: str, *options: str) -> float:
    """Seconds of one `tsf eval` run with these options (a fresh output: no journal to resume)."""
    command = [sys.executable, "-m", "services.cli", "eval", "--role", "shooter", "--seeds", "8"]
    command += ["--identify-seeds", "3", "--workers", str(workers), "--out", out, *options]
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def whole_eval(workers: int, out: str, partners: int) -> float:
    """Seconds of the default evaluation with `workers`, measured or extrapolated from `partners`."""
    everyone = [p for group in population("bait").values() for p in group]
    if not partners or partners >= len(everyone):
        return tsf_eval(workers, out)
    chosen = everyone[:: -(-len(everyone) // partners)]
    ident = tsf_eval(workers, f"{out}/identification", "--no-performance")
    team = tsf_eval(workers, f"{out}/team", "--no-identify", *(f"--partner={p}" for p in chosen))
    print(
        f"  {workers} workers: identification and figures {ident:.0f} s; "
        f"team games of {len(chosen)} partners {team:.0f} s"
    )
    return ident + team * len(everyone) / len(chosen)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", default="1,2", help="numbers of local workers, comma-separated")
    parser.add_argument("--partners", type=int, default=0, help="team games of N partners only (0: all)")
    parser.add_argument("--out", default=None, help="keep the results here (default: a temporary directory)")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    walls = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in (int(w) for w in args.workers.split(",")):
            walls[n] = whole_eval(n, f"{args.out or tmp}/{n}workers", args.partners)
            how = "extrapolated" if args.partners else "measured"
            print(
                f"tsf eval, default population, {n} workers, {how}: "
                f"{walls[n]:.0f} s ({walls[n] / 60:.1f} min)"
            )
    if 1 in walls and 2 in walls:
        print(f"speed-up of 2 workers over 1: {walls[1] / walls[2]:.2f}x")


if __name__ == "__main__":
    main()
