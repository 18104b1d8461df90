"""The population stage adopts the events runs the shipped population trained under the same
recipe (a new spec over the same runs trains nothing), and only those."""

from __future__ import annotations

from services.agent import library
from services.growth.population import _shipped, events_recipe
from services.growth.workspace import Workspace
from services.population.families import SPEC, read


def _recorded(tmp_path, text: str) -> tuple[Workspace, list]:
    tmp_path.mkdir(exist_ok=True)
    path = tmp_path / "population.toml"
    path.write_text(text)
    spec = read(path)
    ws = Workspace(spec, tmp_path / "run", engine=None, say=lambda line: None)
    runs = spec.events_runs("bait")[:2]
    library.record(ws.population_dir, {k: events_recipe(spec, r) for r in runs for k in r.level_keys()})
    return ws, runs


def test_a_run_the_shipped_population_trained_alike_is_adopted(tmp_path):
    ws, runs = _recorded(tmp_path, SPEC.with_name("population-2.toml").read_text())
    assert all(_shipped(ws, run, library.NAMED["population"]) for run in runs)


def test_the_third_versions_runs_are_adopted_from_its_own_shipped_members_and_not_the_firsts(tmp_path):
    ws, runs = _recorded(tmp_path, SPEC.with_name("population-3.toml").read_text())
    assert all(_shipped(ws, run, library.NAMED["population-3"]) for run in runs)
    assert not any(_shipped(ws, run, library.NAMED["population"]) for run in runs)  # PPO, 150,000 steps


def test_a_run_of_another_recipe_or_other_levels_is_trained(tmp_path):
    text = SPEC.read_text()
    ws, runs = _recorded(tmp_path / "steps", text.replace("steps = 150000", "steps = 160000", 1))
    assert not any(_shipped(ws, run, library.NAMED["population"]) for run in runs)  # the recipe differs
    ws, runs = _recorded(
        tmp_path / "levels", text.replace("levels = [0.25, 0.5, 1.0]", "levels = [0.3, 0.5, 1.0]", 1)
    )
    assert not any(
        _shipped(ws, run, library.NAMED["population"]) for run in runs
    )  # the same recipe, the first level trained further
