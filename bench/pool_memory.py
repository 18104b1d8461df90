"""A pool's memory over many matches in a row: the resident memory of each of a real pool's service
processes (sim, agent, recorder) after each match, and its growth per match after a warm-up. A pool
runs for hours (a study server's), so what it keeps of an ended match adds up.

The bench starts a `Pool` (services/runtime/pool.py) and has it play `--matches` short matches one
after another, both seats library policies (B3, S5), as a study's launcher would (Pool.run: each
recorded and checked complete; a failed match is counted, not fatal). Printed: each service's RSS
after the warm-up and at the end, and its growth per match (least-squares slope of RSS over the
matches after the warm-up), in KiB.

    nice -n 10 .venv/bin/python bench/pool_memory.py [--matches 300] [--warmup 30] [--frames 30]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from proc import rss_kib

from services.population.seat import PolicySeat
from services.runtime.launch import MatchPlan
from services.runtime.pool import Pool
from shared.errors import Failure

SERVICES = ("sim", "agent", "recorder")


def slope(ys: list[int]) -> float:
    """Least-squares growth per step of `ys` (one value per match)."""
    n = len(ys)
    mean_x, mean_y = (n - 1) / 2, sum(ys) / n
    num = sum((x - mean_x) * (y - mean_y) for x, y in enumerate(ys))
    return num / sum((x - mean_x) ** 2 for x in range(n))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--matches", type=int, default=300, help="played in a row, after the warm-up")
    parser.add_argument("--warmup", type=int, default=30, help="matches played first, not counted")
    parser.add_argument("--frames", type=int, default=30, help="of each match (30 a second)")
    parser.add_argument("--every", type=int, default=50, help="print the RSS every this many matches")
    args = parser.parse_args()
    with (
        tempfile.TemporaryDirectory(prefix="tsf-pool-memory-") as out,
        Pool("memory", Path(out), adaptive=False) as pool,
    ):
        pids = {name: pool.processes.children[name].pid for name in SERVICES}
        rss: dict[str, list[int]] = {name: [] for name in SERVICES}
        failures: list[str] = []
        began = time.monotonic()
        for i in range(args.warmup + args.matches):
            plan = MatchPlan(
                match=f"mem-{i}", seed=i, frames=args.frames, directory=Path(out),
                bait=PolicySeat("B3"), shooter=PolicySeat("S5"),
            )  # fmt: skip
            try:
                pool.run(plan)
            except Failure as error:  # counted: the memory is what is measured
                failures.append(str(error))
            Path(out, f"mem-{i}.tsflog").unlink(missing_ok=True)
            if i < args.warmup:
                continue
            for name, pid in pids.items():
                rss[name].append(rss_kib(pid))
            n = i + 1 - args.warmup
            if n % args.every == 0:
                now = ", ".join(f"{name} {rss[name][-1] / 1024:.1f}" for name in SERVICES)
                print(f"  after {n} matches ({time.monotonic() - began:.0f} s): RSS MiB {now}", flush=True)
        restarts = sum(pool.restarts.values())
    print(f"{args.matches} matches of {args.frames} frames in a row after {args.warmup} of warm-up, "
          f"{restarts} restarts, {len(failures)} failed")  # fmt: skip
    for failure in sorted(set(failures))[:5]:
        print(f"  failed: {failure}")
    for name in SERVICES:
        first, last = rss[name][0], rss[name][-1]
        print(f"  {name}: RSS {first / 1024:.1f} -> {last / 1024:.1f} MiB, "
              f"{slope(rss[name]):+.1f} KiB per match")  # fmt: skip


if __name__ == "__main__":
    main()
