"""The responses stage's recipes: a warm start imitates the group's best rule of the family a
network can imitate, chosen on the grouping cross-play."""

from __future__ import annotations

import numpy as np

from services.agent import library
from services.growth.choice import Grid
from services.growth.responses import demonstrator, response_recipe
from services.growth.workspace import train_job
from services.population.families import SPEC, read

MIRRORS = ("mirror(placed_distance=8,max_speed=3)", "mirror(placed_distance=20,max_speed=7)")


def grid() -> Grid:
    """Three bait partners with a study shooter (best over all), two mirrors and a response."""
    means = np.array(
        [
            [9.0, 2.0, 6.0, 1.0],  # a and b: the second mirror is their group's best rule
            [9.0, 3.0, 5.0, 8.0],
            [9.0, 7.0, 1.0, 1.0],  # c: the first
        ]
    )
    return Grid(("a", "b", "c"), ("S1", *MIRRORS, "RS1"), np.repeat(means[:, :, None], 2, axis=2))


def test_a_groups_demonstrator_is_its_best_rule_of_the_family_not_its_best_candidate():
    assert demonstrator(grid(), ["a", "b"], "mirror") == {"placed_distance": 20.0, "max_speed": 7.0}
    assert demonstrator(grid(), ["c"], "mirror") == {"placed_distance": 8.0, "max_speed": 3.0}


def test_a_warm_started_response_records_its_demonstrator_and_its_job_asks_for_the_warm_start(tmp_path):
    text = SPEC.with_name("population-3.toml").read_text()
    path = tmp_path / "population.toml"
    shooter = text.index("[shooter]")  # the shooter table's response: the shooters trained for bait groups
    warm = text[shooter:].replace('algorithm = "TRPO" }', 'algorithm = "TRPO", warm_start = true }')
    path.write_text(text[:shooter] + warm)
    spec = read(path)
    assert spec.seats["shooter"].warm_start and not spec.seats["bait"].warm_start
    assert "warm_start" not in spec.seats["shooter"].response  # how it trains, not a registry field
    shown = demonstrator(grid(), ["a", "b"], "mirror")
    fields = response_recipe(spec, "bait", 0, ["a", "b"], shown)
    library.record(tmp_path / "responses", {"RS1": fields})
    assert library.registry(tmp_path / "responses")["RS1"].demonstrator == shown
    assert "demonstrator" not in response_recipe(spec, "bait", 0, ["a", "b"])
    assert train_job("RS1", tmp_path, {"RS1": 10}, tmp_path, warm_start=True).args["warm_start"] is True
    assert (
        "warm_start" not in train_job("RS1", tmp_path, {"RS1": 10}, tmp_path).args
    )  # journals stay as they were
