"""How many participants one machine serves at once, how fast their games start, and what a crowd
arriving at random gets.

Stand-ins (services/study/standin.py) take part in a study served here (`run_study`), over the
page's WebSocket protocol, each playing `--trials` trials of `--trial-seconds`.

Load: for each count of participants, all arrive together with a match for each, in a study of the
shipped config's five variants (services/study/configs/static.toml; `--adaptive`: adaptive.toml,
three adaptive variants and two static ones), `--trials` trials of each; reported are the trials
done of all (done = the recording read back complete), the worst and median tick jitter p99 of the
matches' sims and how many are over 5 ms, Ready-to-first-frame p50/p99 over all trials, the waits
before the offers (consent to the first, each trial's end to the next), the load average, and what
one participant costs: CPU seconds of the server's pool (its sim, agent, recorder and adapter
processes) per second of play, from the moment the pool is up to the last trial's end (the
server's judge, its worker process that reads each recording back, printed beside it: the server's
work, as its bridges of the people's seats are), and the pool's resident memory (peak over the
run) divided by the participants (the judge's printed apart: once per server). The server's own
CPU (this process less its main thread, where the stand-ins play, and the sampler) is counted
with them. The pool's own start-up (once per server) is printed apart. Everyone is admitted at
once (the arrival limits are lifted). The most participants served is the largest count with
every trial done, every match's tick jitter p99 <= 5 ms and the agent's round trip p99 (state to
action, at the sim) <= 33 ms; `--max-lag` sets the server's admission hold (Serving.max_lag).
After each count, bench/bus_floor.py's floor is played at as many matches (`--floor-seconds`, 0:
none), and a participant's cost is printed as a multiple of it: the bus's cost moves with the hour,
the ratio does not.

Arrivals (`--arrivals N --over S`): N participants arrive at random times over S seconds with at
most `--max-matches` matches at once: completed (goal N), lost (goal 0) and the queue wait
p50/p99 of the trials that waited.

Across machines (`--second-host netns`, as root): the same arrivals twice, first on this machine's
`--max-matches` slots alone, then with a second match host (`tsf match-host`, as many slots) in a
Linux network namespace of its own, reached over a veth pair: the study server is the router, at
10.199.0.1, and the host connects to it from 10.199.0.2 (its matches' processes talk over the
namespace's own loopback). `--second-host process` runs it as a plain process on loopback (no
root needed). Both hosts share this machine's CPUs: the figure shows the slots adding up and the
protocol's cost, not a second machine's CPU.

    nice .venv/bin/python bench/study.py [--counts 1 4 8 12] [--trial-seconds 10] [--trials 1] [--adaptive]

As an ordinary user runs it (the sim cannot raise its priority, nor enter the real-time class), from
root: `setpriv --bounding-set=-sys_nice --inh-caps=-sys_nice .venv/bin/python bench/study.py ...`
(CAP_SYS_NICE dropped for it and its children).
    nice .venv/bin/python bench/study.py --arrivals 20 --over 120 --trial-seconds 5 --max-matches 4
    nice .venv/bin/python bench/study.py --arrivals 16 --over 60 --trial-seconds 5 --max-matches 2 \
        --second-host netns
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import os
import random
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from bus_floor import floor

from services.human.gateway import Web
from services.recorder.recording import load
from services.study.core import StudyConfig, Variant
from services.study.runner import run_study
from services.study.serving import Serving
from services.study.standin import StandInReport, stand_in
from shared.bus import BusConfig, free_endpoint
from shared.game import other

TOKEN = "bench"
HOST_SECRET = b"the-bench-host-secret"  # shared by the server and its match host
JITTER_MS = 5.0
TRIP_MS = 33.0  # the agent's round trip p99, state -> action at the sim: within a frame
JUDGE = "judge"
# Every stand-in comes from this machine's one address, as every person does behind a reverse
# proxy: the servers below take arrivals from one address without its own limit (arrivals_per_address=0).
CONFIGS = Path(__file__).resolve().parent.parent / "services" / "study" / "configs"


def quantile(values: list[float], q: int) -> float:
    return statistics.quantiles(values, n=100, method="inclusive")[q - 1] if len(values) > 1 else values[0]


class Children:
    """Samples the resident memory and CPU time of this process's children (the study server's
    pool, and its judge) five times a second: the peak memory of each, and the CPU time they have
    used so far."""

    def __init__(self) -> None:
        self.cpu, self.stop, self.sampled = dict[int, float](), threading.Event(), 0.0
        self.peak = {"pool": 0, JUDGE: 0}  # bytes, the most resident at once
        self.service: dict[int, str] = {}  # pid -> the pool service it runs, or the judge
        self.page, self.tick = os.sysconf("SC_PAGE_SIZE"), os.sysconf("SC_CLK_TCK")
        self.thread = threading.Thread(target=self._sample, daemon=True)
        self.thread.start()

    def own(self) -> float:
        """CPU seconds of the sampling thread itself (not the server's)."""
        return self.sampled

    def used(self) -> dict[str, float]:
        """CPU seconds used so far by each pool service and the judge (an ended process: until its
        last sample)."""
        used: dict[str, float] = {}
        for pid, seconds in self.cpu.items():
            used[self.service[pid]] = used.get(self.service[pid], 0.0) + seconds
        return used

    def _sample(self) -> None:
        while not self.stop.wait(0.2):
            self.sampled = time.thread_time()
            total = {"pool": 0, JUDGE: 0}
            for stat in Path("/proc").glob("[0-9]*/stat"):
                try:
                    fields = stat.read_text().rsplit(")", 1)[1].split()
                    if int(fields[1]) != os.getpid():
                        continue
                    pid = int(stat.parent.name)
                    if pid not in self.service:
                        self.service[pid] = _service((stat.parent / "cmdline").read_bytes().split(b"\0"))
                    rss = int((stat.parent / "statm").read_text().split()[1]) * self.page
                    total[JUDGE if self.service[pid] == JUDGE else "pool"] += rss
                    self.cpu[pid] = (int(fields[11]) + int(fields[12])) / self.tick
                except (OSError, IndexError, ValueError):
                    continue
            self.peak = {part: max(self.peak[part], total[part]) for part in total}


def _service(words: list[bytes]) -> str:
    """What a child of the server runs: a pool service (`tsf sim --pool`...), or the judge (its
    worker process, services/study/judge.py; multiprocessing's resource tracker counted with it)."""
    return words[words.index(b"services.commands") + 1].decode() if b"services.commands" in words else JUDGE


def serve(
    config: StudyConfig, serving: Serving, arrivals: list[float], on_up: Callable[[], None] = lambda: None
) -> tuple[list[StandInReport], list, list, list]:
    """Run the study with one stand-in arriving at each of `arrivals` (seconds from now, once the
    server is up: `on_up`): their reports, every attempt, and the tick jitter p99 and the agent's
    round trip p99 (state -> action at the sim, ms) of each match done."""
    stop, urls = threading.Event(), []
    with tempfile.TemporaryDirectory() as directory, ThreadPoolExecutor(1) as pool:
        server = pool.submit(
            run_study, config, directory, Web(port=0, per_address=0), stop, urls.append, serving
        )
        while not urls:
            if server.done():
                server.result()
            time.sleep(0.01)
        url = urls[0].url
        on_up()

        async def arrive(at: float, seed: int) -> StandInReport:
            await asyncio.sleep(at)
            return await stand_in(url, seed=seed, test=TOKEN)

        async def crowd() -> list[StandInReport]:
            return await asyncio.gather(*(arrive(at, i) for i, at in enumerate(arrivals)))

        try:
            reports = asyncio.run(crowd())
        finally:
            on_up()  # the end of play
            stop.set()
        study = server.result()
        attempts = [(a, p.role) for p in study.participants.values() for a in p.attempts]
        timings = [
            (load(Path(directory) / "recordings" / f"{a['match']}.tsflog").summary.timing, role)
            for a, role in attempts
            if a["status"] == "done"
        ]
    jitters = [timing.get("tick_jitter_ms_p99", 0.0) for timing, _ in timings]
    trips = [timing.get(f"round_trip_{other(role)}_ms_p99", float("nan")) for timing, role in timings]
    return reports, [a for a, _ in attempts], jitters, trips


def spread(values: list[float]) -> str:
    return f"p50 {quantile(values, 50):.1f} s, p99 {quantile(values, 99):.1f} s" if values else "none"


def cpu_of_this_process() -> tuple[float, float]:
    """CPU seconds of this whole process, and of its main thread (where the stand-ins play)."""
    return time.process_time(), time.thread_time()


def load_test(
    counts: list[int],
    trials: int,
    seconds: float,
    adaptive: bool = False,
    max_lag: float = Serving.max_lag,
    floor_seconds: float = 10.0,
) -> None:
    shipped = StudyConfig.load(CONFIGS / ("adaptive.toml" if adaptive else "static.toml"))
    config = dataclasses.replace(shipped, trials=trials, trial_seconds=seconds, practice_seconds=0.0)
    served, each = 0, trials * len(config.variants)
    print(
        f"load: everyone arrives at once, a match for each; {shipped.name}.toml's {len(config.variants)} "
        f"variants, {trials} trial(s) of {seconds:g} s with each ({each} trials a participant)"
    )
    for count in counts:
        load = os.getloadavg()[0]
        children, marks = Children(), []
        began = time.monotonic()
        # Everyone admitted at once (ids at any rate: the limits are for a crowd, not for the bench)
        serving = Serving(
            max_matches=count, test_token=TOKEN, arrivals=1e6, arrivals_per_address=0.0, max_lag=max_lag
        )

        def mark(marks: list = marks, children: Children = children) -> None:
            marks.append((time.monotonic(), children.used(), cpu_of_this_process(), children.own()))

        reports, attempts, jitters, trips = serve(config, serving, [0.0] * count, mark)
        children.stop.set()
        (up, at_up, (process_up, main_up), own_up), (_, at_end, (process_end, main_end), own_end) = marks
        played = count * each * seconds
        cost = {name: (at_end[name] - at_up.get(name, 0.0)) / played for name in at_end}
        judging = cost.pop(JUDGE, 0.0)  # the server's work, as its bridges are: not the pool's
        # The server: this process less the stand-ins (its main thread) and the sampler of the children
        server = ((process_end - process_up) - (main_end - main_up) - (own_end - own_up)) / played
        done = sum(a["status"] == "done" for a in attempts)
        first = [f for r in reports for f in r.first_frames]
        jitter, trip = max(jitters, default=float("nan")), max(trips, default=float("nan"))
        complete = done == count * each and all(r.done for r in reports)
        if complete and jitter <= JITTER_MS and trip <= TRIP_MS:
            served = max(served, count)
        print(
            f"  {count:3d} participants: trials done {done}/{count * each} ({len(attempts)} attempts); "
            f"tick jitter p99 worst {jitter:.1f} ms, median {statistics.median(jitters or [jitter]):.1f} ms, "
            f"{sum(j > JITTER_MS for j in jitters)} matches over {JITTER_MS:g} ms; agent round trip p99 "
            f"worst {trip:.1f} ms, {sum(t > TRIP_MS for t in trips)} over {TRIP_MS:g} ms; "
            f"Ready-to-first-frame p50 {quantile(first, 50):.3f} s, p99 {quantile(first, 99):.3f} s"
        )
        print(
            f"       consent to first offer {spread([r.offers[0] for r in reports if r.offers])}; "
            f"trial end to next offer {spread([o for r in reports for o in r.offers[1:]])}; "
            f"load average {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end"
        )
        pool, judge = (children.peak[part] / 2**20 for part in ("pool", JUDGE))
        total = sum(cost.values()) + judging + server
        print(
            f"       per participant {total:.4f} CPU s per s of play, the server's included: the pool "
            f"{sum(cost.values()):.4f} ({', '.join(f'{name} {value:.4f}' for name, value in cost.items())}), "
            f"the server {server:.4f} and its judge {judging:.4f} (so {2 / total:.0f} per 2 cores at most); "
            f"{pool / count:.1f} MiB (the pool {pool:.0f} MiB at its peak, the judge {judge:.0f} MiB apart; "
            f"its start-up {up - began:.1f} s, {sum(at_up.values()):.1f} CPU s, once per server)"
        )
        if floor_seconds > 0:
            print(beside_the_floor(count, floor_seconds, sum(cost.values()), total))
    print(
        f"the largest count served with every trial done, tick jitter p99 <= {JITTER_MS:g} ms and the "
        f"agent's round trip p99 <= {TRIP_MS:g} ms: {served} (held above {max_lag * 1e3:g} ms of lag)"
    )


def beside_the_floor(count: int, seconds: float, pool: float, total: float) -> str:
    """bench/bus_floor.py's floor at `count` matches, played right after the load test, and what a
    participant costs as a multiple of it: of the pool (its processes against the floor's router,
    agent and recorder) and in all (the server's against the floor's participant too). The bus's
    cost moves with the hour (docs/architecture.md: 0.0099 and 0.0187 an hour apart); the ratio
    reads the same in a slow hour and a fast one."""
    per_match, _ = floor(count, seconds)
    every = per_match["pool"] + per_match["participant"]
    return (
        f"       the bus's floor ({count} matches, {seconds:g} s, bench/bus_floor.py): the pool's "
        f"{per_match['pool']:.4f}, with the participant's {every:.4f} CPU s per s of play per match; "
        f"a participant costs {pool / per_match['pool']:.1f}x the floor in the pool, "
        f"{total / every:.1f}x in all"
    )


NETNS, VETH, ROUTER_IP, HOST_IP = "tsf-bench", "tsf-bench0", "10.199.0.1", "10.199.0.2"


def ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True)


