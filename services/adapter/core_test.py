"""The adapter core: window arithmetic, selection from a table, the filter, dwell and fallback."""

from __future__ import annotations

import copy
import json
import math
import re
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.adapter.core import Adapter, AdapterLanes, Payoff, Scorer, Window, ood_threshold, threshold
from services.adapter.skill import FEATURES, LEVELS, SkillModel
from services.agent import library, networks
from services.agent.library_test import empty_library
from services.agent.seats import policy_for
from services.population.adaptive import AdapterConfig
from services.sim import observation as ob
from services.sim.engine import Game
from services.sim.observation import world_values
from shared.errors import UsageError
from shared.game import join_action

# A hand-made table: partner types X, Y, Z (rows) against our policies a, b, c (columns).
PAYOFF = Payoff(
    ("X", "Y", "Z"), ("a", "b", "c"), np.array([[5.0, 1.0, 2.0], [0.0, 4.0, 3.0], [1.0, 1.0, 3.5]])
)
LOW, HIGH = math.log(0.05), math.log(0.8)
HOLDS = {"novice": 100.0, "typical": 200 / 3, "practised": 200 / 3, "library": 100 / 3}


def toy_model(window: int = 60) -> SkillModel:
    """A skill model on the hand-made table: levels told apart by their holds alone (the other
    features alike at every level); with people of any style, b is best."""
    mean = np.zeros((3, len(LEVELS), len(FEATURES)))
    mean[:, :, 0] = [HOLDS[level] for level in LEVELS]
    values = np.tile([1.0, 6.0, 2.0], (3, len(LEVELS) - 1, 1))
    spread = np.tile([1.0, 100.0, 1.0, 100.0], (3, len(LEVELS), 1))  # any key changes, scores
    return SkillModel("shooter", PAYOFF.partners, PAYOFF.ours, window, values, mean, spread, (), "")


