"""The comparison's figures at a glance (team._glance, results._against_references) on a small
games table whose numbers are worked out by hand here."""

from __future__ import annotations

import json
import math

import pytest

from services.evaluation.populations import listed
from services.evaluation.results import BEST, PREVIOUS, STUDY, Comparison, TeamGame, write_results
from services.evaluation.team import compare
from services.population.adaptive import SHIPPED
from shared.game import other

DEFAULT, WORSE = SHIPPED.name, "adaptive-T150-cem"
# partner -> agent -> kills/min of each seed: B1 and B2 are library partners, noisy(B1) a noisy one
# (the partner kinds are the parts); noisy(B1) has four seeds, the others two, so that the partner
# as the unit (each partner's mean counts once) differs from the game.
TABLE = {
    "B1": {"S1": 2.0, "S2": 1.0, "GS1": 4.0, DEFAULT: 6.0, WORSE: 3.5},
    "B2": {"S1": 0.0, "S2": 0.5, "GS1": 0.5, DEFAULT: 0.5, WORSE: 0.0},  # no teammate scores 1 kill/min
    "noisy(B1)": {"S1": 3.0, "S2": 2.0, "GS1": 2.0, DEFAULT: 1.5, WORSE: 1.5},
}
SEEDS = {"B1": 2, "B2": 2, "noisy(B1)": 4}


def games(table: dict[str, dict[str, float]] = TABLE) -> list[TeamGame]:
    return [
        TeamGame(partner, agent, seed, kills, 0, 0)
        for partner, by_agent in table.items()
        for agent, kills in by_agent.items()
        for seed in range(SEEDS[partner])
    ]


def test_the_default_against_every_reference_with_the_game_and_the_partner_as_the_unit() -> None:
    """By hand: over the 8 games GS1 scores 17/8 = 2.125 (the best static), S1 16/8 = 2.0 (the
    study's best), the default 19/8 = 2.375. Its differences from GS1 per game are +2, +2, 0, 0 and
    -0.5 four times: mean 0.25 (+11.76 %), s.e. sqrt(8.5/7/8); per partner +2, 0, -0.5: mean 0.5
    over GS1's partner mean 6.5/3 (+23.08 %), s.e. sqrt(1.75/3). The gain of 1.5 comes 2 from the
    library partners and -0.5 from the noisy one: the library's share 4/3."""
    c = compare(games())
    assert c.references == {BEST: "GS1", STUDY: "S1", PREVIOUS: "GS1"} and c.unplayed == {}
    assert c.scoring == ["B1", "noisy(B1)"]  # B2's best teammate scores 0.5
    best = c.glance[DEFAULT]["all"][BEST]
    assert best["mean"] == pytest.approx(2.375) and best["reference"] == pytest.approx(2.125)
    assert best["games"]["difference"] == pytest.approx(0.25) and best["games"]["n"] == 8
    assert best["games"]["percent"] == pytest.approx(100 * 0.25 / 2.125)
    assert best["games"]["stderr"] == pytest.approx(math.sqrt(8.5 / 7 / 8))
    assert best["partners"]["difference"] == pytest.approx(0.5) and best["partners"]["n"] == 3
    assert best["partners"]["percent"] == pytest.approx(100 * 0.5 / (6.5 / 3))
    assert best["partners"]["stderr"] == pytest.approx(math.sqrt(1.75 / 3))
    assert best["part_shares"] == pytest.approx({"library": 4 / 3, "noisy": -1 / 3})
    assert best["top_part"] == "library" and best["top_share"] == pytest.approx(4 / 3)
    # the tests over games and over partners are the comparison's own (p_t, p_t_partners)
    assert best["games"]["p"] == pytest.approx(c.tests[DEFAULT]["p_t"])
    assert best["partners"]["p"] == pytest.approx(c.tests[DEFAULT]["p_t_partners"])
    # against S1: per game +4, +4, +0.5, +0.5, -1.5 x 4 (mean 3/8 of 2.0); per partner +4, +0.5,
    # -1.5 (mean 1 of 5/3); the library's share 4.5 of 3
    study = c.glance[DEFAULT]["all"][STUDY]
    assert study["games"]["percent"] == pytest.approx(100 * 0.375 / 2.0)
    assert study["partners"]["percent"] == pytest.approx(60.0)
    assert study["top_part"] == "library" and study["top_share"] == pytest.approx(1.5)


