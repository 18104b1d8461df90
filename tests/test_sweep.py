"""Distributed sweeps over real zenoh sessions: workers in separate processes, one killed with
SIGKILL mid-job, a stopped sweep resumed, and a worker in another network namespace reached
through a router. Every table must equal the one computed in-process."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import uuid

import pytest

from services.jobs.core import Hashes, journal_line
from services.runtime.launch import service_command
from services.table.sweep import cell_spec, journal_path, run_sweep
from services.table.table import Table, assemble, jobs, run_job
from shared.bus import BusConfig, free_endpoint

BAITS, SHOOTERS, GAMES, CHUNK = ["B4", "B7"], ["S4", "S5"], 4, 1


@pytest.fixture(scope="module")
def reference() -> Table:
    """The sub-table computed in-process, job by job."""
    results = {job.id: run_job(job) for job in jobs(BAITS, SHOOTERS, GAMES, CHUNK)}
    return assemble(BAITS, SHOOTERS, GAMES, results, CHUNK)


def worker_args(sweep: str, name: str) -> list[str]:
    return ["--sweep", sweep, "--id", name]


@pytest.mark.slow
@pytest.mark.long  # 30 s alone
@pytest.mark.timeout(600)  # a cold compile of the batch engine took 47-160 s on this machine
def test_sweep_survives_a_killed_worker(bus, spawn, background, wait_until, tmp_path, reference):
    sweep, out = f"s{uuid.uuid4().hex[:8]}", tmp_path / "table.json"
    progress: list[int] = []
    result = background(
        run_sweep, bus.config(listen=True), sweep, out, BAITS, SHOOTERS, GAMES, CHUNK,
        lambda done, total: progress.append(done), lanes=2,
    )  # fmt: skip
    victim = spawn("worker", bus.config(), *worker_args(sweep, "victim"))
    assert wait_until(
        lambda: (
            result.done() or journal_path(out).exists() and journal_path(out).read_text().count("\n") >= 1
        ),
        300,
    )  # a worker's first job may compile the batch engine (numba), slow on a loaded 2-core machine
    assert not result.done() or result.result() is None, "the sweep ended before its first job"
    survivor = spawn("worker", bus.config(), *worker_args(sweep, "survivor"))
    victim.send_signal(signal.SIGKILL)  # mid-batch: it always has two jobs while jobs remain
    table = result.result(timeout=240)
    assert table is not None and table.results == reference.results
    assert Table.load(out).results == reference.results
    assert survivor.wait(timeout=30) == 0  # leaves once the coordinator is gone


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_stopped_sweep_resumes_from_its_journal(bus, spawn, wait_until, tmp_path, reference):
    sweep, out = f"s{uuid.uuid4().hex[:8]}", tmp_path / "table.json"
    spawn("worker", bus.config(), *worker_args(sweep, "w1"))
    stop = threading.Event()

    def stop_after_three(done: int, total: int) -> None:
        if done >= 3:
            stop.set()

    config = bus.config(listen=True)
    stopped = run_sweep(config, sweep, out, BAITS, SHOOTERS, GAMES, CHUNK, stop_after_three, stop, lanes=1)
    assert stopped is None
    collected = journal_path(out).read_text().count("\n")
    assert 3 <= collected < len(jobs(BAITS, SHOOTERS, GAMES, CHUNK)) and not out.exists()
    spawn("worker", bus.config(), *worker_args(sweep, "w2"))
    counts: list[int] = []
    table = run_sweep(
        bus.config(listen=True), sweep, out, BAITS, SHOOTERS, GAMES, CHUNK, lambda d, t: counts.append(d)
    )
    assert counts[0] >= collected  # picked up where it stopped
    assert table is not None and table.results == reference.results


def test_a_journal_line_of_another_library_never_enters_the_table(bus, spawn, tmp_path, reference):
    """The issue's finding: a line planted by hand with the wrong library hash and 99 kills/min."""
    from services.jobs.kinds import hashes

    sweep, out = f"s{uuid.uuid4().hex[:8]}", tmp_path / "table.json"
    first = jobs(BAITS, SHOOTERS, GAMES, CHUNK)[0]
    planted = Hashes("0badc0ffee000000", hashes().config)
    journal_path(out).write_text(journal_line(cell_spec(first).id, [99.0] * len(first.seeds), planted))
    spawn("worker", bus.config(), *worker_args(sweep, "w1"))
    table = run_sweep(bus.config(listen=True), sweep, out, BAITS, SHOOTERS, GAMES, CHUNK)
    assert table is not None and table.results == reference.results
    assert 99.0 not in table.results[first.bait][first.shooter]


def netns_available() -> str:
    if os.geteuid() != 0 or shutil.which("ip") is None:
        return "needs root and iproute2 for `ip netns`"
    probe = f"tsfprobe{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"`ip netns add` is not allowed here: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], check=False)
    return ""


@pytest.fixture
def namespace():
    """A network namespace joined to this one by a veth pair: (name, this side's address)."""
    reason = netns_available()
    if reason:
        pytest.skip(reason)
    tag = os.getpid() % 200 + 20
    name, here, there = f"tsf{os.getpid()}", f"veth{tag}a", f"veth{tag}b"
    host, guest = f"10.{tag}.0.1", f"10.{tag}.0.2"
    commands = [
        ["ip", "netns", "add", name],
        ["ip", "link", "add", here, "type", "veth", "peer", "name", there],
        ["ip", "link", "set", there, "netns", name],
        ["ip", "addr", "add", f"{host}/24", "dev", here],
        ["ip", "link", "set", here, "up"],
        ["ip", "netns", "exec", name, "ip", "addr", "add", f"{guest}/24", "dev", there],
        ["ip", "netns", "exec", name, "ip", "link", "set", there, "up"],
        ["ip", "netns", "exec", name, "ip", "link", "set", "lo", "up"],
    ]
    try:
        for command in commands:
            subprocess.run(command, check=True, capture_output=True)
        yield name, host
    finally:
        subprocess.run(["ip", "link", "del", here], check=False, capture_output=True)
        subprocess.run(["ip", "netns", "del", name], check=False, capture_output=True)


def test_worker_in_another_namespace_through_a_router(namespace, background, tmp_path, reference):
    name, host = namespace
    router_endpoint = free_endpoint(host)
    router = subprocess.Popen(
        [sys.executable, "-m", "services.commands", "router", "--listen", router_endpoint]
    )
    worker_bus = BusConfig("client", (), (router_endpoint,))
    worker = subprocess.Popen(
        ["ip", "netns", "exec", name, *service_command("worker", worker_bus, "--sweep", "far", "--id", "far")]
    )
    try:
        table = run_sweep(
            BusConfig("client", (), (router_endpoint,)),
            "far",
            tmp_path / "t.json",
            BAITS,
            SHOOTERS,
            GAMES,
            CHUNK,
        )
        assert table is not None and table.results == reference.results
        assert worker.wait(timeout=30) == 0
    finally:
        for process in (worker, router):
            if process.poll() is None:
                process.kill()
            process.wait()
