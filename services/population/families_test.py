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
        (("seed = 2026", "sead = 2026"), "sead: no such setting"),
        # every depth, kind and range (issue 59): a nested key, a negative count, a grid as text,
        # repeated grid values, a seat with no members
        (('reward = "drawing-fire"', 'reword = "drawing-fire"'), "bait.response.reword: no such setting"),
        (
            ('reward = "drawing-fire"', 'warm_start = "yes", reward = "drawing-fire"'),
            'warm_start = "yes": true or false',
        ),
        (("runs = 10, steps = 150000", "runs = 10, steps = -5"), "bait.events: runs = 10, steps = -5"),
        (("speed = [1.5, 2.5, 3.5]", 'speed = "1.5"'), 'bait.rule.grid.speed = "1.5": a list'),
        (("speed = [1.5, 2.5, 3.5]", "speed = [1.5, 1.5]"), "grid.speed = [1.5, 1.5]: a list of distinct"),
        (('features = "shooter", partners', 'features = "shoter", partners'), "features = 'shoter'"),
        (("split = { train = 0.5,", "split = { train = 0.6,"), "positive fractions that add up to 1"),
        (("games = 4 ", "games = 3 "), "games = 3"),
        (('skills = ["novice"', 'skills = ["newbie"'), "skill=newbie"),
        (("levels = [0.25, 0.5, 1.0]", "levels = [0.5, 0.25, 1.0]"), "increasing fractions"),
        (('family = "circle"', 'family = "mirror"'), "the bait's rule is 'circle'"),
        (("seed = 2026", "seed = [2026"), "cannot be read as TOML"),
        (("seed = 2026", "search = { trials = 0 }\nseed = 2026"), "search: trials = 0, seeds = 8"),
        (
            ("seed = 2026", 'search = { trials = 9, families = { bait = ["mirror"] } }\nseed = 2026'),
            "families.bait = ['mirror']: a seat (bait, shooter) and one or more of its rules (circle, orbit)",
        ),
        (("seed = 2026", 'keys = { bait = "PB" }\nseed = 2026'), "keys.bait = 'PB': a seat (bait, shooter)"),
        (("seed = 2026", 'keys = { bait = "GS" }\nseed = 2026'), "a prefix of its own for each seat"),
        (("regret = 0.05", "regret = 0.05, floor = -1"), "floor = -1, identify = 0.0: kills/min, 0 or more"),
        (("steps = 150000,", 'steps = 150000, algorithm = "DQN",'), "algorithm = 'DQN': one of PPO"),
        (("steps = 300000", 'steps = 300000, algorithm = "trpo"'), "algorithm = 'trpo': one of PPO"),
    ],
)
def test_a_wrong_spec_is_one_line(tmp_path, change, says):
    path = tmp_path / "population.toml"
    path.write_text(SPEC.read_text().replace(*change, 1))
    with pytest.raises(UsageError, match="--population") as error:
        read(path)
    assert says in str(error.value) and "\n" not in str(error.value)


def test_a_spec_grows_a_search_only_where_it_asks_for_one(tmp_path):
    """The shipped spec has no search (its library was grown without one); seeds default to 8."""
    assert read().search is None
    path = tmp_path / "population.toml"
    path.write_text("search = { trials = 100 }\n" + SPEC.read_text())
    search = read(path).search
    assert (search.trials, search.seeds) == (100, 8)
    assert search.of("bait") == ("circle",) and search.of("shooter") == ("mirror",)  # each seat's own rule


def test_the_third_population_trains_its_events_runs_and_responses_with_trpo():
    spec = read(SPEC.with_name("population-3.toml"))
    first = read()
    for role in ("bait", "shooter"):
        runs, before = spec.events_runs(role), first.events_runs(role)
        assert {r.algorithm for r in runs} == {"TRPO"} and {r.steps for r in runs} == {1_000_000}
        assert [(r.key, r.weights, r.seed) for r in runs] == [(r.key, r.weights, r.seed) for r in before]
        assert spec.seats[role].response["algorithm"] == "TRPO"
    assert first.seats["bait"].response["algorithm"] == "PPO"  # where a spec names none
    assert spec.split_of(spec.members("bait")) == first.split_of(first.members("bait"))


def test_the_second_population_searches_the_orbit_too_and_grows_from_the_first_ones_members():
    """population-2.toml: the first version's members (the same events recipes and split) with 8
    games a pair, a competence floor and the search, the bait seat's orbit as well as its circle."""
    first, second = read(), read(SPEC.with_name("population-2.toml"))
    assert second.search.of("bait") == ("circle", "orbit") and second.search.seeds >= 8
    assert second.games >= 8 and second.groups["floor"] == 1.0 and second.groups["identify"] == 0.85
    assert first.keys == {"bait": "GB", "shooter": "GS"} and second.keys == {"bait": "TB", "shooter": "TS"}
    for role in ("bait", "shooter"):
        assert first.members(role) == second.members(role)
        assert first.split_of(first.members(role)) == second.split_of(second.members(role))
        assert first.events_runs(role) == second.events_runs(role)


def test_a_seat_cannot_end_without_members(tmp_path):
    """No library, no events runs, and a grid setting with no values (once: no rule members)."""
    text = SPEC.read_text().replace('library = ["S1", "S2", "S3", "S4", "S5", "S6", "S7"]', "library = []")
    text = text.replace("aim_tolerance = [3.0, 8.0] }", "aim_tolerance = [] }")
    text = text.replace("runs = 10, steps = 150000", "runs = 0, steps = 150000")
    path = tmp_path / "population.toml"
    path.write_text(text)
    with pytest.raises(UsageError, match="aim_tolerance = \\[\\]: a list of distinct numbers, at least one"):
        read(path)
