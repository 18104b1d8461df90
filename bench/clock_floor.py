"""The scheduler's floor under a pool's clock: how late a bare 30-Hz clock ticks beside a given load.

The study server's capacity target (issue 49: every match's tick-jitter p99 at most 5 ms, as an
ordinary user) depends on how promptly Linux wakes the sim's clock while the machine's other work
runs. This bench takes our code out of it. A clock process plays `--matches` pretend matches on the
pool's grid (`--phases` phases of the 30-Hz period, each match's tick a busy `--tick-us` of CPU, a
phase's matches in one pass: services/sim/clock.py's shape), beside `--workers` load processes that
wake at random (Poisson) and each time spin for a while, so that together they keep a given share
of the machine's cores busy (`--load`, 0-1). Each match's tick jitter is what the sim reports
(|interval - period|, services/sim/service.py _timing); the bench prints, per load, the worst and
median match's p99 and the CPU the clock used.

Run it as the study runs, as an ordinary user (from root: `setpriv --bounding-set=-sys_nice
--inh-caps=-sys_nice .venv/bin/python bench/clock_floor.py`), on an otherwise quiet machine.
`--clock-slice-us` asks Linux for a time slice for the clock (sched_setattr, no privilege needed,
EEVDF: kernel 6.12 on) and `--load-nice`/`--load-batch` put the load below it, the levers an
ordinary user has.
"""

from __future__ import annotations

import argparse
import ctypes
import multiprocessing as mp
import os
import platform
import random
import statistics
import struct
import time

from services.sim.service import _timing
from shared.game import ROLES

PERIOD = 1 / 30
_SCHED_ATTR = struct.Struct("IIQiIQQQII")  # struct sched_attr (include/uapi/linux/sched/types.h)
_SETATTR = {"x86_64": 314, "aarch64": 274}


def _spin(seconds: float) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def _slice(slice_us: int) -> bool:
    """This thread's time slice (ns) for the ordinary class: sched_setattr's sched_runtime."""
    attr = _SCHED_ATTR.pack(
        _SCHED_ATTR.size,
        os.SCHED_OTHER,
        0,
        os.getpriority(os.PRIO_PROCESS, 0),
        0,
        slice_us * 1000,
        0,
        0,
        0,
        0,
    )
    libc = ctypes.CDLL(None, use_errno=True)
    return libc.syscall(_SETATTR[platform.machine()], 0, ctypes.create_string_buffer(attr), 0) == 0


def load(share: float, rate: float, seconds: float, nice: int, batch: bool, seed: int) -> None:
    """Spin `share` of one core in bursts that start at Poisson times, `rate` a second."""
    if nice:
        os.nice(nice)
    if batch:
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    rng = random.Random(seed)
    burst = share / rate
    end = time.monotonic() + seconds
    due = time.monotonic()
    while (now := time.monotonic()) < end:
        due += rng.expovariate(rate)
        if due > now:
            time.sleep(due - now)
        _spin(burst)


def clock(matches: int, phases: int, tick_us: float, seconds: float, slice_us: int, out: mp.Queue) -> None:
    """Play `matches` pretend matches on `phases` phases of the period; send each one's tick times."""
    sliced = _slice(slice_us) if slice_us else False
    ticks: list[list[float]] = [[] for _ in range(matches)]
    start = time.monotonic() + 0.2
    cpu = time.process_time()
    for n in range(int(seconds / PERIOD)):
        for phase in range(phases):
            due = start + (n + phase / phases) * PERIOD
            if (wait := due - time.monotonic()) > 0:
                time.sleep(wait)
            for match in range(phase, matches, phases):
                ticks[match].append(time.monotonic())
                _spin(tick_us * 1e-6)
    out.put((ticks, time.process_time() - cpu, sliced))


def p99(ticks: list[float]) -> float:
    """A match's tick-jitter p99 (ms), as the sim computes it for its summary."""
    return _timing({role: [] for role in ROLES}, ticks, PERIOD)["tick_jitter_ms_p99"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--load", type=float, nargs="+", default=[0.0, 0.5, 0.65, 0.8, 0.9])
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--matches", type=int, default=24)
    parser.add_argument("--phases", type=int, default=4)
    parser.add_argument("--tick-us", type=float, default=300.0, help="CPU of one match's tick")
    parser.add_argument("--workers", type=int, default=6)
    parser.add_argument("--rate", type=float, default=240.0, help="bursts a second per worker")
    parser.add_argument("--clock-slice-us", type=int, default=0)
    parser.add_argument("--load-nice", type=int, default=0)
    parser.add_argument("--load-batch", action="store_true")
    args = parser.parse_args()
    cores = os.cpu_count() or 1
    print(
        f"{cores} cores; clock: {args.matches} matches in {args.phases} phases, "
        f"{args.tick_us:.0f} us a tick; "
        f"load: {args.workers} workers, {args.rate:.0f} bursts/s each, nice +{args.load_nice}"
        f"{', batch' if args.load_batch else ''}; clock slice {args.clock_slice_us or 'default'} us"
    )
    print("load  clock CPU  worst p99 ms  median p99 ms  matches over 5 ms")
    for share in args.load:
        out: mp.Queue = mp.Queue()
        each = share * cores / args.workers
        workers = (
            [
                mp.Process(
                    target=load,
                    args=(each, args.rate, args.seconds + 0.5, args.load_nice, args.load_batch, seed),
                )
                for seed in range(args.workers)
            ]
            if share > 0
            else []
        )
        for worker in workers:
            worker.start()
        ticker = mp.Process(
            target=clock,
            args=(args.matches, args.phases, args.tick_us, args.seconds, args.clock_slice_us, out),
        )
        ticker.start()
        ticks, cpu, sliced = out.get()
        if args.clock_slice_us and not sliced:
            raise SystemExit(f"--clock-slice-us {args.clock_slice_us}: Linux refused the time slice")
        ticker.join()
        for worker in workers:
            worker.join()
        jitter = sorted(p99(t) for t in ticks)
        over = sum(j > 5 for j in jitter)
        print(
            f"{share:4.2f}  {cpu / args.seconds:9.2f}  {jitter[-1]:12.1f}  "
            f"{statistics.median(jitter):13.1f}  {over:3d} of {len(jitter)}"
        )


if __name__ == "__main__":
    main()
