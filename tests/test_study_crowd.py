"""Crowd-sourcing end to end, Prolific's conventions: the platform's ids from the link kept with the
participant, attention checks, the completion and screened-out redirects (in Debian's Chromium,
the platform's site answered by Playwright: nothing leaves the machine), and the bulk-bonus file
computed from the recordings when the server stops. Skipped, with the reason, without Chromium."""

from __future__ import annotations

import asyncio
import re
from urllib.parse import quote

import pytest
from conftest import CHROMIUM, STAND_IN_TOKEN, wait_in_page

from services.recorder.recording import load
from services.study.core import StudyConfig, Variant
from services.study.crowd import BONUSES, Bonus, Crowd
from services.study.standin import stand_in
from services.study.visit import SCREENED

DONE = "https://app.prolific.com/submissions/complete?cc={code}"
OUT = "https://app.prolific.com/submissions/complete?cc=SCREENED"
VARIANTS = (Variant.read("a", "B5", "S5"), Variant.read("b", "B1", "S1"))
STRONG = {"bait": "B5", "shooter": "S5"}  # the stand-in's policies: ones that kill
BONUS = Bonus(per_kill=0.5, per_point=0.01, max=2.0)


def crowd_config(trial_seconds: float) -> StudyConfig:
    crowd = Crowd(completion_url=DONE, screened_out_url=OUT, bonus=BONUS, attention_checks=(1, 2))
    return StudyConfig("crowd", VARIANTS, trials=1, trial_seconds=trial_seconds, seed=4, crowd=crowd)


@pytest.mark.long
@pytest.mark.slow
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


def take_part(page, url: str, pid: str, attentive: bool) -> str:  # noqa: ANN001 - a Playwright Page
    """Go through the study in the page as a participant would, each check answered right or
    wrong, until it says the end; returns the completion code shown ("" if none)."""
    page.goto(url + f"?PROLIFIC_PID={pid}&STUDY_ID=S-2&SESSION_ID=sess-{pid}")
    wait_in_page(page, "tsf.phase === 'consent'", 20_000)
    page.click("#go")
    while True:
        wait_in_page(page, "['check', 'instructions', 'done'].includes(tsf.phase)", 60_000)
        phase = page.evaluate("tsf.phase")
        if phase == "check":
            word = page.locator("#text").inner_text().split('"')[1]
            buttons = page.locator("button.answer")
            choice = word if attentive else next(o for o in buttons.all_inner_texts() if o != word)
            buttons.filter(has_text=re.compile(f"^{choice}$")).click()
        elif phase == "instructions":
            page.click("#go")
        else:
            text = page.locator("#text").inner_text()
            return text.split("Your completion code: ")[1].split()[0] if "completion code" in text else ""
        wait_in_page(page, f"tsf.phase !== '{phase}'", 5_000)


@pytest.mark.long
@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
def test_prolific_links_in_chromium_end_on_the_platforms_completion_or_screened_out_page(
    tmp_path, browser, study_server
):
    stop, url, server = study_server(crowd_config(2.0), tmp_path)
    visited = []

    def platform(route) -> None:  # noqa: ANN001 - Playwright's Route: the platform's site, answered here
        visited.append(route.request.url)
        route.fulfill(status=200, content_type="text/html", body="<p>Submission complete</p>")

    page = browser.new_page()
    page.route("https://app.prolific.com/**", platform)
    code = take_part(page, url, "5f00cc33", attentive=True)
    page.wait_for_url(DONE.replace("{code}", code), timeout=15_000)  # after the 5 s notice
    careless = browser.new_page()
    careless.route("https://app.prolific.com/**", platform)
    assert take_part(careless, url, "6e00dd44", attentive=False) == ""
    assert SCREENED in careless.locator("#text").inner_text()
    careless.wait_for_url(OUT, timeout=15_000)
    assert visited == [DONE.replace("{code}", code), OUT]
    stop.set()
    first, second = server.result(timeout=60).participants.values()
    assert (first.worker, first.link, first.checks) == (
        "5f00cc33",
        {"study": "S-2", "session": "sess-5f00cc33"},
        [True] * 2,
    )
    assert (second.worker, second.checks) == ("6e00dd44", [False, False])
