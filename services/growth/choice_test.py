import numpy as np
import pytest

from services.growth.choice import (
    Grid,
    best_single,
    groups,
    headroom,
    kmeans,
    oracle,
    partner_groups,
    place,
    regret,
    select,
    shape,
)


def grid(kills: list[list[list[float]]], candidates: str = "abc") -> Grid:
    kills = np.array(kills, float)
    return Grid(tuple(f"p{i}" for i in range(len(kills))), tuple(candidates[: kills.shape[1]]), kills)


def test_oracle_chooses_on_the_other_half():
    # partner 0: a wins on even seeds, b on odd ones; each half is scored by the other's choice
    kills = np.array([[[4, 0, 4, 0], [0, 4, 0, 4]]], float)
    assert oracle(kills) == 0.0  # what each half chose is what the other half loses with
    kills = np.array([[[4, 4, 4, 4], [0, 0, 0, 0]], [[0, 0, 0, 0], [2, 2, 2, 2]]], float)
    assert oracle(kills) == 3.0
    assert best_single(kills) == (0, 2.0)
    assert headroom(kills) == pytest.approx(0.5)


def test_a_single_column_leaves_no_room():
    kills = np.random.default_rng(0).uniform(0, 9, (5, 1, 4))
    assert headroom(kills) == pytest.approx(0.0)


def test_selection_starts_from_the_best_single_and_adds_what_covers():
    # a suits partners 0-1, b partners 2-3, c is a little worse than a everywhere: c adds nothing
    rows = [[[6] * 4, [1] * 4, [5] * 4]] * 2 + [[[2] * 4, [8] * 4, [1] * 4]] * 2
    steps = select(grid(rows), most=3, gain=0.01)
    assert [s["library"] for s in steps] == [["b"], ["b", "a"]]
    assert steps[0]["headroom"] == 0.0
    assert steps[1]["headroom"] == pytest.approx((7 - 4.5) / 4.5, abs=1e-4)


def test_selection_stops_at_its_size():
    rows = [[[9 if j == i else 1] * 2 for j in range(4)] for i in range(4)]
    assert len(select(grid(rows, "abcd"), most=2, gain=0.0)[-1]["library"]) == 2


def test_groups_are_what_works_not_how_well():
    # partners 0 and 1 want a (at very different levels), 2 and 3 want b
    rows = [[[8] * 2, [1] * 2], [[2] * 2, [0.2] * 2], [[1] * 2, [6] * 2], [[0.1] * 2, [3] * 2]]
    label, tried = groups(grid(rows), most=4, bound=0.01, seed=0)
    assert label[0] == label[1] != label[2] == label[3]
    assert [t["groups"] for t in tried] == [1, 2]
    assert tried[-1]["regret"] == 0.0


def test_regret_and_shape():
    means = np.array([[4.0, 2.0], [1.0, 3.0]])
    assert shape(means).max(axis=1).tolist() == [1.0, 1.0]
    assert regret(means, np.array([0, 0])) == pytest.approx(2 / 7)
    assert regret(means, np.array([0, 1])) == 0.0


def test_kmeans_is_seeded():
    rows = np.random.default_rng(1).normal(size=(30, 3))
    assert (kmeans(rows, 3, seed=5) == kmeans(rows, 3, seed=5)).all()


def test_partner_groups_place_new_partners_by_what_works_and_average_the_validation_rows():
    # training: p0 and p1 want a, p2 and p3 want b; validation: v0 wants a (at a low level), v1
    # wants b, and a stand-in of v1 too; teammates a and b (c was a candidate the library left)
    train = grid([[[8] * 2, [1] * 2, [2] * 2], [[4] * 2, [0.5] * 2, [1] * 2],
                  [[1] * 2, [6] * 2, [1] * 2], [[0.1] * 2, [3] * 2, [0.1] * 2]])  # fmt: skip
    label = np.array([0, 0, 1, 1])
    kills = [[[2, 2], [0, 0], [1, 1]], [[1, 1], [5, 3], [0, 0]], [[0, 0], [2, 2], [0, 0]]]
    validation = Grid(("v0", "v1", "human(v1)"), ("a", "b", "c"), np.array(kills, float))
    assert place(validation, train, label).tolist() == [0, 1, 1]
    groups = partner_groups(train, label, validation, ["v0", "v1"], ["a", "b"])
    assert [g["name"] for g in groups] == ["G1", "G2"]
    assert groups[0]["members"] == ["p0", "p1", "v0"] and groups[1]["members"] == ["p2", "p3", "v1"]
    assert groups[0]["values"] == [2.0, 0.0] and groups[0]["partners"] == 1
    assert groups[1]["values"] == [0.5, 3.0] and groups[1]["partners"] == 2  # v1 and its stand-in


def test_groups_the_filter_confuses_are_merged_while_merging_costs_little():
    """G2 and G3 are taken for each other half the time and want the same teammate: merged. G1 is
    told apart and wants another; merging it would cost far more than the regret bound."""
    from services.growth.choice import expected, identified, merge

    confusion = np.array([[90.0, 5.0, 5.0], [5.0, 50.0, 45.0], [5.0, 45.0, 50.0]])
    values = np.array([[8.0, 1.0], [1.0, 6.0], [1.5, 5.0]])
    weight = np.array([10.0, 10.0, 10.0])
    assert identified(confusion) < 0.85
    assert merge(confusion, values, weight, 0.85, 0.05) == [[0], [1, 2]]
    assert merge(confusion, values, weight, 0.5, 0.05) == [[0], [1], [2]]  # identified enough already
    assert 5.0 < expected(confusion, values, weight) < 7.0
    apart = np.array([[80.0, 20.0, 0.0], [20.0, 80.0, 0.0], [0.0, 0.0, 100.0]])
    sharp = np.array([[8.0, 0.0], [0.0, 6.0], [1.5, 5.0]])
    assert identified(apart) < 0.9  # but G1 and G2 want other teammates, and are mostly told apart
    assert merge(apart, sharp, weight, 0.9, 0.05) == [[0], [1], [2]]