@contextlib.contextmanager
def second_host(how: str, slots: int, out: Path) -> Iterator[BusConfig]:
    """A match host of `slots` slots, in a network namespace (`netns`) or as a plain process;
    yields the study server's router config that it connects to. Everything is removed on exit."""
    secret = out / "host-secret"
    secret.parent.mkdir(parents=True, exist_ok=True)
    secret.write_bytes(HOST_SECRET)
    command = [
        sys.executable,
        "-m",
        "services.commands",
        "match-host",
        "--mode",
        "client",
        "--slots",
        str(slots),
    ]
    command += ["--id", f"{how}-host", "--out", str(out), "--host-secret", str(secret), "-q"]
    with contextlib.ExitStack() as undo:
        if how == "netns":
            ip("netns", "add", NETNS)
            undo.callback(ip, "netns", "del", NETNS)
            ip("link", "add", VETH, "type", "veth", "peer", "name", "tsf-bench1")
            undo.callback(subprocess.run, ["ip", "link", "del", VETH], check=False)
            ip("link", "set", "tsf-bench1", "netns", NETNS)
            ip("addr", "add", f"{ROUTER_IP}/24", "dev", VETH)
            ip("link", "set", VETH, "up")
            for args in (
                ("addr", "add", f"{HOST_IP}/24", "dev", "tsf-bench1"),
                ("link", "set", "tsf-bench1", "up"),
            ):
                ip("netns", "exec", NETNS, "ip", *args)
            ip("netns", "exec", NETNS, "ip", "link", "set", "lo", "up")
            endpoint = free_endpoint(ROUTER_IP)
            command = ["ip", "netns", "exec", NETNS, *command]
        else:
            endpoint = free_endpoint()
        host = subprocess.Popen([*command, "--connect", endpoint])
        undo.callback(host.wait, 30)
        undo.callback(host.terminate)
        yield BusConfig("router", (endpoint,))


