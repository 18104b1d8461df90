"""The evaluation core: adaptive games (batched, replayed on the scalar engine), sessions, window
arithmetic, following lags and the statistics."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from services.adapter import core
from services.agent import networks
from services.agent.library import NAMED
from services.evaluation.evaluate import batches, play_games, play_session, play_teams, setup
from services.evaluation.evaluate import policy as ours
from services.evaluation.identification import follow_lag, windowed
from services.evaluation.results import TeamGame, population_of, read_games, write_results
from services.evaluation.team import compare, holm, known_partner, paired_tests, variants
from services.population.adaptive import AdapterConfig
from services.population.seat import AdaptiveSeat, PolicySeat, SeatSpec, seats_of
from services.sim.batch_play import play_batch
from services.sim.engine import Game
from services.sim.observation import observe, world_values
from services.sim.sampling import lane_uniforms, sample
from services.table.table import DEFAULT_TABLE, Table
from shared.errors import UsageError
from shared.game import GameConfig, scoring


def seated(games: list[tuple]) -> list[tuple[SeatSpec, SeatSpec, int]]:
    """(partner name, our key or AdapterConfig, seed) games as play_games takes them: as seats."""
    return [
        (SeatSpec.parse(p), AdaptiveSeat(a) if isinstance(a, AdapterConfig) else SeatSpec.parse(a), seed)
        for p, a, seed in games
    ]


def test_windowed_means_match_brute_force() -> None:
    scores = np.random.default_rng(0).normal(size=(50, 3))
    means = windowed(scores, 7)
    assert means.shape == (44, 3)
    for i in (0, 10, 43):
        np.testing.assert_allclose(means[i], scores[i : i + 7].mean(axis=0))


def test_follow_lag_needs_the_estimate_to_hold() -> None:
    estimates = np.array([0] * 10 + [1, 0] + [1] * 40)
    assert follow_lag(estimates, 1, 10, hold=30) == 2
    assert follow_lag(np.array([0] * 50), 1, 10) is None
    assert follow_lag(np.array([0] * 45 + [1] * 5), 1, 10) == 35  # held to the end of the game


def test_variant_names_round_trip() -> None:
    names = variants([150, 400], ["cem", "bayes"])
    assert names == ["adaptive-T150-cem", "adaptive-T400-cem", "adaptive-T400-bayes"]
    assert AdapterConfig.parse("adaptive-T400-bayes", role="bait") == AdapterConfig("bait", 400, "bayes")
    assert SeatSpec.parse("S5").adaptive("shooter") is None  # a static policy's key
    with pytest.raises(UsageError):
        AdapterConfig.parse("S5", role="shooter")


def test_adaptive_game_switches_to_the_best_response_and_is_deterministic() -> None:
    config = AdapterConfig("shooter", 150, "cem")
    first, again = play_games(seated([("B3", config, 4), ("B3", config, 4)]), "shooter")
    assert first == again
    assert first.timeline[0][1:] == ("B3", Table.load(DEFAULT_TABLE).best_shooter("B3"))
    assert first.timeline[0][0] == 150  # decided on the warm-up's last frame, played from the next


@pytest.mark.long
@pytest.mark.slow
def test_a_session_is_its_games_one_after_another_with_the_adapter_carried() -> None:
    """Without -memory a session's trials are the games of their seeds, as in any batch; with it
    the first trial is the same game and the next ones start where the adapter left off."""
    forgetting = AdapterConfig("shooter", 150, "bayes-dwell-ood-guard")
    remembering = dataclasses.replace(forgetting, strategy="bayes-dwell-ood-guard-memory")
    alone = play_games(
        seated([("B3", forgetting, seed) for seed in (3, 4, 5)]), "shooter"
    )  # person 1's seeds
    assert play_session(PolicySeat("B3"), AdaptiveSeat(forgetting), 1, "shooter") == alone
    carried = play_session(PolicySeat("B3"), AdaptiveSeat(remembering), 1, "shooter")
    assert carried[0] == alone[0] and alone[1].timeline[0][0] >= 150  # warm-up first
    assert sum(o.switches for o in carried[1:]) < sum(o.switches for o in alone[1:])


def test_compare_pairs_by_partner_and_seed() -> None:
    rng = np.random.default_rng(1)
    rows, truth = [], {}
    for partner in ("P1", "P2", "P3"):
        for seed in range(6):
            base = rng.normal(5, 1)
            for agent, shift in (("S1", 0.0), ("S2", -1.0), ("adaptive-T150-cem", 0.5 + rng.normal(0, 0.3))):
                switches = 2 if agent.startswith("adaptive") else 0
                rows.append(TeamGame(partner, agent, seed, base + shift, switches, 0))
                truth.setdefault(agent, []).append(base + shift)
    result = compare(rows)
    assert result.best_static == "S1" and result.units == 18
    test = result.tests["adaptive-T150-cem"]
    expected = stats.ttest_rel(truth["adaptive-T150-cem"], truth["S1"], alternative="greater")
    assert np.isclose(test["p_t"], expected.pvalue) and test["p_t"] < 1e-6
    diff = np.array(truth["adaptive-T150-cem"]) - np.array(truth["S1"])
    assert np.isclose(test["d_z"], diff.mean() / diff.std(ddof=1))
    assert test["partners_better"] == 3
    assert np.isclose(result.agents["S2"]["mean"], np.mean(truth["S2"]))
    assert result.per_partner["P2"]["S1"]["n"] == 6 and set(result.per_part) == {"outside"}
    assert result.parts == "kind"  # a list of partners is broken down by their kinds
    assert np.isclose(result.per_partner["P2"]["S1"]["mean"], np.mean(truth["S1"][6:12]))
    assert result.switches["adaptive-T150-cem"] == {"mean": 2.0, "max": 2, "guarded_games": 0}
    by_kind = result.tests_by_part["adaptive-T150-cem"]["outside"]
    assert by_kind["noninferior"] and by_kind["p_superior"] == test["p_t"] == test["p_holm"]
    known = result.known_partner  # S1 is every partner's best: knowing them gains nothing
    assert known["all"]["mean_difference"] == 0 and known["outside"]["mean"] == result.agents["S1"]["mean"]


@pytest.mark.parametrize("trial", [None, 2])
def test_an_evaluations_games_read_back_as_written(tmp_path, trial) -> None:  # noqa: ANN001 - a Path
    """`tsf eval --games` analyses a team.csv again: its games read back equal (sessions' trials
    too), and the summary made from them names the headroom of knowing each partner."""
    games = [
        TeamGame(p, a, seed, 0.5 * seed + (a == "S2"), seed % 2, 0, trial)
        for p in ("B1", "human(B5)") for a in ("S1", "S2", "adaptive-T150-cem") for seed in range(4)
    ]  # fmt: skip
    summary = write_results(tmp_path, None, games, compare(games), "listed").read_text()
    assert read_games(tmp_path / "team.csv") == games and population_of(tmp_path / "team.csv") == "listed"
    assert "Knowing each partner in advance" in summary
    assert "| known partner - S2 | +0.00 ± 0.00 (+0.0 %)" in summary


def test_knowing_the_partner_chooses_on_its_other_seeds() -> None:
    """Each game is scored by the static policy chosen on the partner's other half of seeds, not on
    itself: with P2 the choice on seed 1 (S2) plays seed 0, and the one on seed 0 (S1) seed 1."""
    units = [("P1", s) for s in range(4)] + [("P2", 0), ("P2", 1), ("P3", 7)]
    grid = {
        "S1": dict(zip(units, [5, 5, 5, 5, 5, 3, 2], strict=True)),
        "S2": dict(zip(units, [6, 6, 6, 6, 4, 4, 1], strict=True)),
    }
    assert known_partner(grid, ["S1", "S2"], units).tolist() == [6, 6, 6, 6, 4, 3, 2]


GUARD = "bayes-dwell-ood-guard"
GAMES = [
    ("B3", AdapterConfig("shooter", 150, "cem"), 4),
    ("noisy(B6)", AdapterConfig("shooter", 150, "cem-dwell"), 1),
    ("circle", AdapterConfig("shooter", 400, "bayes-dwell-ood"), 2),
    ("sticky(switch(B1,B5))", AdapterConfig("shooter", 150, "bayes"), 3),
    ("delayed(B2)", "S6", 5),
    ("human(B1)", AdapterConfig("shooter", 150, GUARD), 6),
    ("human(B1,B5)", AdapterConfig("shooter", 150, GUARD), 7),
    (
        "noisy(circle(radius=140,speed=1.5,outside=215))",
        AdapterConfig("shooter", 150, "bayes", partners="groups"),
        8,
    ),
]


@pytest.fixture
def grown_groups(monkeypatch: pytest.MonkeyPatch):
    """The grown library's partner groups as the groups in use (the previous default's: the tuned
    library's groups all want one member, so its agent never switches), read afresh."""
    monkeypatch.setattr(core, "GROUPS", NAMED["grown"] / "groups.json")
    setup.cache_clear()
    yield
    setup.cache_clear()


