"""The dashboard's overview as a pure function of a study and its admission, and its token's rules."""

from __future__ import annotations

import pytest

from services.study.core import Admission, Study, StudyConfig, Variant
from services.study.dashboard import overview, read_token


def test_the_overview_counts_each_participants_trials_and_shows_queue_matches_and_hosts(tmp_path):
    study = Study(
        StudyConfig("ov", (Variant.read("a", "B5", "S5"), Variant.read("b", "B1", "S1")), trials=2), tmp_path
    )
    first, second, third = (study.arrive(w) for w in ("W-1", "W-2", ""))
    trial = study.next_trial(first)
    study.record(trial, "failed")
    again = study.next_trial(first)  # the same trial, a second attempt
    study.record(again, "done", 3)
    running = study.next_trial(first)
    study.record(running, "running")
    admission = Admission(1)
    admission.hosts = {"lab-2": 2}
    assert admission.start(running.match)
    waiting = study.next_trial(second).match
    admission.start("x")  # another match on the host, so that the next one waits
    admission.start("y")
    assert not admission.start(waiting)
    study.check(second, False)
    study.check(second, True)
    study.refused(third, "unproven")
    shown = overview(study, admission, {first.id})
    study.close()

    assert [(p["id"], p["done"], p["failed"], p["replayed"], p["match"]) for p in shown["participants"]] == [
        (first.id, 1, 1, 1, running.match),
        (second.id, 0, 0, 0, None),
        (third.id, 0, 0, 0, None),
    ]
    assert all(p["trials"] == 4 for p in shown["participants"])
    assert [(p["state"], p["checks"], p["refused"]) for p in shown["participants"]] == [
        ("playing", [], 0),
        ("dropped", [False, True], 0),
        ("refused", [], 1),
    ]
    roles = study.config.roles
    assert shown["counts"]["roles"] == {r: sum(p.role == r for p in (first, second, third)) for r in roles}
    assert shown["counts"]["variants"] == [
        {"variant": v.name, **{r: int(r == first.role and v == trial.variant) for r in roles}}
        for v in study.config.variants
    ]
    assert shown["counts"]["states"] == {
        "playing": 1, "finished": 0, "screened out": 0, "dropped": 1, "refused": 1,
    }  # fmt: skip
    assert shown["queue"] == [{"match": waiting, "participant": second.id}]
    assert shown["matches"][0] == {
        "match": running.match, "participant": first.id, "variant": running.variant.name,
        "person": first.role, "host": "local",
    }  # fmt: skip
    local, host = {"host": "local", "slots": 1, "used": 1}, {"host": "lab-2", "slots": 2, "used": 2}
    assert shown["hosts"] == [local, host]
    assert "W-1" not in str(shown)  # the platform's ids stay in the study's file


def test_a_dashboard_token_is_16_to_64_characters():
    assert read_token(" " + "t" * 16 + "\n") == "t" * 16
    for bad in ("", "short", "t" * 65):
        with pytest.raises(ValueError, match="give 16 to 64"):
            read_token(bad)
