"""What the study's page tells a participant is true: a server that stops mid-trial says so (their
progress kept, whom to contact) and never "Time is up" with time left; the end shows the platform's
completion code, with text that matches the redirect; consent names the practice game and the
attention checks; points are explained, or hidden. Stand-ins over the page's WebSocket protocol,
and Debian's Chromium for the page itself (its screenshots go to TSF_SHOTS, if set)."""

from __future__ import annotations

import asyncio
import json
import os
import threading
import time
from pathlib import Path

import pytest
from conftest import CHROMIUM, STAND_IN_TOKEN

from services.human.core import end
from services.study.admission import STOPPED
from services.study.core import CHECKS_TEXT, PRACTICE_TEXT, StudyConfig, Variant
from services.study.crowd import Crowd
from services.study.standin import stand_in
from shared.messages import Summary
from shared.page import End

VARIANT = (Variant.read("s", "B5", "S5"),)
CONTACT = "the researcher at lab@example.org"


def running(directory: Path) -> bool:
    """Whether the study's journal has a trial running."""
    path = directory / "study.jsonl"
    lines = path.read_text().splitlines() if path.exists() else []
    return any(json.loads(line).get("attempt", {}).get("status") == "running" for line in lines)


def stop_mid_trial(directory: Path, stop: threading.Event, after: float = 2.0) -> threading.Thread:
    """Set `stop` `after` seconds into the first trial that runs."""

    def watch() -> None:
        deadline = time.monotonic() + 60
        while not running(directory) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(after)
        stop.set()

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


@pytest.mark.long
@pytest.mark.slow
def test_a_server_that_stops_mid_trial_tells_the_participant_the_truth(tmp_path, study_server):
    config = StudyConfig("halt", VARIANT, trials=2, trial_seconds=30.0, crowd=Crowd(contact=CONTACT))
    stop, url, server = study_server(config, tmp_path)
    stop_mid_trial(tmp_path, stop)
    report = asyncio.run(stand_in(url, test=STAND_IN_TOKEN))
    study = server.result(timeout=90)
    assert len(report.kills) == len(report.cut), "no game cut short is reported as over in time"
    assert report.stopped == f"{STOPPED} If it stays stopped, please contact {CONTACT}."
    assert not report.done and not report.set_ups - 1, "no next game is announced"
    (participant,) = study.participants.values()
    assert [a["status"] for a in participant.attempts] in (["dropped"], ["failed"])
    assert study.next_trial(participant).trial == 1, "the cut trial is played again on return"


def test_a_game_cut_short_is_said_to_be(tmp_path) -> None:
    """The `end` message carries the frame the game ended at and the frames it was to last: the
    page says "stopped" for one that ended early, "Time is up" only for one that ran its time."""
    summary = Summary(match="m", frame=59, sender="sim", kills=1, points=80)
    assert end(summary, 900) == End(kills=1, kills_per_minute=0.0, points=80, frame=59, frames=900)


def test_consent_names_the_practice_and_the_checks_and_the_end_matches_the_redirect() -> None:
    plain = StudyConfig("p", VARIANT, trials=1, trial_seconds=10.0)
    assert PRACTICE_TEXT[:20] not in plain.consent_text() and "attention check" not in plain.consent_text()
    full = StudyConfig(
        "p", VARIANT, trials=1, trial_seconds=10.0, practice_seconds=20.0,
        crowd=Crowd(attention_checks=(1,), completion_code="C1A2B3"), pay="GBP 2",
    )  # fmt: skip
    text = full.consent_text()
    assert PRACTICE_TEXT.format(seconds="20") in text and CHECKS_TEXT.format(fails=2) in text
    assert text.endswith("\n\nPay: GBP 2")
    placed = StudyConfig("p", VARIANT, consent="{checks} Then: {games}. {practice}", crowd=full.crowd)
    assert placed.consent_text() == f"{CHECKS_TEXT.format(fails=2)} Then: 3 games. "
    assert "close this window" in plain.end_text(redirected=False)
    assert "close this window" not in plain.end_text(redirected=True)
    assert StudyConfig("p", VARIANT, end="Bye.").end_text(redirected=True) == "Bye."
    assert full.crowd.code("OWN1") == "C1A2B3" and plain.crowd.code("OWN1") == "OWN1"


