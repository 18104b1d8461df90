"""The skill estimate: a person's level from the window, and the choice from the skill table where
the partner is a person, from P where it is a library policy."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from services.adapter.core import AdapterLanes, build_lanes, skill_model
from services.adapter.core_test import PAYOFF, keys_held, toy_model
from services.adapter.skill import LEVELS, skill_path
from services.agent import library
from services.evaluation.evaluate import play_games, setup
from services.evaluation.evaluate_test import seated
from services.population.adaptive import AdapterConfig
from services.sim import observation as ob
from shared.errors import UsageError


def test_a_person_gets_the_skill_tables_choice_and_a_policy_ps() -> None:
    """X's best response in P is a, the best average c; with people the toy skill table says b."""
    config = AdapterConfig("shooter", 60, "bayes-dwell-ood-guard-skill", warmup=30, dwell=10)
    lanes = AdapterLanes(config, PAYOFF, 3, threshold=-20.0, skill=toy_model())
    actions = np.stack([keys_held(300, 3), keys_held(300, 2), keys_held(300, 1)], axis=1)
    values = np.zeros((3, ob.TIME + 1))
    values[:, ob.SELF + ob.ALIVE] = values[:, ob.FORTRESS + ob.F_ALIVE] = values[:, ob.PARTNER + ob.ALIVE] = 1
    scores = np.log([[0.8, 0.05, 0.05]] * 3)  # every lane plays like X
    for t in range(300):
        lanes.update(scores, values, actions[t])
    assert [LEVELS[i] for i in lanes.levels.argmax(axis=1)][::2] == ["novice", "library"]
    assert lanes.levels[1, 1:3].sum() > 0.99  # a hold of 2 frames: typical or practised
    assert [PAYOFF.ours[p] for p in lanes.policy] == ["b", "b", "a"]
    assert lanes.switches.tolist() == [1, 1, 1]  # once, from the best average
    held = np.array([[100.0, 12.0, 0.0, -0.2], [250.0, 12.0, 0.0, -0.2]])  # 3 frames; 7.5 (no level's)
    posterior, plausible = toy_model().posterior(held, np.full((2, 3), 1 / 3))
    assert posterior[:, 0].tolist() == pytest.approx([1.0, 1.0]) and plausible.tolist() == [True, False]


def test_a_model_of_other_libraries_or_windows_is_refused_with_the_remedy(tmp_path) -> None:
    config = AdapterConfig("shooter", 400, "bayes-dwell-ood-guard-skill")
    payoff = setup("shooter").payoff
    assert skill_model(config, payoff).teammates == payoff.ours
    record = json.loads(skill_path().read_text())
    path = tmp_path / "skill.json"
    path.write_text(json.dumps(record | {"library": "0123456789abcdef"}))
    with pytest.raises(UsageError, match=re.escape("0123456789abcdef") + ".*tsf skill-model"):
        skill_model(config, payoff, path)
    with pytest.raises(UsageError, match="no skill model"):
        skill_model(config, payoff, tmp_path / "none.json")
    with pytest.raises(UsageError, match="window"):
        skill_model(AdapterConfig("shooter", 150, "bayes-dwell-ood-guard-skill"), payoff)
    assert record["library"] == library.manifest_hash() and skill_model(AdapterConfig(), payoff) is None


@pytest.mark.slow
def test_the_shipped_model_recovers_the_stand_ins_skill() -> None:
    """Stand-ins of two styles at each skill, and the library policies, on seeds neither the model
    (64-75) nor the skill table (0-19) played: a novice is read as a novice, a typical or practised
    hand as one of the two (they share their shortest press, so the window barely tells them apart),
    a policy as a policy, each at the end of the game."""
    config = AdapterConfig(strategy="bayes-dwell-ood-guard-skill")
    names = [f"human({s},skill={k})" for s in ("B1", "B5") for k in LEVELS[:-1]] + ["B1", "B5"]
    games = [(name, config, seed) for name in names for seed in (96, 97)]
    adapter = build_lanes(config, len(games), setup("shooter").payoff)
    play_games(seated(games), "shooter", adapters={config: adapter})
    read = {}
    for (name, _, _), levels in zip(games, adapter.levels, strict=True):
        level = re.search(r"skill=(\w+)", name)[1] if "skill" in name else "library"
        read.setdefault(level, []).append(levels)
    assert all(p[0] > 0.9 for p in read["novice"]) and all(p[3] > 0.9 for p in read["library"])
    assert all(p[1] + p[2] > 0.9 for p in read["typical"] + read["practised"])