@pytest.mark.long
@pytest.mark.slow
@pytest.mark.usefixtures("grown_groups")
def test_batched_adaptive_games_decide_as_the_scalar_engine_replays_them() -> None:
    """Replay each batched game's actions on the scalar engine with the Scorer on world values and
    a one-game Adapter: the same states and scores, switches at the same frames to the same
    policies, the same kills; and our seat's every action is the draw of the policy the timeline
    says was playing; under the guard and with human-like partners too (the groups of the grown
    library, whose agent switches)."""
    config = GameConfig(frames=900)
    played = play_games(seated(GAMES), "shooter", config, record=True, score="library")
    assert play_games(seated(GAMES[1:2]), "shooter", config)[0] == dataclasses.replace(
        played[1], values=None, actions=None, scores=None, pairs=None
    )
    library = setup("shooter").scorer
    for (_, agent, seed), outcome in zip(GAMES, played, strict=True):
        game = Game(config, seed)
        adaptive = isinstance(agent, AdapterConfig)
        s = setup("shooter", agent.partners if adaptive else "library")
        adapter = core.build(agent, s.payoff) if adaptive else None
        policy = ours(adapter.policy if adapter else agent, "shooter")
        timeline, switches, playing = [], 0, adapter.policy if adapter else agent
        for frame, (bait, shooter) in enumerate(outcome.pairs.tolist()):
            probs = policy.probs(observe(game, "shooter", policy.view))
            assert shooter == sample(probs[None], lane_uniforms(np.array([seed]), 1, frame))[0]
            values = world_values(game, "bait")
            np.testing.assert_allclose(outcome.values[frame], values, rtol=1e-6, atol=1e-6)  # float32
            assert outcome.actions[frame] == bait
            np.testing.assert_allclose(outcome.scores[frame], library(values, bait), rtol=1e-12)
            if adapter is not None:
                switches += adapter.update(s.scorer(values, bait), values)
                if scoring(frame) and adapter.policy != playing:  # the ruling: from the next frame
                    timeline.append((frame + 1, adapter.partner, adapter.policy))
                    playing, policy = adapter.policy, ours(adapter.policy, "shooter")
            game.step(bait, shooter)
        assert outcome.timeline == timeline and outcome.switches == switches
        assert outcome.kills_per_minute == game.kills_per_minute()
        assert outcome.guarded == (adapter is not None and adapter.guarded)
    p = setup("shooter").payoff
    best = p.ours[p.best_response(p.partners.index("B3"))]  # the table's answer to B3
    assert sum(o.switches for o in played) > 4 and played[0].timeline[0][1:] == ("B3", best)
    assert [o.switches for o in played[5:7]] == [3, 2]  # under the guard's doubling dwell
    assert played[7].timeline[0][1:] == ("G4", "GS2")  # the one group whose best member is not GS1


