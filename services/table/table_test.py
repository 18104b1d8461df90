"""The table core: jobs, in-process games, the artifact and its staleness check, and the
coordinator's bookkeeping (without a bus)."""

from __future__ import annotations

import json
import math

import pytest

from services.agent import library, networks
from services.sim.batch_play import play_batch
from services.sim.play import play, summarize
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
        play_batch(networks.load("B5"), networks.load("S5"), [seed])[0].kills_per_minute for seed in (0, 1)
    ]
    assert run_job(job) == alone == run_job(job)


@pytest.mark.slow
def test_batched_games_agree_with_scalar_games_in_distribution():
    """Batched sampling draws other random streams than the scalar policies: same mean kills/min
    within three standard errors of the difference, over 100 games of a competent pair."""
    bait, shooter = networks.load("B5"), networks.load("S5")
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
    missing = tmp_path / "mine" / "table.json"
    with pytest.raises(
        StaleTable, match=f"no table at {missing}: measure it with `tsf sweep --out {missing}`"
    ):
        Table.load(missing)