def keys_held(frames: int, hold: int) -> np.ndarray:
    """Turning left and right in turn, each for `hold` frames."""
    return np.where(np.arange(frames) // hold % 2 == 0, join_action(1, 0, 0), join_action(2, 0, 0))


def one(config: AdapterConfig, threshold: float | None = None) -> Adapter:
    """One game's adapter on the hand-made table (and, for -skill, a hand-made skill model)."""
    skill = toy_model(config.window) if "skill" in config.strategy else None
    return Adapter(AdapterLanes(config, PAYOFF, 1, threshold, skill))


def frame(best: int, k: int = 3) -> np.ndarray:
    """Scores of one frame in which type `best` finds the action likely and the others do not."""
    scores = np.full(k, LOW)
    scores[best] = HIGH
    return scores


@settings(max_examples=200, deadline=None)
@given(
    size=st.integers(1, 20),
    rows=st.lists(st.lists(st.floats(-20, 0), min_size=3, max_size=3), min_size=1, max_size=80),
)
def test_window_means_match_brute_force(size: int, rows: list[list[float]]) -> None:
    """Lane 0 takes every row, lane 1 every other row, lane 2 none."""
    window = Window(3, 3, size)
    for t, row in enumerate(rows):
        lanes = np.array([0, 1] if t % 2 == 0 else [0])
        window.push(lanes, np.array([row] * len(lanes)))
        for lane, taken in ((0, rows[: t + 1]), (1, rows[: t + 1 : 2])):
            recent = np.array(taken[-size:])
            assert window.filled[lane] == len(recent)
            np.testing.assert_allclose(window.means()[lane], recent.mean(axis=0), atol=1e-9)
        assert window.filled[2] == 0 and not window.means()[2].any()


def test_best_response_and_average_from_a_hand_made_table() -> None:
    assert [PAYOFF.best_response(i) for i in range(3)] == [0, 1, 2]
    assert PAYOFF.best_average() == 2  # column means 2.0, 2.0, 2.83
    assert PAYOFF.best_expected(np.array([0.5, 0.5, 0.0])) == 0  # 2.5, 2.5, 2.5 -> first
    assert PAYOFF.best_expected(np.array([0.4, 0.6, 0.0])) == 1  # 2.0, 2.8, 2.6


def test_payoff_from_the_shipped_table_for_either_seat() -> None:
    from services.table.table import DEFAULT_TABLE, Table

    table = Table.load(DEFAULT_TABLE)
    shooter = Payoff.from_table(table, "shooter")
    bait = Payoff.from_table(table, "bait")
    assert shooter.partners == tuple(library.keys("bait")) and bait.partners == tuple(library.keys("shooter"))
    assert shooter.ours[shooter.best_response(0)] == table.best_shooter("B1")
    assert bait.ours[bait.best_response(0)] == table.best_bait("S1")


def test_cem_plays_the_initial_policy_until_warmup_then_the_best_response() -> None:
    adapter = one(AdapterConfig(window=10, strategy="cem", warmup=5))
    assert adapter.policy == "c" and adapter.partner == ""  # best average
    changes = [adapter.update(frame(1)) for _ in range(5)]
    assert changes == [False] * 4 + [True]
    assert (adapter.partner, adapter.policy) == ("Y", "b")


def test_cem_follows_a_switch_once_the_window_majority_changes() -> None:
    adapter = one(AdapterConfig(window=9, strategy="cem", warmup=9))
    for _ in range(9):
        adapter.update(frame(0))
    assert adapter.policy == "a"
    followed = next(t for t in range(1, 10) if adapter.update(frame(1)))
    assert followed == 5  # the mean favours Y once 5 of the 9 frames are Y's
    assert (adapter.partner, adapter.policy) == ("Y", "b")


def test_dwell_waits_for_a_choice_to_hold_and_ignores_a_blip() -> None:
    config = AdapterConfig(window=4, warmup=1, strategy="cem-dwell", dwell=3)
    adapter = one(config)
    assert [adapter.update(frame(0)) for _ in range(3)] == [False, False, True]
    adapter = one(replace(config, window=1))  # every frame's estimate is that frame's
    pattern = [0, 0, 1, 0, 0, 0]
    changes = [adapter.update(frame(i)) for i in pattern]
    assert changes == [False, False, False, False, False, True]  # the Y blip never held 3 frames
    assert adapter.policy == "a"


def test_out_of_library_partner_falls_back_to_the_best_average() -> None:
    config = AdapterConfig(window=5, warmup=5, strategy="cem-ood")
    adapter = one(config, threshold=-1.0)
    for _ in range(5):
        adapter.update(np.full(3, math.log(0.1)))  # no type explains the actions
    assert adapter.out_of_library and adapter.policy == "c"
    for _ in range(5):
        adapter.update(frame(0))
    assert not adapter.out_of_library and adapter.policy == "a"
    with pytest.raises(ValueError, match="threshold"):
        one(config)


def test_bayes_filter_matches_a_hand_computed_forward_pass() -> None:
    config = AdapterConfig(window=10, warmup=1, strategy="bayes", hazard=0.1, noise=0.2)
    adapter = one(config)
    p1, p2 = np.array([0.6, 0.3, 0.1]), np.array([0.2, 0.5, 0.3])
    adapter.update(np.log(p1))
    adapter.update(np.log(p2))
    belief = np.full(3, 1 / 3)
    for p in (p1, p2):
        predicted = np.array([0.9 * belief[i] + 0.05 * (1 - belief[i]) for i in range(3)])
        post = predicted * (0.8 * p + 0.2 / 12)
        belief = post / post.sum()
    np.testing.assert_allclose(adapter.belief(), belief, rtol=1e-12)
    assert adapter.partner == "XYZ"[int(np.argmax(belief))]
    assert adapter.policy == "abc"[int(np.argmax(belief @ PAYOFF.values))]
    assert set(adapter.status()["belief"]) == {"X", "Y", "Z"}


def test_random_initial_policy_is_drawn_by_seed() -> None:
    drawn = {Payoff.initial(PAYOFF, AdapterConfig(initial="random", seed=s)) for s in range(20)}
    assert drawn == {"a", "b", "c"}
    assert PAYOFF.initial(AdapterConfig(initial="random", seed=3)) == PAYOFF.initial(
        AdapterConfig(initial="random", seed=3)
    )


def test_config_is_validated() -> None:
    with pytest.raises(UsageError, match="--strategy oracle: unknown; valid: cem, "):
        AdapterConfig(strategy="oracle")
    with pytest.raises(UsageError, match="--role pilot: unknown; valid: bait, shooter"):
        AdapterConfig(role="pilot")
    with pytest.raises(UsageError, match=r"--noise 1.0: a probability in \[0, 1\)"):
        AdapterConfig(noise=1.0)
    assert AdapterConfig(window=800).warmup_frames == 150
    assert AdapterConfig(window=400, strategy="cem-dwell").dwell_frames == 40
    assert AdapterConfig(window=400, strategy="cem").dwell_frames == 0


def test_scorer_single_and_batched_agree_with_each_policy() -> None:
    baits = [networks.load(k) for k in library.keys("bait")]
    scorer = Scorer(baits)
    game, circle = Game(seed=4), policy_for("circle", "bait")
    values, actions = [], []
    for t in range(40):
        values.append(world_values(game, "bait"))
        actions.append(circle.act(np.asarray(values[-1], dtype=np.float32)))
        game.step(actions[-1], 0 if t % 2 else 5)
    batched = scorer.batch(np.array(values), np.array(actions))
    single = np.array([scorer(v, a) for v, a in zip(values, actions, strict=True)])
    np.testing.assert_allclose(batched, single, rtol=1e-6)
    assert batched.shape == (40, 9) and np.all(batched < 0)


def test_shipped_calibration_has_a_threshold_per_role() -> None:
    for role in ("bait", "shooter"):
        assert -12.0 < ood_threshold(role, 400) < 0.0
        assert ood_threshold(role, 150) <= ood_threshold(role, 800) + 1e-9


def test_thresholds_of_other_libraries_or_none_are_refused_with_the_remedy(tmp_path, monkeypatch) -> None:
    """A strategy with -ood in a library of yours needs thresholds measured on it, as the table does."""
    mine = empty_library(tmp_path / "mine")
    monkeypatch.setenv("TSF_LIBRARY", str(mine))
    config = AdapterConfig("shooter", 400, "bayes-dwell-ood-guard")
    with pytest.raises(
        UsageError, match=re.escape(f"no out-of-library thresholds at {mine}/calibration.json")
    ):
        threshold(config)
    record = json.loads((library.LIBRARY / "calibration.json").read_text())
    (mine / "calibration.json").write_text(json.dumps(record | {"library": "0123456789abcdef"}))
    with pytest.raises(
        UsageError, match="was measured with library 0123456789abcdef, but the library is now"
    ):
        threshold(config)
    (mine / "calibration.json").write_text(json.dumps(record | {"library": library.manifest_hash()}))
    assert threshold(config) == record["thresholds"]["bait"]["400"]
    assert threshold(AdapterConfig("shooter", 400, "cem-dwell")) is None


def test_frames_of_a_stalled_round_say_nothing_about_the_partner() -> None:
    values = np.zeros(ob.TIME + 1)
    values[ob.SELF + ob.ALIVE] = values[ob.FORTRESS + ob.F_ALIVE] = 1.0  # the partner's partner is dead
    adapter = one(AdapterConfig("shooter", 10, "bayes", warmup=1))
    adapter.update(frame(0), values.tolist())
    assert adapter.filled == 0 and np.allclose(adapter.belief(), 1 / 3)
    values[ob.PARTNER + ob.ALIVE] = 1.0
    adapter.update(frame(0), values.tolist())
    assert adapter.filled == 1 and adapter.belief()[0] > 0.5


@pytest.mark.long
@pytest.mark.slow
def test_lanes_decide_apart_with_the_guard_and_stalled_rounds() -> None:
    """Each lane decides as a one-lane adapter fed that lane's frames alone: partner types that
    change, bursts out of library, stalled rounds (left out of window and filter), kills that keep
    or break the table's promise (the guard) and the dwell doubling per switch."""
    rng = np.random.default_rng(5)
    lanes, frames = 8, 2400
    kind = rng.integers(0, 2, (frames // 600 + 1, lanes))[np.arange(frames) // 600]  # X or Y
    best = np.where(rng.random((frames, lanes)) < 0.7, kind, rng.integers(0, 3, (frames, lanes)))
    scores = np.where(np.arange(3) == best[..., None], HIGH, LOW) + rng.normal(0, 0.1, (frames, lanes, 3))
    scores[700:800, 5] = LOW - 3.0  # out of library for a while
    values = np.zeros((frames, lanes, ob.TIME + 1))
    values[..., ob.SELF + ob.ALIVE] = values[..., ob.FORTRESS + ob.F_ALIVE] = 1.0
    values[..., ob.PARTNER + ob.ALIVE] = (np.arange(frames)[:, None] // 40 + np.arange(lanes)) % 5 != 0
    values[::150, :3, ob.FORTRESS + ob.F_ALIVE] = 0.0  # lanes 0-2 kill every 5 s; the rest never
    actions = np.stack([keys_held(frames, 1 + lane % 3) for lane in range(lanes)], axis=1)  # skill
    actions[1200:, 4] = keys_held(frames - 1200, 1)  # a person's hand, then a policy's
    for strategy in ("bayes-dwell-ood-guard", "cem-dwell", "bayes", "bayes-dwell-ood-guard-skill"):
        config = AdapterConfig("shooter", 60, strategy, warmup=30, dwell=10)
        threshold = 2 * LOW if "ood" in strategy else None
        scalar = [one(config, threshold) for _ in range(lanes)]
        together = AdapterLanes(config, PAYOFF, lanes, threshold, one(config, threshold).lanes.skill)
        for t in range(frames):
            switched = together.update(scores[t], values[t], actions[t])
            alone = [
                a.update(scores[t, i], values[t, i].tolist(), int(actions[t, i]))
                for i, a in enumerate(scalar)
            ]
            assert switched.tolist() == alone, (strategy, t)
            assert [PAYOFF.ours[p] for p in together.policy] == [a.policy for a in scalar], (strategy, t)
        assert together.guarded.tolist() == [a.guarded for a in scalar]
        assert [a.filled for a in scalar] == together.window.filled.tolist()
        if "guard" in strategy:
            assert 0 < sum(a.guarded for a in scalar) < lanes and max(a.switches for a in scalar) >= 2
            assert not any(a.guarded for a in scalar[:3])  # the lanes that kept the promise
        if "skill" in strategy:  # holds of 1, 2, 3 frames by lane; lane 4 a policy from frame 1200
            read = [LEVELS[i] for i in together.levels.argmax(axis=1)]
            assert read == [
                "library",
                "typical",
                "novice",
                "library",
                "library",
                "novice",
                "library",
                "typical",
            ]


# The same table as partner groups: members x1, x2 of group P (row as X's), y of Q (Y's), z of R.
GROUPED = {
    "version": 1,
    "seats": {
        "shooter": {
            "teammates": ["a", "b", "c"],
            "groups": [
                {"name": "P", "members": ["x1", "x2"], "values": [5.0, 1.0, 2.0]},
                {"name": "Q", "members": ["y"], "values": [0.0, 4.0, 3.0]},
                {"name": "R", "members": ["z"], "values": [1.0, 1.0, 3.5]},
            ],
            "thresholds": {"150": -4.0, "400": -3.5},
        }
    },
}


def test_groups_are_identified_by_their_members_and_choose_by_their_rows(tmp_path) -> None:
    (tmp_path / "groups.json").write_text(json.dumps(GROUPED))
    payoff = Payoff.from_groups("shooter", tmp_path / "groups.json")
    assert payoff.partners == ("x1", "x2", "y", "z") and payoff.types == ("P", "Q", "R")
    assert payoff.membership.tolist() == [[1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    config = AdapterConfig("shooter", 20, "bayes-dwell-ood", warmup=10, partners="groups")
    assert threshold(config, payoff) == -4.0  # the nearest calibrated window's
    adapter = Adapter(AdapterLanes(config, payoff, 1, -4.0))
    # the partner looks like x1 and x2 in turn: one group, whose answer is a, though no member
    # alone is sure of it
    for t in range(60):
        scores = np.full(4, LOW)
        scores[t % 2] = HIGH
        adapter.update(scores)
    assert adapter.partner == "P" and adapter.policy == "a"
    assert adapter.belief().sum() == pytest.approx(1.0) and adapter.belief()[0] > 0.9
    status = adapter.status()
    assert set(status["scores"]) == set(status["belief"]) == {"P", "Q", "R"}
    assert status["scores"]["P"] == pytest.approx(max(adapter.lanes.window.means()[0][:2]))
    for _ in range(200):  # then like y: group Q, played with b
        adapter.update(frame(2, 4))
    assert (adapter.partner, adapter.policy) == ("Q", "b")


def test_groups_missing_or_uncalibrated_are_one_line(tmp_path) -> None:
    with pytest.raises(UsageError, match="no partner groups for the bait seat"):
        Payoff.from_groups("bait", tmp_path / "none.json")
    uncalibrated = copy.deepcopy(GROUPED)
    del uncalibrated["seats"]["shooter"]["thresholds"]
    (tmp_path / "groups.json").write_text(json.dumps(uncalibrated))
    payoff = Payoff.from_groups("shooter", tmp_path / "groups.json")
    with pytest.raises(UsageError, match="no out-of-group thresholds"):
        threshold(AdapterConfig(partners="groups"), payoff)
    with pytest.raises(UsageError, match="skill model knows the library's policies"):
        AdapterConfig(strategy="bayes-dwell-ood-guard-skill", partners="groups")


def _groups(**change: object) -> dict:
    """GROUPED with the shooter seat's Q group (or, with `groups`, its group list) changed."""
    record = copy.deepcopy(GROUPED)
    seat = record["seats"]["shooter"]
    if "groups" in change:
        seat["groups"] = change.pop("groups")
    seat["groups"][1:2] = [seat["groups"][1] | change] if seat["groups"] else []
    return record


@pytest.mark.parametrize(
    ("record", "says"),
    [
        # no groups: once loaded, and a log of zero after the match had started
        (_groups(groups=[]), "seats.shooter: groups and teammates: at least one of each"),
        (_groups(members=[]), "groups[1]: group Q: members = []: at least one member"),
        (_groups(values=[0.0, 4.0]), "group Q: 2 values for 3 teammates"),
        (_groups(values=[0.0, "4", 3.0]), 'groups[1].values[1] = "4": a number expected'),
        (_groups(member=["y"]), "groups[1].member: no such setting"),
    ],
)
def test_a_wrong_groups_file_is_refused_before_play(tmp_path, record, says) -> None:
    path = tmp_path / "groups.json"
    path.write_text(json.dumps(record))
    with pytest.raises(UsageError, match=f"^groups {path}: seats.shooter") as error:
        Payoff.from_groups("shooter", path)
    assert says in str(error.value) and "\n" not in str(error.value)
