"""A study's config read against the values it fills: each mistake one line in the study's words."""

from __future__ import annotations

import pytest

from services.study.core import StudyConfig
from services.study.crowd import Bonus, Crowd
from shared.config import build

VARIANT = {"name": "a", "bait": "B1", "shooter": "S1"}


def test_a_study_is_built_with_its_nested_tables() -> None:
    config = build(
        StudyConfig,
        {
            "name": "s",
            "variants": [VARIANT],
            "roles": ["bait"],
            "crowd": {"attention_checks": [1], "bonus": {"per_kill": 0.5, "max": 2}},
        },
    )
    assert config.roles == ("bait",) and config.variants[0].names == {**VARIANT, "adapter": ""}
    assert config.crowd == Crowd(attention_checks=(1,), bonus=Bonus(per_kill=0.5, max=2))


@pytest.mark.parametrize(
    ("table", "said"),
    [
        (
            {"name": "s", "variants": [VARIANT], "trial_secnds": 5},
            "trial_secnds: no such setting; valid: name,",
        ),
        ({"variants": [VARIANT]}, "name: missing (a required setting)"),
        ({"name": "s", "variants": [{"bait": "B1"}]}, "variants[0].name: missing"),
        (
            {"name": "s", "variants": [{**VARIANT, "colour": 1}]},
            "variants[0].colour: no such setting; valid: name",
        ),
        ({"name": "s", "variants": [VARIANT], "trials": "3"}, 'trials = "3": a whole number expected'),
        ({"name": "s", "variants": [VARIANT], "trials": 2.5}, "trials = 2.5: a whole number expected"),
        (
            {"name": "s", "variants": [VARIANT], "trial_seconds": True},
            "trial_seconds = true: a number expected",
        ),
        ({"name": "s", "variants": [VARIANT], "roles": "bait"}, 'roles = "bait": a list [...] of texts'),
        ({"name": "s", "variants": VARIANT}, "variants = {"),
        (
            {"name": "s", "variants": [VARIANT], "crowd": {"bonus": {"max": "2"}}},
            'crowd.bonus.max = "2": a number',
        ),
        (
            {"name": "s", "variants": [VARIANT], "crowd": {"attention_checks": ["1"]}},
            'crowd.attention_checks[0] = "1": a whole number expected',
        ),
        (
            {"name": "s", "variants": [VARIANT], "instructions": {"pilot": "fly"}},
            "instructions: a text per role",
        ),
        ({"name": "s", "variants": [VARIANT], "trials": 0}, "need at least one trial"),
    ],
)
def test_a_mistake_is_named(table: dict, said: str) -> None:
    with pytest.raises(ValueError, match=None) as error:
        build(StudyConfig, table)
    assert said in str(error.value)
