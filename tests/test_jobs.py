"""The job system with real worker processes over real zenoh: evaluation games (team games,
sessions, identification runs) on workers equal the same jobs run in-process, bit for bit; a
worker that cannot import a job's plug-in says so and gets no more of the run's jobs; a killed
worker, or a killed coordinator run again, loses no result and counts none twice."""

from __future__ import annotations

import json
import logging
import signal
import subprocess
import sys
import threading
import uuid

import pytest

from services.evaluation import identification, team
from services.jobs.bus import Coordination
from services.jobs.core import spec
from services.jobs.engine import on_workers
from services.jobs.kinds import in_process
from shared import keys
from shared.errors import Failure

PARTNERS = ["noisy(B4)", "switch(B1,B5)"]
AGENTS = ["S4", "adaptive-T150-cem", "adaptive-T150-bayes-dwell-ood-guard-memory"]


@pytest.mark.long
@pytest.mark.slow
def test_evaluation_on_workers_equals_in_process(bus, spawn, tmp_path):
    sweep = f"e{uuid.uuid4().hex[:8]}"
    for i in range(2):
        spawn("worker", bus.config(), "--sweep", sweep, "--id", f"w{i}")
    with Coordination(bus.config(listen=True), sweep, tmp_path / "eval.journal") as coordination:
        evaluate_both_ways(on_workers(coordination))


def evaluate_both_ways(run) -> None:  # noqa: ANN001 - a Runner
    progress: list[tuple[int, int]] = []
    here = team.team("shooter", PARTNERS, AGENTS, [0, 1])
    there = team.team("shooter", PARTNERS, AGENTS, [0, 1], run, lambda d, t: progress.append((d, t)))
    assert there == here and len(here) == 12
    assert progress[-1] == (12, 12)
    assert team.sessions("shooter", PARTNERS[:1], AGENTS[1:], [0], run) == team.sessions(
        "shooter", PARTNERS[:1], AGENTS[1:], [0]
    )
    games = [["noisy(B4)", "S5", 0, 3, -1], ["noisy(switch(B1,B5))", "S4", 0, -1, 4]]
    job = [spec("identify", "identify", {"role": "shooter", "windows": [150, 400], "games": games}, 2)]
    assert run(job, None) == in_process(identification.KINDS)(job)


@pytest.mark.slow
@pytest.mark.long  # 11 s or more in the full run: kept out of the default run
def test_a_worker_without_the_plugin_gets_no_more_jobs(bus, spawn, tmp_path, monkeypatch, caplog, wait_until):
    (tmp_path / "lab_partners.py").write_text(
        "from services.population.partners_test import Constant\n\n"
        "class Alice(Constant):\n    key = 'alice'\n"
    )
    partners, sweep = ["lab_partners:Alice", "noisy(lab_partners:Alice)"], f"p{uuid.uuid4().hex[:8]}"
    spawn("worker", bus.config(), "--sweep", sweep, "--id", "without")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.syspath_prepend(str(tmp_path))
    spawn("worker", bus.config(), "--sweep", sweep, "--id", "with")
    with (
        Coordination(bus.config(listen=True), sweep, tmp_path / "eval.journal") as coordination,
        caplog.at_level(logging.ERROR, "tsf.jobs"),
    ):
        # both up first: with no live worker left to take a job, a run ends
        assert wait_until(lambda: {"without", "with"} <= coordination.live, 60)
        there = team.team(
            "shooter", partners, ["S4", "adaptive-T150-cem"], [0, 1, 2], on_workers(coordination)
        )
    assert there == team.team("shooter", partners, ["S4", "adaptive-T150-cem"], [0, 1, 2])
    refusals = [
        r.getMessage() for r in caplog.records if "cannot import plug-in lab_partners:Alice" in r.getMessage()
    ]
    assert len(refusals) <= 1 and all("without" in r for r in refusals)


def test_a_job_that_breaks_the_contract_is_refused_at_once_not_left_to_time_out(bus, tmp_path):
    """Workers drop a job message that breaks the contract; the coordinator checks the same, before
    sending anything (a proxy directory taken for a plug-in once waited out the timeout)."""
    broken = spec("team-0", "team", {"role": "shooter", "games": []}, 1, plugins=("proxy:/a/dir",))
    fine = spec("team-1", "team", {"role": "shooter", "games": []}, 1)
    refused = r"job team-0\.\w+ breaks the job contract, so no worker would run it: .*plugins"
    with (
        Coordination(bus.config(listen=True), "contract", tmp_path / "j.journal") as coordination,
        pytest.raises(Failure, match=refused),
    ):
        coordination.run([fine, broken])
    assert not (tmp_path / "j.journal").exists() or (tmp_path / "j.journal").read_text() == ""


@pytest.mark.parametrize("name", ["no_such_module:Alice"])
def test_in_process_run_names_the_missing_plugin(name):
    from services.jobs.kinds import import_plugins
    from services.population.seat import plugins_in

    assert plugins_in(
        [f"noisy({name})", "B1", "my.zip", "human(proxy:/study/proxies/p0)", "humans:/s@p0"]
    ) == (name,)
    assert import_plugins([name]).startswith(f"cannot import plug-in {name}: ModuleNotFoundError")
    assert import_plugins(["services.population.partners_test:Constant"]) == ""
    assert sys.modules.get("no_such_module") is None