def test_teams_of_partners_play_both_seats_as_the_batched_pair_games() -> None:
    """Library keys on both seats draw as play_batch's seats do, so the games are the same;
    recorded actions and openings come back per team and seed."""
    frames = GameConfig(frames=300)
    kills, actions, opened = play_teams(
        [seats_of(["B5", "S4"]), seats_of(["human(B5)", "S4"])], [0, 1], frames, record=True
    )
    pair = play_batch(networks.load("B5"), networks.load("S4"), [0, 1], frames)
    assert kills[0].tolist() == [r.kills_per_minute for r in pair]
    assert actions.shape == (2, 2, 300, 2) and opened.shape == (2, 2, 301)
    assert opened[0].any() and (actions[1, :, :, 0] != actions[0, :, :, 0]).any()


def test_batches_cover_every_game_once_in_order() -> None:
    items = list(range(103))
    for workers, lanes in ((1, 1024), (2, 1024), (2, 10), (8, 50)):
        parts = batches(items, workers, lanes)
        assert [i for part in parts for i in part] == items
        assert max(map(len, parts)) - min(map(len, parts)) <= 1
        assert max(map(len, parts)) <= lanes and len(parts) >= workers


def test_holm_and_non_inferiority() -> None:
    adjusted = holm({"a": 0.01, "b": 0.04, "c": 0.03})
    assert adjusted == {"a": 0.03, "c": 0.06, "b": 0.06}
    rng = np.random.default_rng(2)
    slightly_worse = rng.normal(-0.03, 0.1, 400)  # within the 0.1 margin
    much_worse = rng.normal(-0.3, 0.1, 400)
    assert paired_tests(slightly_worse)["noninferior"] and not paired_tests(much_worse)["noninferior"]
    assert paired_tests(slightly_worse)["p_superior"] > 0.5


def test_a_member_left_out_leaves_its_group_and_the_others_as_they_were() -> None:
    from services.evaluation.identification import _without

    payoff = setup("shooter", "groups").payoff
    k = payoff.partners.index("B4")
    left = _without(payoff, k)
    assert "B4" not in left.partners and len(left.partners) == len(payoff.partners) - 1
    assert left.types == payoff.types and (left.type_values == payoff.type_values).all()
    assert left.membership.sum(axis=0).tolist() == [
        n - (j == payoff.group[k]) for j, n in enumerate(payoff.membership.sum(axis=0).tolist())
    ]


def test_a_partner_nobody_scores_with_is_a_result_and_a_zero_base_is_not_defined(tmp_path) -> None:  # noqa: ANN001
    """Every agent scores 0 with P1: the summary says so, and each effect in % of the best static
    policy's mean of 0 is "not defined" (no ZeroDivisionError after every game was played)."""
    games = [
        TeamGame("P1", a, seed, 0.0, 0, 0) for a in ("S1", "S2", "adaptive-T150-cem") for seed in range(4)
    ]
    comparison = compare(games)
    assert comparison.scoreless == ["P1"] and comparison.effect("adaptive-T150-cem") is None
    summary = write_results(tmp_path, None, games, comparison, "listed").read_text()
    assert "No agent scores with 1 of the 1 partners (0 kills/min with every agent): P1." in summary
    assert "| adaptive-T150-cem | not defined |" in summary
