"""The search on a toy objective: it finds each study's known optimum from a random start, the same
settings under the same seed, and a search resumed from its file asks what an unbroken one asks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from services.growth.library import rule_settings
from services.growth.search import WHOLE, best, curve, found, name_of, plan_of, tune

pytest.importorskip("optuna", reason="the `search` extra is not installed")

# Two partners, each with its own best circle (radius, speed); `outside` does not matter.
OPTIMA = {"near": (80.0, 1.0), "far": (170.0, 3.5)}


def toy(names: list[str]) -> np.ndarray:
    """Kills/min of each setting with each partner: 10 at the partner's optimum, less away from it."""
    rows = []
    for name in names:
        s = rule_settings(name)
        rows.append(
            [10 - ((s["radius"] - r) / 30) ** 2 - ((s["speed"] - v) / 1.0) ** 2 for r, v in OPTIMA.values()]
        )
    return np.array(rows)


def plan(trials: int):  # noqa: ANN201
    return plan_of("circle", [["near"], ["far"]], trials, seeds=8, seed=3)


def test_names_are_the_partner_grammar():
    assert name_of("circle", {"radius": 112.0, "speed": 1.25, "outside": 240.0}) == (
        "circle(radius=112,speed=1.25,outside=240)"
    )


def test_each_group_s_study_finds_its_partner_s_optimum(tmp_path):
    record = tune(plan(45), toy, tmp_path / "s.json", say=lambda _: None)
    assert len(record["trials"]) == 45
    tops = best(record)
    for group, (radius, speed) in zip(("G1", "G2"), OPTIMA.values(), strict=True):
        setting = tops[group]["setting"]
        assert abs(setting["radius"] - radius) < 25 and abs(setting["speed"] - speed) < 0.8
        assert tops[group]["value"] > 9.0
        assert curve(record, group)[-1] > curve(record, group)[2]  # better than the random start
    assert set(found(record)) >= {tops["G1"]["name"], tops["G2"]["name"]}
    assert WHOLE in tops


def test_the_same_seed_searches_alike_and_a_resumed_search_as_an_unbroken_one(tmp_path):
    whole = tune(plan(12), toy, tmp_path / "a.json", say=lambda _: None)
    tune(plan(6), toy, tmp_path / "b.json", say=lambda _: None)  # stopped after two rounds
    resumed = tune(plan(12), toy, tmp_path / "b.json", say=lambda _: None)
    assert resumed == whole == json.loads((tmp_path / "a.json").read_text())
    other = plan_of("circle", [["near"], ["far"]], 12, seeds=8, seed=4)
    assert tune(other, toy, tmp_path / "c.json", say=lambda _: None)["trials"] != whole["trials"]


def test_a_file_of_another_search_is_not_resumed(tmp_path):
    tune(plan(3), toy, tmp_path / "s.json", say=lambda _: None)
    other = plan_of("circle", [["near", "far"]], 6, seeds=8, seed=3)
    with pytest.raises(ValueError, match="another search"):
        tune(other, toy, tmp_path / "s.json", say=lambda _: None)