def arrival_test(
    n: int, over: float, seconds: float, cap: int, seed: int, hosts: BusConfig | None = None
) -> None:
    config = StudyConfig("arrive", (Variant.read("s", "B5", "S5"),), trials=1, trial_seconds=seconds)
    rng = random.Random(seed)  # one generator: a new one per arrival gave them all the same time
    arrivals = sorted(rng.uniform(0, over) for _ in range(n))
    where = f"{cap} matches here" + (
        f" + a match host with {cap} slots at {hosts.listen[0]}" if hosts else ""
    )
    print(f"arrivals: {n} participants at random over {over:g} s, one {seconds:g} s trial each, {where}")
    load = os.getloadavg()[0]
    serving = Serving(
        max_matches=cap, test_token=TOKEN, hosts=hosts, host_secret=HOST_SECRET, arrivals_per_address=0.0
    )
    reports, attempts, _, _ = serve(config, serving, arrivals)
    completed = sum(r.done for r in reports)
    waits = [w for r in reports for w in r.waits] or [0.0]
    first = [f for r in reports for f in r.first_frames]
    print(
        f"  completed {completed} (goal {n}), lost {n - completed} (goal 0); {len(attempts)} attempts; "
        f"{sum(bool(r.waits) for r in reports)} waited in the queue: p50 {quantile(waits, 50):.1f} s, "
        f"p99 {quantile(waits, 99):.1f} s; Ready-to-first-frame p50 {quantile(first, 50):.3f} s, "
        f"p99 {quantile(first, 99):.3f} s; load average {load:.1f} at the start, "
        f"{os.getloadavg()[0]:.1f} at the end"
    )
    if lost := Counter(r.refused or "the socket closed" for r in reports if not r.done):
        print("  lost: " + "; ".join(f"{count} {why!r}" for why, count in lost.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[1, 2, 4, 8], help="participants at once")
    parser.add_argument("--trials", type=int, default=1, help="trials per participant")
    parser.add_argument("--trial-seconds", type=float, default=10.0)
    parser.add_argument(
        "--arrivals", type=int, default=0, help="run the arrival test with this many participants"
    )
    parser.add_argument(
        "--over", type=float, default=600.0, help="arrival test: seconds over which they arrive"
    )
    parser.add_argument("--max-matches", type=int, default=4, help="arrival test: matches at once")
    parser.add_argument(
        "--second-host",
        choices=("netns", "process"),
        help="arrival test: again with a second match host, in a network namespace (root) or a process",
    )
    parser.add_argument("--adaptive", action="store_true", help="load test: the adaptive study's variants")
    parser.add_argument(
        "--max-lag", type=float, default=Serving.max_lag, help="load test: Serving.max_lag, s (0: no hold)"
    )
    parser.add_argument(
        "--floor-seconds",
        type=float,
        default=10.0,
        help="load test: seconds of bench/bus_floor.py's floor after each count (0: none)",
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.second_host:
        arrival_test(args.arrivals, args.over, args.trial_seconds, args.max_matches, args.seed)
        with (
            tempfile.TemporaryDirectory() as out,
            second_host(args.second_host, args.max_matches, Path(out)) as bus,
        ):
            arrival_test(args.arrivals, args.over, args.trial_seconds, args.max_matches, args.seed, bus)
            print(f"  of which {len(list(Path(out).glob('*.tsflog')))} ran on the second host")
    elif args.arrivals:
        arrival_test(args.arrivals, args.over, args.trial_seconds, args.max_matches, args.seed)
    else:
        load_test(
            args.counts, args.trials, args.trial_seconds, args.adaptive, args.max_lag, args.floor_seconds
        )


if __name__ == "__main__":
    main()
