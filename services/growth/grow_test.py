"""The whole `tsf library grow` pipeline on a population small enough to grow in minutes, in-process,
and the cross-play jobs against the games they stand for."""

from __future__ import annotations

import json
from contextlib import nullcontext

import numpy as np
import pytest

from services.evaluation.evaluate import play_teams
from services.growth.crossplay import pair_jobs, run_pair_jobs
from services.population.seat import seats_of

SMALL = """
seed = 7
games = 2
skills = ["novice"]
split = { train = 0.5, validation = 0.25, test = 0.25 }
groups = { most = 2, regret = 0.05 }
selection = { most = 3, gain = 0.01 }
search = { trials = 4, seeds = 1 }

[bait]
library = ["B1", "B3", "B5", "B6"]
rule = { family = "circle", grid = { radius = [90.0, 120.0, 150.0, 180.0] } }
events = { runs = 1, steps = 2048, levels = [0.5, 1.0], learned = ["turn", "thrust"], features = "self+shells+partner", partners = ["S4"] }
response = { learned = ["turn", "thrust"], features = "self+shells+partner", reward = "drawing-fire", weights = { kill = 50.0 }, steps = 2048 }

[shooter]
library = ["S1", "S4", "S5", "S7"]
rule = { family = "mirror", grid = { placed_distance = [8.0, 20.0, 40.0, 70.0] } }
events = { runs = 1, steps = 2048, levels = [0.5, 1.0], learned = ["turn", "thrust"], features = "shooter", partners = ["B5"] }
response = { learned = ["turn", "thrust"], features = "shooter", reward = "shooter-position", weights = { kill = 10.0, aim = 1.0 }, steps = 2048, warm_start = true }
"""  # noqa: E501


def test_pair_jobs_play_the_games_they_stand_for():
    teams = [
        ("B5", "S4"),
        ("circle(radius=150)", "mirror(placed_distance=40)"),
        ("human(B1,skill=novice)", "S1"),
    ]
    jobs = pair_jobs("t", teams, [0, 1])
    assert [job.size for job in jobs] == [6]
    expected = play_teams([seats_of(t) for t in teams], [0, 1]).ravel().tolist()
    assert run_pair_jobs([job.args for job in jobs]) == [expected]
    split = pair_jobs("t", teams * 50, [3, 4])  # more teams than a job holds
    assert len(split) == 2 and sum(job.size for job in split) == 300


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.timeout(900)  # five minutes alone (two without the warm starts); a loaded machine takes more
def test_a_small_population_grows_a_library_and_a_second_run_resumes_from_its_files(tmp_path, monkeypatch):
    pytest.importorskip("stable_baselines3", reason="the `train` extra is not installed")
    pytest.importorskip("optuna", reason="the `search` extra is not installed")  # the spec asks for a search
    from services.agent import library, networks
    from services.growth.choice import Grid
    from services.growth.grow import KINDS, Grow
    from services.growth.responses import demonstrator
    from services.jobs.kinds import in_process
    from services.population.families import read

    monkeypatch.delenv("TSF_LIBRARY", raising=False)
    path = tmp_path / "population.toml"
    path.write_text(SMALL)
    spec, out, said = read(path), tmp_path / "grown", []
    summary = Grow(spec, out, lambda stage: nullcontext(in_process(KINDS)), said.append).run()
    population = json.loads((out / "population.json").read_text())["members"]
    assert {row["split"] for row in population["bait"]} == {"train", "validation", "test"}
    assert [row["name"] for row in population["bait"] if row["family"] == "events"] == ["PB01a", "PB01b"]
    groups = json.loads((out / "groups.json").read_text())
    for role in ("bait", "shooter"):
        grouped = sorted(m for g in groups[role]["groups"] for m in g)
        train = sorted(row["name"] for row in population[role] if row["split"] == "train")
        assert grouped == train  # every training member in one group, nothing else
    responses = library.registry(out / "responses")  # the shooters warm-start from their group's best mirror
    grouping = Grid.of(json.loads((out / "grouping.json").read_text())["bait"])
    for j, members in enumerate(groups["bait"]["groups"]):
        assert responses[f"RS{j + 1}"].demonstrator == demonstrator(grouping, members, "mirror")
        checkpoint = json.loads((out / "runs" / f"RS{j + 1}" / "checkpoint.json").read_text())
        assert checkpoint["warm_start"] and 0.0 <= checkpoint["agreement"] <= 1.0
    assert not any(r.demonstrator for k, r in responses.items() if k.startswith("RB"))
    for ours, partners in (("shooter", "bait"), ("bait", "shooter")):  # the search's settings: candidates
        searched = json.loads((out / f"search-{ours}.json").read_text())
        trained = sorted(m for g in groups[partners]["groups"] for m in g)
        assert len(searched["trials"]) == 4 and sorted(searched["partners"]) == trained
        found = json.loads((out / "search-held-out.json").read_text())[partners]["candidates"]
        assert found and set(found) <= {t["name"] for t in searched["trials"]}
    for seat in summary["seats"].values():
        curve = seat["curve"]
        assert curve[0]["headroom"] == 0.0 and 1 <= len(curve) <= 3
        rooms = [step["headroom"] for step in curve]
        assert rooms == sorted(set(rooms))  # each member added adds room
        assert seat["test"]["members"]["partners"] > 0
        assert seat["test"]["stand-ins"]["partners"] == seat["test"]["members"]["partners"]  # one skill
        assert seat["test"]["both"]["partners"] == 2 * seat["test"]["members"]["partners"]
    for role in ("bait", "shooter"):  # every member counted once in its family, able ones among them
        families = summary["competence"][role]
        assert sum(c["members"] for c in families.values()) == len(population[role])
        assert all(0 <= c["able"] <= c["members"] for c in families.values())
    assert "The population's competence" in (out / "summary.md").read_text()
    monkeypatch.setenv("TSF_LIBRARY", str(out / "library"))
    members = json.loads((out / "library" / "members.json").read_text())
    assert set(members) == {k for k in library.registry() if k.startswith(("GB", "GS"))}
    for key in members:  # every member plays and says how likely its actions are
        policy = networks.load(key)
        assert np.isclose(policy.probs(np.zeros(64, np.float32)).sum(), 1.0)
    table = json.loads((out / "library" / "table.json").read_text())
    assert set(table["baits"]) | set(table["shooters"]) == set(members)
    assert (out / "library" / "calibration.json").exists() and (out / "summary.md").exists()
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("*.json") if p.name != "summary.json"}
    again = Grow(spec, out, lambda stage: pytest.fail(f"resumed run played {stage}"), said.append).run()
    assert stamps == {p: p.stat().st_mtime_ns for p in out.glob("*.json") if p.name != "summary.json"}
    assert again == summary  # the figures, computed again from the files
