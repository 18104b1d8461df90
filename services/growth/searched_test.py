"""The search measured on a grown run: its references, and a teammate against them."""

from __future__ import annotations

import numpy as np
import pytest

from services.agent.library import NAMED
from services.growth.searched import _cell, _compared, check_run, references
from shared.errors import UsageError


def test_the_shipped_run_s_references_are_its_best_member_and_the_study_s_best_static():
    assert references("shooter", NAMED["grown"]) == {
        "GS1": "mirror(placed_distance=8,max_speed=7,aim_tolerance=8)",
        "study best": "S4",
    }
    assert references("bait", NAMED["grown"]) == {
        "GB1": "circle(radius=170,speed=1.5,outside=260)",
        "study best": "B1",
    }


def test_a_directory_without_a_run_s_records_is_refused(tmp_path):
    check_run(NAMED["grown"])
    with pytest.raises(UsageError, match="no run-population.json, run-groups.json, run-summary.json"):
        check_run(tmp_path)


def test_a_teammate_is_compared_with_the_partner_and_the_game_as_the_unit():
    rng = np.random.default_rng(0)
    ref = rng.uniform(2, 4, (12, 8))
    better = ref + 0.5 + rng.normal(0, 0.2, (12, 8))
    compared = _compared(better, [ref, ref * 2])
    first, second = compared["against"]
    assert compared["kills"] == pytest.approx(better.mean(), abs=1e-4)
    assert first["percent"] == pytest.approx(100 * 0.5 / ref.mean(), abs=1.0) and second["percent"] < 0
    assert first["p_games"] <= first["p_partners"] < 0.01
    assert second["p_partners"] > 0.99


def test_a_reference_that_scores_nothing_leaves_the_percent_not_defined():
    """As every summary of the project says it (results.percent), never 0 %."""
    compared = _compared(np.ones((3, 2)), [np.zeros((3, 2))])
    assert compared["against"][0]["percent"] is None and "not defined" in _cell(compared)


def test_the_searchable_families_are_each_seats_rules_with_their_settings():
    """Our seat's own rule first (the growth's), then the seat's other rules with a search space;
    every space's settings are settings of its rule."""
    import inspect

    from services.agent.scripted import SCRIPTED
    from services.growth.search import SPACES
    from services.growth.searched import families

    assert families("bait") == ["circle", "orbit"] and families("shooter") == ["mirror"]
    for family, space in SPACES.items():
        assert set(space) <= set(inspect.signature(SCRIPTED[family]).parameters), family
