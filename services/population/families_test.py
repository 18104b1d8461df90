from collections import Counter

import pytest

from services.population.families import SPEC, read
from shared.errors import UsageError


def test_the_shipped_population_has_sixty_members_a_seat_in_three_families():
    spec = read()
    for role in ("bait", "shooter"):
        members = spec.members(role)
        assert len({m.name for m in members}) == len(members) >= 60
        assert set(Counter(m.family for m in members)) == {"library", "rule", "events"}


def test_the_split_is_by_member_and_keeps_an_events_run_together():
    spec = read()
    for role in ("bait", "shooter"):
        members = spec.members(role)
        sides = spec.split_of(members)
        assert set(sides.values()) == {"train", "validation", "test"}
        by_origin: dict[str, set[str]] = {}
        for m in members:
            by_origin.setdefault(m.origin, set()).add(sides[m.name])
        assert all(len(s) == 1 for s in by_origin.values())  # levels of one run on one side
        assert sides == spec.split_of(list(reversed(members)))  # not by order
        share = Counter(sides.values())
        assert share["train"] > share["validation"] > 0 and share["test"] > 0


def test_event_weights_are_drawn_from_the_seed():
    spec = read()
    runs = spec.events_runs("bait")
    assert runs == read().events_runs("bait")
    assert len({tuple(sorted(r.weights.items())) for r in runs}) == len(runs)
    assert all(r.weights["kill"] > 0 >= r.weights["death"] for r in runs)
    assert runs[0].level_keys() == ["PB01a", "PB01b", "PB01c"]


def test_stand_ins_at_each_skill():
    assert read().stand_ins("B5") == [f"human(B5,skill={s})" for s in ("novice", "typical", "practised")]


@pytest.mark.parametrize(
    ("change", "says"),
    [
        (("seed = 2026", "sead = 2026"), "unknown key sead"),
        (("games = 4 ", "games = 3 "), "games = 3"),
        (('skills = ["novice"', 'skills = ["newbie"'), "skill=newbie"),
        (("levels = [0.25, 0.5, 1.0]", "levels = [0.5, 0.25, 1.0]"), "increasing fractions"),
        (('family = "circle"', 'family = "mirror"'), "the bait's rule is 'circle'"),
        (("seed = 2026", "seed = [2026"), "cannot be read as TOML"),
    ],
)
def test_a_wrong_spec_is_one_line(tmp_path, change, says):
    path = tmp_path / "population.toml"
    path.write_text(SPEC.read_text().replace(*change, 1))
    with pytest.raises(UsageError, match="--population") as error:
        read(path)
    assert says in str(error.value) and "\n" not in str(error.value)