def journal_ids(path) -> list[str]:  # noqa: ANN001 - a Path
    return [json.loads(line)["job"] for line in path.read_text().splitlines() if line.endswith("}")]


@pytest.mark.slow  # over 15 s of real processes; runs with -m slow
def test_evaluation_survives_a_killed_worker(bus, spawn, background, wait_until, tmp_path, monkeypatch):
    monkeypatch.setattr(team, "JOB_GAMES", 2)  # six jobs of two games: the victim has one in flight
    sweep, journal = f"k{uuid.uuid4().hex[:8]}", tmp_path / "eval.journal"
    victim = spawn("worker", bus.config(), "--sweep", sweep, "--id", "victim")

    def evaluate(stop: threading.Event) -> list[dict]:
        with Coordination(bus.config(listen=True), sweep, journal, stop) as coordination:
            return team.team("shooter", PARTNERS, AGENTS, [0, 1], on_workers(coordination))

    result = background(evaluate)
    assert wait_until(lambda: journal.exists() and len(journal_ids(journal)) >= 1, 120)
    spawn("worker", bus.config(), "--sweep", sweep, "--id", "survivor")
    victim.send_signal(signal.SIGKILL)
    assert result.result(timeout=300) == team.team("shooter", PARTNERS, AGENTS, [0, 1])
    ids = journal_ids(journal)
    assert len(ids) == len(set(ids)) == 6  # every job once


@pytest.mark.slow  # over 15 s of real processes; runs with -m slow
def test_a_killed_coordinator_resumes_and_counts_each_job_once(tmp_path, wait_until):
    """`tsf sweep` killed with SIGKILL mid-run (its local workers die with it), then run again."""
    from services.table.table import Table, assemble, jobs, run_job

    out = tmp_path / "table.json"
    command = [sys.executable, "-m", "services.commands", "sweep", "--sweep", f"c{uuid.uuid4().hex[:8]}"]
    command += ["--workers", "1", "--games", "3", "--chunk", "1", "--lanes", "1", "--out", str(out)]
    command += ["--bait", "B4", "--bait", "B7", "--shooter", "S4", "--shooter", "S5"]
    journal = tmp_path / "table.json.journal"
    first = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
    try:
        assert wait_until(lambda: journal.exists() and len(journal_ids(journal)) >= 3, 180)
    finally:
        first.kill()
        first.wait()
    collected = journal_ids(journal)
    assert len(collected) < 12 and not out.exists()
    assert subprocess.run(command, stdin=subprocess.DEVNULL, capture_output=True, timeout=300).returncode == 0
    ids = journal_ids(journal)
    assert len(ids) == len(set(ids)) == 12 and ids[: len(collected)] == collected  # resumed, none again
    reference = {job.id: run_job(job) for job in jobs(["B4", "B7"], ["S4", "S5"], 3, 1)}
    assert Table.load(out).results == assemble(["B4", "B7"], ["S4", "S5"], 3, reference, 1).results


def test_a_worker_with_slots_is_one_live_worker_per_slot(bus, spawn, wait_until):
    sweep = f"w{uuid.uuid4().hex[:8]}"
    z = bus.open(listen=True)
    spawn("worker", bus.config(), "--sweep", sweep, "--id", "pair", "--slots", "2")

    def live() -> set[str]:
        return {str(reply.ok.key_expr) for reply in z.liveliness().get(keys.job_worker(sweep), timeout=2)}

    expected = {keys.job_worker(sweep, "pair-0"), keys.job_worker(sweep, "pair-1")}
    assert wait_until(lambda: live() == expected, 60)


@pytest.mark.slow
def test_tsf_eval_across_a_router_equals_a_local_run(spawn, tmp_path):
    """`tsf eval --workers 0 --mode client --connect ROUTER` with a `tsf worker` across the router
    writes the same numbers as `tsf eval` on a local worker."""
    from shared.bus import BusConfig, free_endpoint

    tsf = [
        sys.executable,
        "-m",
        "services.commands",
        "eval",
        "--role",
        "shooter",
        "--seeds",
        "2",
        "--window",
        "150",
    ]
    tsf += ["--strategy", "cem", "--partner", "noisy(B4)", "--partner", "B1", "--identify-seeds", "1"]
    local = subprocess.run(
        [*tsf, "--workers", "1", "--out", str(tmp_path / "local")], capture_output=True, timeout=600
    )
    assert local.returncode == 0, local.stderr[-2000:]
    endpoint = free_endpoint()
    router = subprocess.Popen([sys.executable, "-m", "services.commands", "router", "--listen", endpoint])
    try:
        spawn("worker", BusConfig("client", (), (endpoint,)), "--sweep", "far-eval", "--id", "far")
        remote = [*tsf, "--workers", "0", "--sweep", "far-eval", "--mode", "client", "--connect", endpoint]
        far = subprocess.run([*remote, "--out", str(tmp_path / "far")], capture_output=True, timeout=600)
        assert far.returncode == 0, far.stderr[-2000:]
    finally:
        router.kill()
        router.wait()
    for name in ("identification.json", "team.csv", "comparison.json", "per_partner.csv"):
        assert (tmp_path / "far" / name).read_bytes() == (tmp_path / "local" / name).read_bytes(), name
