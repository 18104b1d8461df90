"""The skill table: every teammate with stand-ins of each style and skill, bound like P, and the
same whoever plays which batch."""

from __future__ import annotations

import pytest

from services.evaluation import skills
from services.evaluation.skills import SkillTable, measure, stand_in
from services.table.plot import skill_heatmap

NOVICE, PRACTISED = stand_in("S4", "novice"), stand_in("S4", "practised")


def test_best_responses_gains_and_the_file_read_back(tmp_path):
    results = {
        NOVICE: {"B6": [1.0, 2.0, 0.0], "B1": [4.0, 5.0, 3.0]},
        PRACTISED: {"B6": [8.0, 9.0, 7.0], "B1": [6.0, 8.0, 7.0]},
    }
    table = SkillTable("bait", ("B6", "B1"), ("S4",), ("novice", "practised"), 3, results)
    assert table.partners == [NOVICE, PRACTISED]
    assert table.best(NOVICE) == "B1" and table.best(PRACTISED) == "B6"
    assert table.overall("B1") == pytest.approx(5.5) and table.best_static() == "B1"
    assert table.gain(PRACTISED, "B6", "B1") == (pytest.approx(1.0), pytest.approx(1 / 3**0.5))
    path = tmp_path / "skills.json"
    table.save(path)
    assert SkillTable.load(path) == table
    assert skill_heatmap(table, tmp_path / "skills.png", {"S4": "B6"}).exists()


@pytest.mark.slow
def test_a_skill_table_is_its_seeds_games_in_any_batches(monkeypatch):
    told: list[tuple[int, int]] = []
    table = measure(
        "bait", ["B6", "B1"], ["S4"], ("novice", "practised"), games=3, progress=lambda *p: told.append(p)
    )
    assert told[0] == (0, 12) and told[-1] == (12, 12)  # 2 stand-ins x 2 baits x 3 games
    assert all(len(table.results[p][t]) == 3 for p in table.partners for t in table.teammates)
    monkeypatch.setattr(skills, "LANES", 3)  # one pair a batch, two worker processes
    assert measure("bait", ["B6", "B1"], ["S4"], ("novice", "practised"), games=3, workers=2) == table


def test_the_held_out_headroom_takes_the_luck_of_the_choice_out():
    """B1 looks best with the novice after the fact only by its lucky seed 0: the held-out choice
    (made on even seeds, scored on odd ones, and back) pays for that luck instead."""
    results = {
        NOVICE: {"B6": [1.0] * 4, "B1": [3.0, 1.0, 1.0, 0.0]},
        PRACTISED: {"B6": [2.0] * 4, "B1": [1.0] * 4},
    }
    table = SkillTable("bait", ("B6", "B1"), ("S4",), ("novice", "practised"), 4, results)
    assert table.best(NOVICE) == "B1" and table.best_static() == "B6"
    assert table.mean(NOVICE, "B1") - table.mean(NOVICE, "B6") == pytest.approx(0.25)
    assert table.held_out() == pytest.approx(-0.125)  # B1 chosen on the even seeds scores 0.5 on the odd
    assert table.held_out({NOVICE: "B1", PRACTISED: "B6"}) == pytest.approx(-0.25)  # B6 on odd, B1 on even


def test_a_table_extends_by_the_columns_of_another_of_the_same_stand_ins():
    one = {NOVICE: {"B6": [1.0, 2.0]}, PRACTISED: {"B6": [3.0, 4.0]}}
    two = {NOVICE: {"B10": [2.0, 2.0]}, PRACTISED: {"B10": [5.0, 5.0]}}
    first = SkillTable("bait", ("B6",), ("S4",), ("novice", "practised"), 2, one, "lib1")
    table = first.extend(SkillTable("bait", ("B10",), ("S4",), ("novice", "practised"), 2, two, "lib2"))
    assert table.teammates == ("B6", "B10") and table.library == "lib2"
    assert table.best(NOVICE) == "B10" and table.results[PRACTISED] == {"B6": [3.0, 4.0], "B10": [5.0, 5.0]}
    with pytest.raises(ValueError, match="differ"):
        first.extend(SkillTable("bait", ("B10",), ("S5",), ("novice", "practised"), 2, two))
