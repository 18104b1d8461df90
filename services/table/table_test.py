"""The table core: jobs, in-process games, the artifact and its staleness check, and the
coordinator's bookkeeping (without a bus)."""

from __future__ import annotations

import json
import math

import pytest

from services.agent import library
from services.sim.batch_play import play_batch
from services.sim.play import play, summarize
from services.table.sweep import Coordinator, read_journal
from services.table.table import StaleTable, Table, assemble, jobs, run_job, run_jobs
from shared.game import GameConfig

BAITS, SHOOTERS = ["B4", "B5"], ["S4", "S6"]


def test_jobs_cover_every_pair_and_seed_once():
    todo = jobs(BAITS, SHOOTERS, games=5, chunk=2)
    covered = [(j.bait, j.shooter, seed) for j in todo for seed in j.seeds]
    assert sorted(covered) == sorted((b, s, seed) for b in BAITS for s in SHOOTERS for seed in range(5))
    assert len({j.id for j in todo}) == len(todo) == 12


def test_a_job_is_its_games_whatever_batch_they_are_played_in():
    job = jobs(["B5"], ["S5"], games=2, chunk=2)[0]
    alone = [
        play_batch(library.load("B5"), library.load("S5"), [seed])[0].kills_per_minute for seed in (0, 1)
    ]
    assert run_job(job) == alone == run_job(job)


@pytest.mark.slow
def test_batched_games_agree_with_scalar_games_in_distribution():
    """Batched sampling draws other random streams than the scalar policies: same mean kills/min
    within three standard errors of the difference, over 100 games of a competent pair."""
    bait, shooter = library.load("B5"), library.load("S5")
    batched = summarize(play_batch(bait, shooter, list(range(100))))
    scalar = summarize([play(bait, shooter, seed) for seed in range(100)])
    assert abs(batched.mean - scalar.mean) < 3 * math.hypot(batched.stderr, scalar.stderr)


@pytest.fixture(scope="module")
def small_table() -> Table:
    results = {job.id: run_job(job, GameConfig(frames=300)) for job in jobs(BAITS, SHOOTERS, 3, 2)}
    return assemble(BAITS, SHOOTERS, 3, results, 2)


def test_jobs_played_together_are_the_jobs_played_alone(small_table):
    todo = jobs(BAITS, SHOOTERS, 3, 2)
    played = run_jobs(todo, GameConfig(frames=300))
    together = assemble(BAITS, SHOOTERS, 3, {j.id: v for j, v in zip(todo, played, strict=True)}, 2)
    assert together.results == small_table.results


def test_table_statistics(small_table):
    values = small_table.results["B5"]["S4"]
    assert len(values) == 3
    assert small_table.mean("B5", "S4") == pytest.approx(sum(values) / 3)
    best = small_table.best_shooter("B5")
    assert all(small_table.mean("B5", best) >= small_table.mean("B5", s) for s in SHOOTERS)


def test_saved_table_loads_and_stale_tables_are_refused(tmp_path, small_table):
    path = tmp_path / "table.json"
    small_table.save(path)
    loaded = Table.load(path)
    assert loaded.results == small_table.results and loaded.games == 3
    record = json.loads(path.read_text())
    assert record["seeds"] == [0, 1, 2] and record["library"] == library.manifest_hash()
    record["library"] = "0" * 16
    path.write_text(json.dumps(record))
    with pytest.raises(StaleTable, match="tsf sweep"):
        Table.load(path)
    assert Table.load(path, check=False).library == "0" * 16
    small_table.save(path)
    with pytest.raises(StaleTable):
        Table.load(path, config=GameConfig(fortress_turn=5.0))


def make_coordinator(n: int = 4) -> Coordinator:
    return Coordinator(jobs(["B4"], ["S4"], games=n, chunk=1), {})


def test_a_dead_workers_job_goes_to_another():
    c = make_coordinator()
    c.worker_up("a")
    c.worker_up("b")
    sent = dict(c.assignments(0.0, 60))
    assert set(sent) == {"a", "b"}
    c.worker_down("a")
    c.worker_up("c")
    resent = dict(c.assignments(1.0, 60))
    assert resent["c"].id == sent["a"].id


def test_each_job_counts_once():
    c = make_coordinator(1)
    c.worker_up("a")
    c.worker_up("b")
    ((worker, job),) = c.assignments(0.0, 60)
    c.worker_down(worker)  # presumed dead, yet its result arrives
    ((other, again),) = c.assignments(1.0, 60)
    assert again == job and other != worker
    assert c.result(worker, job.id, [1.0]) is True
    assert c.result(other, job.id, [2.0]) is False
    assert c.done == {job.id: [1.0]} and c.duplicates == 1 and c.finished


def test_a_slow_job_is_sent_again_and_a_failing_worker_gets_nothing_more():
    c = make_coordinator(2)
    c.worker_up("a")
    ((_, job),) = c.assignments(0.0, timeout=10)
    c.worker_up("b")
    resent = dict(c.assignments(11.0, timeout=10))
    assert resent == {"b": job}
    assert c.result("a", job.id, [3.0]) and "a" in c.idle  # the slow worker answers after all
    c.failed("b", job.id)
    assert "b" not in c.idle and all(w != "b" for w, _ in c.assignments(12.0, 10))


def test_idle_workers_share_the_waiting_jobs_in_batches():
    c = Coordinator(jobs(["B4"], ["S4"], games=7, chunk=1), {}, per_worker=3)
    c.worker_up("a")
    c.worker_up("b")
    sent = c.assignments(0.0, 60)
    assert [w for w, _ in sent] == ["a"] * 3 + ["b"] * 3  # 3 each, not 4 and 3: the cap holds
    c.worker_down("a")
    c.worker_up("c")
    resent = c.assignments(1.0, 60)
    assert [j for w, j in resent if w == "c"] == [j for w, j in sent if w == "a"]  # a's batch, whole
    for worker, job in sent[3:]:
        c.result(worker, job.id, [1.0])
    assert "b" in c.idle and [j.id for _, j in c.assignments(2.0, 60)] == ["B4-S4-6-1"]


def test_journal_resumes_and_skips_a_torn_line(tmp_path):
    path = tmp_path / "t.journal"
    path.write_text('{"job": "B4-S4-0-1", "kills_per_minute": [2.0]}\n{"job": "B4-S4-1-1", "kil')
    c = Coordinator(jobs(["B4"], ["S4"], 2, 1), read_journal(path))
    assert c.done == {"B4-S4-0-1": [2.0]} and [j.id for j in c.waiting] == ["B4-S4-1-1"]
