"""The job system on a real local Ray cluster (a head and a second node, started here; the `ray`
extra): every kind's results equal a local run's, byte for byte; a node killed mid-run costs
retries, not results, and the journal counts each job once; a job that fails ends the run with
one line. Marked `ray` (CI runs them as their own step) and `slow`."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

ray = pytest.importorskip("ray", reason="the `ray` extra is not installed")
from ray.cluster_utils import Cluster  # noqa: E402

from services.evaluation import team, thresholds  # noqa: E402
from services.jobs.core import spec  # noqa: E402
from services.jobs.kinds import in_process  # noqa: E402
from services.jobs.ray_engine import OnRay  # noqa: E402
from services.table.table import Table, assemble, jobs, run_job  # noqa: E402

pytestmark = [pytest.mark.ray, pytest.mark.slow]
ADAPTIVE = {"agent": "adaptive-T150-cem", "person": 0}
TABLE = ["--bait", "B4", "--bait", "B7", "--shooter", "S4", "--shooter", "S5"]
EVAL = ["--seeds", "2", "--window", "150", "--strategy", "cem", "--identify-seeds", "1"]
EVAL += ["--partner", "noisy(B4)", "--partner", "B1", "-q"]


@pytest.fixture
def cluster(tmp_path, monkeypatch):  # noqa: ANN201 - a ray Cluster
    """A head and a second node of one CPU each; the plug-ins of `lab.py` importable on both."""
    (tmp_path / "lab.py").write_text(
        "from services.population.partners_test import Constant\n\n"
        "class Raises(Constant):\n    key = 'raises'\n"
        "    def reset(self, seed=None):\n        self.t = 0\n"
        "    def act(self, obs):\n        self.t += 1\n"
        "        if self.t > 100:\n            raise RuntimeError('boom')\n        return 5\n"
    )
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))  # the nodes' processes inherit it
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    cluster.second = cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    yield cluster
    cluster.shutdown()


def tsf(*args: str, **kwargs: object) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "services.commands", *args],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, **kwargs,
    )  # fmt: skip


def finish(process: subprocess.Popen, timeout: float = 300) -> tuple[int, str]:
    _, err = process.communicate(timeout=timeout)
    return process.returncode, err


def journal_ids(path: Path) -> list[str]:
    return [json.loads(line)["job"] for line in path.read_text().splitlines() if line.endswith("}")]


def reference_table(games: int, chunk: int) -> dict:
    done = {job.id: run_job(job) for job in jobs(["B4", "B7"], ["S4", "S5"], games, chunk)}
    return assemble(["B4", "B7"], ["S4", "S5"], games, done, chunk).results


def test_a_sweep_on_ray_survives_a_killed_node_and_equals_a_local_run(cluster, tmp_path):
    out = tmp_path / "table.json"
    journal = tmp_path / "table.json.journal"
    run = tsf("sweep", "--ray", cluster.address, "--games", "8", "--chunk", "1", *TABLE, "--out", str(out))
    deadline = time.monotonic() + 120
    while not (journal.exists() and len(journal_ids(journal)) >= 4):
        assert time.monotonic() < deadline and run.poll() is None, run.stderr and run.stderr.read()
        time.sleep(0.05)
    cluster.remove_node(cluster.second)  # its raylet and worker processes die now, tasks in flight too
    killed_at = len(journal_ids(journal))
    status, err = finish(run)
    assert status == 0, err
    assert killed_at < 32  # the node went mid-run
    ids = journal_ids(journal)
    assert len(ids) == len(set(ids)) == 32  # every job once
    assert Table.load(out).results == reference_table(8, 1)
    lines = journal.read_text().splitlines(keepends=True)  # a run stopped after 10 jobs, resumed
    journal.write_text("".join(lines[:10]))
    out.unlink()
    again = tsf("sweep", "--ray", cluster.address, "--games", "8", "--chunk", "1", *TABLE, "--out", str(out))
    assert finish(again)[0] == 0
    assert journal_ids(journal)[:10] == ids[:10] and sorted(journal_ids(journal)) == sorted(ids)
    assert Table.load(out).results == reference_table(8, 1)
    zenoh = tmp_path / "zenoh.json"
    assert (
        finish(tsf("sweep", "--workers", "1", "--games", "8", "--chunk", "1", *TABLE, "--out", str(zenoh)))[0]
        == 0
    )
    assert json.loads(out.read_text())["results"] == json.loads(zenoh.read_text())["results"]


def test_an_evaluation_on_ray_writes_the_bytes_of_one_on_zenoh_workers(cluster, tmp_path):
    on_ray = tsf("eval", *EVAL, "--ray", cluster.address, "--out", str(tmp_path / "ray"))
    assert finish(on_ray)[0] == 0, on_ray.stderr
    local = tsf("eval", *EVAL, "--workers", "1", "--sweep", "r-eval", "--out", str(tmp_path / "zenoh"))
    assert finish(local)[0] == 0
    for name in ("identification.json", "team.csv", "comparison.json", "per_partner.csv"):
        assert (tmp_path / "ray" / name).read_bytes() == (tmp_path / "zenoh" / name).read_bytes(), name


def test_sessions_and_calibration_games_on_ray_equal_in_process(cluster, tmp_path):
    todo = [
        spec(
            "session",
            "session",
            {"role": "shooter", "partner": "noisy(B4)", "agent": "adaptive-T150-cem", "person": 0},
            3,
        ),  # noqa: E501
        spec("calibrate", "calibrate", {"games": [["B4", "S5", 0]]}, 1800),
    ]
    runners = team.KINDS | thresholds.KINDS
    with OnRay(cluster.address, tmp_path / "j.journal", runners) as engine:
        done = engine.run(todo)
    assert [done[job.id] for job in todo] == in_process(runners)(todo)


def test_a_job_that_fails_on_ray_ends_the_run_in_one_line(cluster, tmp_path):
    started = time.monotonic()
    run = tsf("eval", "-q", "--partner", "lab:Raises", "--seeds", "2", "--no-identify", "--strategy", "cem",
              "--window", "150", "--ray", cluster.address, "--out", str(tmp_path / "out"))  # fmt: skip
    status, err = finish(run)
    line = err.strip().splitlines()[-1]
    assert status == 1 and "Traceback" not in err
    assert (
        line.startswith("tsf eval: job team-0.")
        and "failed on Ray (job): partner lab:Raises, seed 0:" in line
    )
    assert "raises at frame 100: RuntimeError: boom" in line
    assert time.monotonic() - started < 120
