"""The study core: config files, balanced roles, per-participant orders, progress and resume."""

from __future__ import annotations

import dataclasses
import json
import math
from collections import Counter
from pathlib import Path

import pytest

from services.agent.library import keys as library_keys
from services.agent.seats import beside_keys
from services.population.adaptive import AdapterConfig
from services.runtime.launch import MatchPlan
from services.study.core import Admission, Study, StudyConfig, Variant, assigned_role, variant_order

CONFIGS = Path(__file__).parent / "configs"


def config(**changes: object) -> StudyConfig:
    variants = (
        Variant.read("a", "B1", "S1"),
        Variant.read("b", "B5", "S5"),
        Variant.read("c", adapter="adaptive-T150-cem"),
    )
    return dataclasses.replace(StudyConfig("t", variants, trials=2), **changes)


@pytest.mark.parametrize("name", ["static", "adaptive"])
def test_the_shipped_studies_load_and_name_library_policies(name: str) -> None:
    study = StudyConfig.load(CONFIGS / f"{name}.toml")
    assert study.name == name and len(study.variants) == 5 and study.trials == 3 and study.frames == 1800
    keys = {role: [*library_keys(role), *beside_keys(role)] for role in ("bait", "shooter")}
    for variant in study.variants:
        if not variant.adapter:
            assert str(variant.bait) in keys["bait"] and str(variant.shooter) in keys["shooter"]
    adaptive = [
        (v.adaptive("shooter", 0).window, v.adaptive("bait", 0).partners) for v in study.variants if v.adapter
    ]
    # the grown library's agent at two windows and the study library's, each in both seats
    assert adaptive == ([] if name == "static" else [(400, "groups"), (150, "groups"), (400, "library")])


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"name": "bad name"}, "study name"),
        ({"variants": ()}, "at least one variant"),
        ({"variants": (Variant.read("a", "B1", "S1"), Variant.read("a", "B2", "S2"))}, "names must differ"),
        ({"variants": (Variant.read("a", bait="B1"),)}, "no shooter for a bait participant"),
        ({"trials": 0}, "at least one trial"),
        ({"trial_seconds": 0}, r"trial_seconds 0: outside the range 0.1 to 3600.0"),
        ({"trial_seconds": 1e9}, r"trial_seconds 1000000000.0: outside the range"),
        ({"trial_seconds": float("nan")}, r"trial_seconds nan: outside the range"),
        ({"seed": -1}, r"seed -1: outside the range 0 to 4294967295"),
        ({"roles": ("pilot",)}, "roles must be"),
        ({"practice_seconds": 1e9}, r"practice_seconds 1000000000.0: 0 \(none\) or in the range 0.1"),
        ({"consent": "You earn {money}."}, r"consent: cannot fill in 'money' \(the text may name \{games\}"),
        ({"consent": "A { alone"}, "consent: cannot fill in expected '}' before end of string"),
    ],
)
def test_bad_configs_are_refused(changes: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        config(**changes)


def test_roles_are_balanced_and_random() -> None:
    study = config()
    roles = [assigned_role(study, i) for i in range(40)]
    for n in range(0, 40, 2):  # every block of two has one of each
        assert Counter(roles[n : n + 2]) == Counter({"bait": 1, "shooter": 1})
    assert roles[0::2] != ["bait"] * 20 and roles[0::2] != ["shooter"] * 20  # the order within varies
    assert roles == [assigned_role(study, i) for i in range(40)]  # a function of the study's seed
    assert roles != [assigned_role(config(seed=7), i) for i in range(40)]
    assert {assigned_role(config(roles=("shooter",)), i) for i in range(5)} == {"shooter"}


def test_each_participant_meets_every_variant_once_in_an_order_of_their_own() -> None:
    study = config()
    orders = [variant_order(study, i) for i in range(30)]
    assert all(sorted(order) == [0, 1, 2] for order in orders)
    assert len({tuple(order) for order in orders}) > 3
    assert Counter(order[0] for order in orders).keys() == {0, 1, 2}


def test_variants_put_their_agent_in_the_partner_seat() -> None:
    static, adaptive = config().variants[0], config().variants[2]
    assert str(static.seat("shooter")) == "S1" and str(static.seat("bait")) == "B1"
    assert adaptive.seat("bait").adaptive("bait", 7) == AdapterConfig("bait", 150, "cem", seed=7)
    assert MatchPlan("m", 7, shooter=adaptive.seat("shooter")).adapter == AdapterConfig(
        "shooter", 150, "cem", seed=7
    )
    static_bait = Variant.read("d", bait="B1", adapter="adaptive-T150-cem")  # the adapter in the other seat
    assert str(static_bait.seat("bait")) == "B1" and static_bait.adaptive("bait", 7) is None
    assert static_bait.seat("shooter").adaptive("shooter", 7) == AdapterConfig("shooter", 150, "cem", seed=7)


def test_a_variant_names_an_adaptive_agent_or_none() -> None:
    with pytest.raises(ValueError, match="names no adaptive agent"):
        Variant.read("x", adapter="adaptive-400")
    with pytest.raises(ValueError, match="names no adaptive agent"):
        Variant.read("x", adapter="B5")
    assert Variant.read("x", "B1", "noisy(S5)").names == {
        "name": "x",
        "bait": "B1",
        "shooter": "noisy(S5)",
        "adapter": "",
    }


def test_progress_resume_and_drop_outs(tmp_path: Path) -> None:
    study = Study(config(), tmp_path)
    first, second = study.arrive(), study.arrive()
    assert (first.id, second.id) == ("P001", "P002") and {first.role, second.role} == {"bait", "shooter"}
    trial = study.next_trial(first)
    assert (trial.session, trial.trial, trial.attempt, trial.agent) == (1, 1, 1, "Agent 1")
    assert trial.variant == study.config.variants[first.order[0]]
    assert trial.match == "t-P001-s1t1"
    study.record(trial, "running")
    study.record(trial, "dropped")  # the participant walked away
    again = study.next_trial(first)
    assert (again.session, again.trial, again.attempt, again.match) == (1, 1, 2, "t-P001-s1t1-a2")
    assert again.seed != trial.seed
    sidecar = study.record(again, "done", kills=3)
    assert sidecar["participant"] == "P001" and sidecar["variant"] == again.variant.name
    assert sidecar["role"] == first.role and sidecar["session"] == 1 and sidecar["kills"] == 3

    study.close()
    reopened = Study(config(), tmp_path)  # the server restarts: progress is kept
    back = reopened.resume("P001", first.key)
    assert (
        back is not None and reopened.resume("P001", "guess") is None and reopened.resume("P9", "x") is None
    )
    following = reopened.next_trial(back)
    assert (following.session, following.trial, following.attempt) == (1, 2, 1)
    for session, number in [(1, 2), (2, 1), (2, 2), (3, 1), (3, 2)]:
        current = reopened.next_trial(back)
        assert (current.session, current.trial, current.agent) == (session, number, f"Agent {session}")
        reopened.record(current, "done", kills=0)
    assert reopened.next_trial(back) is None
    reopened.close()
    assert [a["status"] for a in Study(config(), tmp_path).participants["P001"].attempts] == (
        ["dropped"] + ["done"] * 6
    )
    lines = (tmp_path / "study.jsonl").read_text().splitlines()  # appended, one line per change
    assert len(lines) == 1 + 2 + 3 + 5 and json.loads(lines[0])["config"] == config().hash()


def test_a_line_cut_short_by_a_crash_is_skipped(tmp_path: Path) -> None:
    study = Study(config(), tmp_path)
    first = study.arrive()
    study.close()
    with (tmp_path / "study.jsonl").open("a") as journal:
        journal.write('{"participant": {"id": "P0')
    back = Study(config(), tmp_path)
    assert list(back.participants) == ["P001"] and back.resume("P001", first.key) is not None
    back.close()


def test_admission_serves_waiting_trials_in_order() -> None:
    slots = Admission(2)
    assert slots.start("a") and slots.start("b") and not slots.start("c") and not slots.start("d")
    assert (slots.place("c"), slots.place("d")) == (1, 2)
    assert slots.wait(1, 60) == 30 and slots.wait(3, 60) == 90
    slots.end("a")
    assert not slots.start("d"), "c came first"
    assert slots.start("c") and not slots.start("d") and slots.place("d") == 1
    slots.end("d")  # gave up waiting
    assert slots.waiting == [] and set(slots.running) == {"b", "c"}


def test_admission_fills_local_slots_first_then_the_freest_host() -> None:
    slots = Admission(1)
    slots.hosts = {"lab-a": 1, "lab-b": 2}
    for match in "abcd":
        assert slots.start(match)
    assert slots.running == {"a": "", "b": "lab-b", "c": "lab-a", "d": "lab-b"}
    assert not slots.start("e") and slots.place("e") == 1 and slots.wait(4, 60) == 30
    slots.hosts = {"lab-a": 1}  # lab-b went away: its two matches still count until they end
    slots.end("c")
    assert slots.start("e") and slots.running["e"] == "lab-a"
    slots.end("b")
    slots.end("d")
    assert not slots.start("f"), "lab-b's slots are gone"
    slots.end("a")
    assert slots.start("f") and slots.running["f"] == ""


def test_a_changed_study_does_not_reuse_another_versions_file(tmp_path: Path) -> None:
    study = Study(config(), tmp_path)
    study.arrive()
    study.close()
    with pytest.raises(ValueError, match="another version"):
        Study(config(trials=3), tmp_path)


def test_a_worker_id_is_trimmed_validated_and_taken_in_any_case(tmp_path):
    from services.study.core import Study, worker_id

    assert [worker_id(w) for w in ("", None, " W-17 ", "5f8e0c1d2a3b4c5d6e7f8a9b")] == [
        "",
        "",
        "W-17",
        "5f8e0c1d2a3b4c5d6e7f8a9b",
    ]
    for bad in ("W\x0017", "<b>W</b>", "\udc80", "W 17", "x" * 65, 17, ["W-17"]):
        assert worker_id(bad) is None, bad
    study = Study(config(), tmp_path)
    study.arrive("W-17")
    assert study.taken("w-17") and study.taken("W-17") and not study.taken("W-18") and not study.taken("")
    study.close()
    assert Study(config(), tmp_path).taken("w-17")  # read back from the journal


def test_the_consent_text_states_the_studys_numbers_and_pay() -> None:
    """Games, their length and the time in all come from the config, not a fixed "one-minute"."""
    study = config(trials=2, trial_seconds=30.0)
    games = 2 * len(study.variants)
    shown = study.consent_text()
    assert f"play {games} games of 30 seconds each" in shown and "minute games" not in shown
    assert f"about {math.ceil(games * 50 / 60)} minutes in all" in shown and "Pay" not in shown
    paid = dataclasses.replace(study, pay="GBP 2.50 through Prolific")
    assert paid.consent_text().endswith("\n\nPay: GBP 2.50 through Prolific")
    placed = dataclasses.replace(paid, consent="{games} for {pay}; {{braces}} stay.")
    assert placed.consent_text() == f"{games} games for GBP 2.50 through Prolific; {{braces}} stay."
    assert study.hash() != paid.hash(), "what a participant agrees to is part of the study's version"


def test_a_practice_game_only_before_the_recorded_ones_and_a_new_match_each_time(tmp_path: Path) -> None:
    assert Study(config(), tmp_path / "none").practice(Study(config(), tmp_path / "n").arrive()) is None
    study = Study(config(practice_seconds=5.0), tmp_path / "study")
    participant = study.arrive()
    first, again = study.practice(participant), study.practice(participant)
    assert first.practice and first.agent == "a practice partner" and first.match != again.match
    assert str(first.variant.seat("shooter")) == "mirror" and str(first.variant.seat("bait")) == "circle"
    study.record(study.next_trial(participant), "running")
    assert study.practice(participant) is None, "the recorded trials have begun"


def test_a_machine_that_falls_behind_starts_no_new_match_until_it_catches_up():
    from services.study.core import Lag

    lag = Lag(window=5.0)
    for frame in range(30):  # on time: a frame each 1/30 s
        lag.frame("a", frame, 100.0 + frame / 30)
    assert lag.worst(101.0) == pytest.approx(0.0, abs=1e-9)
    lag.frame("a", 30, 101.0 + 0.040)  # 40 ms late
    assert lag.worst(101.1) == pytest.approx(0.040)
    assert lag.worst(106.1) == 0.0  # the window has passed: caught up
    lag.frame("b", 0, 107.0)  # a match of its own origin
    lag.end("a")
    assert set(lag.origins) == {"b"}

    slots = Admission(3)
    assert slots.start("m1")
    slots.held = True  # behind: the second waits, though a slot is free
    assert not slots.start("m2") and slots.place("m2") == 1
    slots.hosts = {"h": 1}  # another machine's slot is not held
    assert slots.start("m2") and slots.running["m2"] == "h"
    slots.end("m1")
    assert slots.start("m3"), "with none running here, a held machine still starts one"
    slots.held = False
    assert slots.start("m4") and slots.running["m4"] == Admission.LOCAL