def test_the_partners_who_can_score_and_a_gain_that_is_not_one() -> None:
    """On B1 and noisy(B1) (6 games): the default 18/6 = 3.0 against GS1's 16/6, +1/3 per game
    (+12.5 %), +2 and -0.5 per partner (+0.75 of 3: +25 %). WORSE gains -0.5, 0 and -0.5 over GS1
    per partner: no gain to share, so no top part."""
    c = compare(games())
    scoring = c.glance[DEFAULT]["scoring"][PREVIOUS]
    assert scoring["mean"] == pytest.approx(3.0) and scoring["reference"] == pytest.approx(16 / 6)
    assert scoring["games"]["percent"] == pytest.approx(12.5) and scoring["games"]["n"] == 6
    assert scoring["partners"]["percent"] == pytest.approx(25.0) and scoring["partners"]["n"] == 2
    assert scoring["top_share"] == pytest.approx(4 / 3)
    worse = c.glance[WORSE]["all"][BEST]
    assert worse["top_part"] is None and worse["top_share"] is None and worse["part_shares"] == {}


def test_the_summary_gives_the_default_first_and_labelled_and_reads_older_files(tmp_path) -> None:  # noqa: ANN001
    c = compare(games())
    text = write_results(tmp_path, None, games(), c, "listed").read_text()
    section = text[text.index("## Against fixed references") : text.index("## Team performance")]
    rows = [line for line in section.splitlines() if line.startswith("| adaptive-")]
    assert len(rows) == 8  # 2 agents x 2 sets of partners x 2 references (GS1 is best and previous)
    assert rows[0] == (
        f"| {DEFAULT} (default) | all (3) | GS1 (best static, previous default) | 2.375 / 2.125 | "
        "+0.250 ± 0.390 (+11.8 %) | +0.500 ± 0.764 (+23.1 %) | "
        f"{c.tests[DEFAULT]['p_t']:.2g} / {c.tests[DEFAULT]['p_t_partners']:.2g} | library: 133 % |"
    )
    assert rows[1].startswith(f"| {DEFAULT} (default) | all (3) | S1 (study's best static) | 2.375 / 2.000 |")
    assert rows[2].startswith(f"| {DEFAULT} (default) | can score (2) | GS1 ")
    assert rows[4].startswith(f"| {WORSE} | all (3) |") and rows[4].endswith("| not defined |")
    assert "who can score (a static teammate at 1 kill/min or more: 2 of 3)" in section
    assert f"| {DEFAULT} (default) | +11.8 % |" in text  # the table at the top marks it too
    # an older comparison.json (before these figures) reads back with them empty, and says nothing
    older = {k: v for k, v in json.loads((tmp_path / "comparison.json").read_text()).items()}
    for key in ("references", "unplayed", "scoring", "glance"):
        del older[key]
    read = Comparison.of(older)
    assert (read.references, read.unplayed, read.scoring, read.glance) == ({}, {}, [], {})
    assert (
        read.tests == c.tests
        and "## Against fixed references" not in write_results(tmp_path / "older", None, [], read).read_text()
    )


def test_the_studys_best_static_is_the_study_librarys_whatever_tsf_library_adds(monkeypatch) -> None:
    """A library in TSF_LIBRARY (here the tuned one, whose TS1 scores best) is compared among the
    statics, but the study's best static stays the study library's own."""
    monkeypatch.setenv("TSF_LIBRARY", "tuned")
    table = {
        "P1": {"S1": 2.0, "S2": 1.0, "TS1": 5.0, DEFAULT: 4.0},
        "P2": {"S1": 1.0, "S2": 3.0, "TS1": 4.0, DEFAULT: 3.0},
    }
    played = [TeamGame(p, a, s, k, 0, 0) for p, by in table.items() for a, k in by.items() for s in range(2)]
    c = compare(played, listed(tuple(table), "bait"))
    assert c.references[BEST] == "TS1" and c.references[STUDY] == "S2"


@pytest.mark.parametrize(
    ("role", "statics", "references", "unplayed"),
    [  # the bait seat without GB1; the shooter seat with the grown library's GS2 only
        ("bait", ("B2", "B3"), {BEST: "B3", STUDY: "B3"}, {PREVIOUS: "GB1"}),
        ("shooter", ("GS2",), {BEST: "GS2"}, {STUDY: "any of S1, S2, S3, S4, S5, S6, S7", PREVIOUS: "GS1"}),
    ],
)
def test_a_reference_that_was_not_played_is_said_to_be(tmp_path, role, statics, references, unplayed) -> None:  # noqa: ANN001
    table = {"P1": [2.0, 3.0, 4.0], "P2": [1.0, 3.0, 2.0]}  # kills/min: statics, then the default
    agents = (*statics, DEFAULT)
    played = [
        TeamGame(p, a, s, k, 0, 0)
        for p, kills in table.items()
        for a, k in zip(agents, kills[-len(agents) :], strict=True)
        for s in range(2)
    ]
    c = compare(played, listed(tuple(table), other(role)))
    assert (c.references, c.unplayed) == (references, unplayed)
    text = write_results(tmp_path, None, played, c, "listed").read_text()
    for label, asked in unplayed.items():
        assert f"Not played in these games: the {label} ({asked}), so no comparison with it." in text
