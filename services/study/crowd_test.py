"""The crowd-sourcing rules as pure functions: the bonus, the bulk-bonus file, redirects, which
trial an attention check comes before, and the [crowd] table of a study's TOML file."""

from __future__ import annotations

import pytest

from services.study.core import StudyConfig, Variant
from services.study.crowd import Bonus, Crowd, attention_check, bonus_file
from shared.errors import UsageError


def test_the_bonus_pays_per_kill_and_point_up_to_its_cap():
    rule = Bonus(per_kill=0.05, per_point=0.001, max=2.0)
    assert rule.amount([(3, 200), (1, -500)]) == 0.40  # 4 kills 0.20, 200 points 0.20, a loss counts 0
    assert rule.amount([(100, 0)]) == 2.0 and rule.amount([]) == 0.0
    for bad in ({"max": 0.0}, {"per_kill": -1.0, "max": 1.0}):
        with pytest.raises(ValueError, match="bonus"):
            Bonus(**bad)


def test_the_bonus_file_is_the_platforms_bulk_format_without_zero_rows():
    assert bonus_file([("5f00aa", 1.5), ("P002", 0.0), ("a,b", 0.25)]) == '5f00aa,1.50\n"a,b",0.25\n'


def test_redirects_take_the_code_and_only_web_addresses_are_taken():
    crowd = Crowd(completion_url="https://app.prolific.com/submissions/complete?cc={code}")
    assert (
        crowd.redirect(crowd.completion_url, "AB 12")
        == "https://app.prolific.com/submissions/complete?cc=AB%2012"
    )
    for url in ("javascript:alert(1)", "ftp://x.org/", "https://"):
        with pytest.raises(ValueError, match="http"):
            Crowd(screened_out_url=url)
    assert Crowd().ids({"PROLIFIC_PID": "p", "STUDY_ID": "s", "other": "o"}) == ("p", "s", "")


def test_an_attention_check_comes_before_the_first_trial_of_its_sessions_once():
    crowd = Crowd(attention_checks=(1, 3))
    due = [(s, t) for s in (1, 2, 3) for t in (1, 2) if crowd.check_due(s, t, answered=(s > 1) + (s > 3))]
    assert due == [(1, 1), (3, 1)]
    assert crowd.check_due(3, 1, answered=0)  # resumed past session 1's check: asked before going on
    check, word = attention_check("seed")
    assert attention_check("seed") == (check, word) and word in check.options and f'"{word}"' in check.text
    assert len({attention_check(str(i))[1] for i in range(20)}) > 1  # the word changes
    with pytest.raises(ValueError, match="attention_checks"):
        Crowd(attention_checks=(0,))


def test_a_studys_toml_names_its_platform_and_logistics_leave_its_hash_alone(tmp_path):
    path = tmp_path / "study.toml"
    base = 'name = "c"\n[[variants]]\nname = "v"\nbait = "B5"\nshooter = "S5"\n'
    path.write_text(base)
    plain = StudyConfig.load(path)
    path.write_text(
        base + '[crowd]\nstudy = "study"\ncompletion_url = "https://example.org/done?cc=C0DE"\n'
        'bonus = { per_kill = 0.05, max = 2.0, currency = "GBP" }\n'
    )
    crowd = StudyConfig.load(path)
    assert crowd.crowd.study == "study" and crowd.crowd.participant == "PROLIFIC_PID"
    assert crowd.crowd.bonus == Bonus(per_kill=0.05, max=2.0)
    assert crowd.hash() == plain.hash()  # a redirect or bonus fixed mid-study keeps the journal
    checked = StudyConfig("c", (Variant.read("v", "B5", "S5"),), crowd=Crowd(attention_checks=(1,)))
    assert checked.hash() != plain.hash()  # a check changes what participants go through
    with pytest.raises(ValueError, match="sessions are 1 to 1"):
        StudyConfig("c", (Variant.read("v", "B5", "S5"),), crowd=Crowd(attention_checks=(2,)))
    path.write_text(base + '[crowd]\ncompletion_url = "javascript:alert(1)"\n')
    with pytest.raises(UsageError, match="not a study: crowd.completion_url"):
        StudyConfig.load(path)
