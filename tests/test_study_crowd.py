"""Crowd-sourcing end to end, Prolific's conventions: the platform's ids from the link kept with the
participant, attention checks, the completion and screened-out redirects (in Debian's Chromium,
the platform's site answered by Playwright: nothing leaves the machine), and the bulk-bonus file
computed from the recordings when the server stops. Skipped, with the reason, without Chromium."""

from __future__ import annotations

import asyncio
from urllib.parse import quote

import pytest
from conftest import CHROMIUM, STAND_IN_TOKEN

from services.recorder.recording import load
from services.study.core import StudyConfig, Variant
from services.study.crowd import BONUSES, Bonus, Crowd
from services.study.runner import SCREENED
from services.study.standin import stand_in

DONE = "https://app.prolific.com/submissions/complete?cc={code}"
OUT = "https://app.prolific.com/submissions/complete?cc=SCREENED"
VARIANTS = (Variant("a", "B5", "S5"), Variant("b", "B1", "S1"))
STRONG = {"bait": "B5", "shooter": "S5"}  # the stand-in's policies: ones that kill
BONUS = Bonus(per_kill=0.5, per_point=0.01, max=2.0)


def crowd_config(trial_seconds: float) -> StudyConfig:
    crowd = Crowd(completion_url=DONE, screened_out_url=OUT, bonus=BONUS, attention_checks=(1, 2))
    return StudyConfig("crowd", VARIANTS, trials=1, trial_seconds=trial_seconds, seed=4, crowd=crowd)


def test_stand_ins_from_a_platform_are_checked_redirected_and_paid_their_bonus(tmp_path, study_server):
    stop, url, server = study_server(crowd_config(8.0), tmp_path)  # 8 s: long enough for a kill
    ids = {"PROLIFIC_PID": "5f00aa11", "STUDY_ID": "S-1", "SESSION_ID": "sess-9"}
    attentive = asyncio.run(stand_in(url, test=STAND_IN_TOKEN, link=ids, policies=STRONG))
    careless = asyncio.run(
        stand_in(url, test=STAND_IN_TOKEN, link={"PROLIFIC_PID": "6e00bb22"}, attentive=False)
    )
    bad = asyncio.run(stand_in(url, test=STAND_IN_TOKEN, link={"STUDY_ID": "<script>"}))
    stop.set()
    study = server.result(timeout=60)

    assert attentive.done and attentive.checks == 2 and not attentive.screened
    assert attentive.redirect == DONE.replace("{code}", quote(attentive.code))
    assert (
        careless.screened and careless.checks == 2 and careless.redirect == OUT and careless.end == SCREENED
    )
    assert len(careless.kills) == 1  # played session 1 between its two failed checks
    assert "ids are not ones this study can take" in bad.refused
    first, second = study.participants.values()
    assert (first.worker, first.link, first.checks) == (
        "5f00aa11",
        {"study": "S-1", "session": "sess-9"},
        [True] * 2,
    )
    assert (second.worker, second.checks, second.screened) == ("6e00bb22", [False, False], True)

    rows = []
    for participant in (first, second):
        summaries = [
            load(tmp_path / "recordings" / f"{a['match']}.tsflog").summary
            for a in participant.attempts
            if a["status"] == "done"
        ]
        earned = sum(BONUS.per_kill * s.kills + BONUS.per_point * max(s.points, 0) for s in summaries)
        amount = round(min(earned, BONUS.max), 2)
        rows += [f"{participant.worker},{amount:.2f}\n"] if amount > 0 else []
    assert rows, "a bonus was earned (the scripted pairs destroy a fortress in about 8 s)"
    assert (tmp_path / BONUSES).read_text() == "".join(rows)


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
def test_a_prolific_link_in_chromium_ends_on_the_platforms_completion_page(tmp_path, browser, study_server):
    expect = pytest.importorskip("playwright.sync_api").expect
    config = StudyConfig("crowdpage", VARIANTS[:1], trials=1, trial_seconds=2.0, crowd=Crowd(
        completion_url=DONE, screened_out_url=OUT, attention_checks=(1,)))  # fmt: skip
    stop, url, server = study_server(config, tmp_path)
    page = browser.new_page()
    visited = []

    def platform(route) -> None:  # noqa: ANN001 - Playwright's Route: the platform's site, answered here
        visited.append(route.request.url)
        route.fulfill(status=200, content_type="text/html", body="<p>Submission complete</p>")

    page.route("https://app.prolific.com/**", platform)
    page.goto(url + "?PROLIFIC_PID=5f00cc33&STUDY_ID=S-2&SESSION_ID=sess-3")
    title = page.locator("#title")
    expect(title).to_have_text("Before we start", timeout=20_000)
    page.click("#go")
    expect(title).to_have_text("A quick check", timeout=20_000)
    word = page.locator("#text").inner_text().split('"')[1]
    page.locator("button.answer", has_text=word).click()
    expect(title).to_contain_text("Session 1 of 1", timeout=30_000)
    page.click("#go")
    expect(title).to_have_text("The end", timeout=120_000)
    code = page.locator("#text").inner_text().split("Your completion code: ")[1].split()[0]
    page.wait_for_url(DONE.replace("{code}", code), timeout=15_000)  # after the 5 s notice
    assert visited == [DONE.replace("{code}", code)]
    stop.set()
    (participant,) = server.result(timeout=60).participants.values()
    assert (participant.worker, participant.link, participant.checks) == (
        "5f00cc33", {"study": "S-2", "session": "sess-3"}, [True])  # fmt: skip
