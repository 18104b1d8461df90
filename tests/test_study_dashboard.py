"""The experimenter's dashboard end to end: a real study server with a stand-in participant, and
Debian's Chromium opening the dashboard (counts that change as trials are done) and the spectator
view of the running match (frames drawn by the participants' page); a wrong or missing token and
a participant's own credentials open nothing. Skipped, with the reason, where Chromium is missing."""

from __future__ import annotations

import asyncio
import json
import os
from concurrent.futures import ThreadPoolExecutor

import pytest
import websockets
from conftest import CHROMIUM, STAND_IN_TOKEN, wait_in_page

from services.human.gateway import Web
from services.recorder.recording import load
from services.study.core import StudyConfig, Variant
from services.study.dashboard import NOT_RUNNING, WRONG
from services.study.serving import Serving
from services.study.standin import stand_in
from shared.bus import free_endpoint

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
TOKEN = "dashboard-token-for-tests-0123"


def ask(url: str, first: dict) -> dict:
    """A socket's first message sent to `url`, and the first answer (or how it was closed)."""

    async def go() -> dict:
        async with websockets.connect(url.replace("http", "ws", 1) + "ws") as ws:
            await ws.send(json.dumps(first))
            try:
                return json.loads(await ws.recv())
            except websockets.ConnectionClosed as closed:
                return {"closed": closed.rcvd.code if closed.rcvd else None}

    with ThreadPoolExecutor(1) as pool:  # Playwright's loop may be running in this thread
        return pool.submit(asyncio.run, go()).result(timeout=30)


@pytest.mark.long
@pytest.mark.slow
def test_the_dashboard_shows_the_study_live_and_a_spectator_watches_a_match(tmp_path, browser, study_server):
    port = int(free_endpoint().rsplit(":", 1)[1])
    serving = Serving(test_token=STAND_IN_TOKEN, dashboard=Web(port=port), dashboard_token=TOKEN)
    config = StudyConfig("watched", (Variant.read("s", "B5", "S5"),), trials=2, trial_seconds=6.0, seed=2)
    stop, url, server = study_server(config, tmp_path, serving)
    board = f"http://127.0.0.1:{port}/"
    with ThreadPoolExecutor(1) as pool:
        participant = pool.submit(asyncio.run, stand_in(url, test=STAND_IN_TOKEN))
        page = browser.new_page()
        page.goto(board + "#token=" + TOKEN)
        wait_in_page(page, "dash.overview && dash.overview.matches.length === 1", 60_000)
        first = page.evaluate("dash.overview")
        (seen,) = first["participants"]
        assert seen["id"] == "P001" and seen["done"] == 0 and seen["trials"] == 2
        assert seen["state"] == "playing" and first["counts"]["roles"][seen["role"]] == 1
        (running,) = first["matches"]
        assert (running["variant"], running["person"]) == ("s", seen["role"])
        assert first["hosts"] == [{"host": "local", "slots": Serving().max_matches, "used": 1}]
        assert "W-" not in json.dumps(first)  # no worker ids, only the study's own

        watch = page.locator("a.watch").first.get_attribute("href")
        spectator = browser.new_page()
        spectator.goto(board.rstrip("/") + watch)
        wait_in_page(spectator, "tsf.drawn > 10", 30_000)  # frames arrive and are drawn
        assert spectator.evaluate("tsf.role") is None  # a spectator: no seat, nothing to send
        assert spectator.evaluate("tsf.watching") == {"type": "watching", "match": running["match"],
                                                      "variant": "s", "person": seen["role"]}  # fmt: skip
        if os.environ.get("TSF_SHOTS"):
            page.screenshot(path=f"{os.environ['TSF_SHOTS']}/dashboard.png", full_page=True)
            spectator.screenshot(path=f"{os.environ['TSF_SHOTS']}/dashboard_watch.png")
        spectator.keyboard.down("Space")  # a spectator's keys go nowhere (checked in the recording)
        wait_in_page(page, "dash.overview.participants[0].done >= 1", 60_000)  # live: counts change
        wait_in_page(page, "dash.overview.participants[0].done === 2", 60_000)
        wait_in_page(page, "dash.overview.matches.length === 0", 30_000)
        wait_in_page(page, "dash.overview.participants[0].state === 'finished'", 30_000)
        assert page.evaluate("dash.overview.counts.variants") == [
            {"variant": "s", "bait": 2 * (seen["role"] == "bait"), "shooter": 2 * (seen["role"] == "shooter")}
        ]
        report = participant.result(timeout=60)
        assert report.done
        spectator.close()
        page.close()

        wrong = browser.new_page()
        wrong.goto(board + "#token=not-" + TOKEN)
        wait_in_page(wrong, "dash.refused !== null", 10_000)
        assert wrong.evaluate("dash.refused") == WRONG
        wrong.goto(board + "?again")  # no token at all
        wait_in_page(wrong, "dash.refused !== null", 10_000)
        wrong.close()

    # a participant's credentials open nothing here, and the dashboard's nothing there
    assert ask(board, {"type": "dashboard", "token": report.key}) == {"type": "refused", "reason": WRONG}
    assert ask(board, {"type": "watch", "token": TOKEN, "match": "watched-P001-s1t1"}) == {
        "type": "refused", "reason": NOT_RUNNING}  # fmt: skip
    assert ask(url, {"type": "dashboard", "token": TOKEN}) == {"closed": 1008}
    stop.set()
    p001 = server.result(timeout=60).participants["P001"]
    for attempt in p001.attempts:
        recording = load(tmp_path / "recordings" / f"{attempt['match']}.tsflog")
        assert {a.sender for _, a in recording.actions if a.role == p001.role} == {f"human/{p001.role}"}
