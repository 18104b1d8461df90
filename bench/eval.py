"""`tsf eval` speed: the wall time of the default evaluation (`tsf eval --role shooter --seeds 8
--identify-seeds 3`: identification, team games of every partner of the population with every
agent, the figures), run in-process as the command runs it (`evaluate`, then the report written)
on the job system's local workers, for each number of workers asked (default 1 and 2: the
speed-up of a second worker). Goal: <= 4 minutes with 2 workers (it took 36 minutes when each
game was played on its own); 2 workers >= 1.8x one.

    .venv/bin/python bench/eval.py [--workers 1,2] [--partners N] [--out DIR]

With --partners N only every k-th partner of the population plays its team games (N of them, across
the groups), and the whole population's time is extrapolated: identification and figures as
measured, team games scaled by the number of partners. Run alone: other load skews the figure.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time
from pathlib import Path

from services.evaluation.evaluation import KINDS, EvalPlan, evaluate
from services.jobs.engine import on_workers, open_engine
from shared.bus import BusConfig


def seconds(plan: EvalPlan, workers: int, out: Path) -> float:
    """Seconds of one evaluation and its report (a fresh output: no journal to resume)."""
    start = time.perf_counter()
    with open_engine(BusConfig(), "eval", out / "eval.journal", KINDS, workers) as engine:
        evaluate(plan, on_workers(engine)).write(out)
    return time.perf_counter() - start


def whole_eval(plan: EvalPlan, workers: int, out: Path, partners: int) -> float:
    """Seconds of `plan` with `workers`, measured or extrapolated from `partners` of its partners."""
    everyone = plan.partners
    if not partners or partners >= len(everyone):
        return seconds(plan, workers, out)
    chosen = everyone[:: -(-len(everyone) // partners)]
    ident = seconds(dataclasses.replace(plan, performance=False), workers, out / "identification")
    some = dataclasses.replace(plan.population, partners=chosen)
    team = seconds(dataclasses.replace(plan, population=some, identify=False), workers, out / "team")
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
    plan = EvalPlan("shooter", seeds=8, identify_seeds=3, variants=True)  # the shipped docs/eval's options
    walls = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in (int(w) for w in args.workers.split(",")):
            walls[n] = whole_eval(plan, n, Path(args.out or tmp) / f"{n}workers", args.partners)
            how = "extrapolated" if args.partners else "measured"
            print(
                f"tsf eval, default population, {n} workers, {how}: "
                f"{walls[n]:.0f} s ({walls[n] / 60:.1f} min)"
            )
    if 1 in walls and 2 in walls:
        print(f"speed-up of 2 workers over 1: {walls[1] / walls[2]:.2f}x")


if __name__ == "__main__":
    main()