def test_a_setting_added_later_keeps_the_study_hash_at_its_default() -> None:
    """A journal begun before `show_points` existed is still this study's."""
    shown = StudyConfig("p", VARIANT)
    assert shown.hash() == StudyConfig("p", VARIANT, show_points=True).hash()
    assert shown.hash() != StudyConfig("p", VARIANT, show_points=False).hash()


def test_the_platforms_completion_code_is_shown_and_sent_back(tmp_path, study_server):
    crowd = Crowd(
        completion_url="https://app.prolific.com/submissions/complete?cc={code}", completion_code="C1A2B3"
    )
    config = StudyConfig("code", VARIANT, trials=1, trial_seconds=1.0, crowd=crowd, show_points=False)
    stop, url, server = study_server(config, tmp_path)
    report = asyncio.run(stand_in(url, test=STAND_IN_TOKEN, worker="W-1"))
    stop.set()
    (participant,) = server.result(timeout=60).participants.values()
    assert report.done and report.code == "C1A2B3" and report.redirect.endswith("?cc=C1A2B3")
    assert report.end == "Thank you for taking part." and participant.code != "C1A2B3"


@pytest.mark.long
@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
def test_the_page_says_the_study_stopped_and_shows_the_platforms_code(tmp_path, browser, study_server):
    expect = pytest.importorskip("playwright.sync_api").expect
    shots = os.environ.get("TSF_SHOTS")
    crowd = Crowd(
        contact=CONTACT, completion_code="C1A2B3", completion_url="https://app.prolific.com/x?cc={code}"
    )
    config = StudyConfig("page", VARIANT, trials=1, trial_seconds=20.0, crowd=crowd, show_points=False)
    stop, url, server = study_server(config, tmp_path / "a")
    page = browser.new_page(viewport={"width": 900, "height": 760})
    page.goto(url + "?PROLIFIC_PID=5f00cc33")
    title = page.locator("#title")
    expect(title).to_have_text("Before we start", timeout=20_000)
    page.click("#go")
    expect(title).to_contain_text("Session 1 of 1", timeout=20_000)
    said = page.locator("#text").inner_text()
    assert "flies into the fortress's shield" in said and "into the wall" not in said
    assert "counts points" not in said, "points hidden by the study"
    page.click("#go")
    page.wait_for_function("window.tsf.phase === 'playing'", timeout=30_000)
    page.wait_for_timeout(1500)
    stop.set()
    expect(title).to_have_text("The study has stopped", timeout=30_000)
    text = page.locator("#text").inner_text()
    assert STOPPED in text and CONTACT in text and "Time is up" not in text
    if shots:
        page.screenshot(path=f"{shots}/stopped-study.png")
    page.wait_for_timeout(1000)  # the socket closes: the page keeps saying so
    expect(title).to_have_text("The study has stopped")
    server.result(timeout=90)

    stop, url, server = study_server(
        StudyConfig("page", VARIANT, trials=1, trial_seconds=1.0, crowd=crowd), tmp_path / "b"
    )
    page = browser.new_page(viewport={"width": 900, "height": 760})
    page.route("https://app.prolific.com/**", lambda route: route.fulfill(status=200, body="<p>done</p>"))
    page.goto(url + "?PROLIFIC_PID=6e00dd44")
    expect(title := page.locator("#title")).to_have_text("Before we start", timeout=20_000)
    consent = page.locator("#text").inner_text()
    page.click("#go")
    expect(title).to_contain_text("Session 1 of 1", timeout=20_000)
    assert (
        "The game also counts points: +100 for each fortress destroyed" in page.locator("#text").inner_text()
    )
    page.click("#go")
    expect(title).to_have_text("The end", timeout=60_000)
    text = page.locator("#text").inner_text()
    assert "Your completion code: C1A2B3" in text and "Taking you back to the study's site" in text
    assert "close this window" not in text and consent
    if shots:
        page.screenshot(path=f"{shots}/completion.png")
    page.wait_for_url("https://app.prolific.com/x?cc=C1A2B3", timeout=15_000)
    stop.set()
    server.result(timeout=60)
