"""`tsf eval` speed: the wall time of the default evaluation (`tsf eval --role shooter --seeds 8
--identify-seeds 3`: identification, team games of every partner of the population with every
agent, the figures), run as the command, with 2 worker processes. Goal: <= 4 minutes (it took 36
minutes when each game was played on its own).

    .venv/bin/python bench/eval.py [--workers 2] [--partners N] [--out DIR]

With --partners N only every k-th partner of the population plays its team games (N of them, across
the groups), and the whole population's time is extrapolated: identification and figures as
measured, team games scaled by the number of partners. Run alone: other load skews the figure.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time

from services.adapter.partners import population


def tsf_eval(workers: int, out: str, *options: str) -> float:
    """Seconds of one `tsf eval` run with these options."""
    command = [sys.executable, "-m", "services.cli", "eval", "--role", "shooter", "--seeds", "8"]
    command += ["--identify-seeds", "3", "--workers", str(workers), "--out", out, *options]
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--partners", type=int, default=0, help="team games of N partners only (0: all)")
    parser.add_argument("--out", default=None, help="keep the results here (default: a temporary directory)")
    args = parser.parse_args()
    everyone = [p for group in population("bait").values() for p in group]
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or tmp
        if not args.partners or args.partners >= len(everyone):
            wall = tsf_eval(args.workers, out)
            print(
                f"tsf eval, default population ({len(everyone)} partners), {args.workers} workers:", end=" "
            )
            print(f"{wall:.0f} s ({wall / 60:.1f} min; goal <= 4 min)")
            return
        chosen = everyone[:: -(-len(everyone) // args.partners)]
        ident = tsf_eval(args.workers, f"{out}/identification", "--no-performance")
        team = tsf_eval(args.workers, f"{out}/team", "--no-identify", *(f"--partner={p}" for p in chosen))
        whole = ident + team * len(everyone) / len(chosen)
        print(
            f"identification and figures: {ident:.0f} s; team games of {len(chosen)} partners: {team:.0f} s"
        )
        print(
            f"tsf eval, default population ({len(everyone)} partners), {args.workers} workers, "
            f"extrapolated: {whole:.0f} s ({whole / 60:.1f} min; goal <= 4 min)"
        )


if __name__ == "__main__":
    main()
