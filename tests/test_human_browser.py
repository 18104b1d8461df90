"""The page in a real browser: Debian's Chromium driven by Playwright (never a downloaded browser),
against a real match (`tsf play`'s path: gateway here, sim, agent and recorder as processes).
Skipped, with the reason, where Chromium is not installed (.ci/run installs it)."""

from __future__ import annotations

import io
import threading
from concurrent.futures import Future, ThreadPoolExecutor

import pytest
from conftest import CHROMIUM, wait_in_page

from services.human.core import SeatBook
from services.human.gateway import Gateway, Web, seat_handler
from services.human.play import play_with_people, seat_links
from services.population.seat import SeatSpec
from services.recorder.recording import load
from services.recorder.replay import republish
from services.runtime.launch import MatchPlan, run_match
from shared.game import HUMAN, GameConfig
from shared.messages import Action

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
FRAMES = 300  # 10 s of real time
BACKGROUND = (12, 14, 28)
BAIT_COLOUR = (255, 150, 40)


@pytest.fixture
def match(tmp_path):
    """A match with a person in the bait seat and the mirror shooter: (links, the running match)."""
    links: dict[str, str] = {}
    ready = threading.Event()
    seats = {"bait": SeatSpec.parse(HUMAN), "shooter": SeatSpec.parse("mirror")}
    plan = MatchPlan("browser", 1, FRAMES, directory=tmp_path, wait_players=60, **seats)

    def on_links(urls: dict[str, str]) -> None:
        links.update(urls)
        ready.set()

    with ThreadPoolExecutor(1) as pool:
        running: Future = pool.submit(play_with_people, plan, port=0, on_links=on_links)
        assert ready.wait(30) or running.exception(0), "the gateway is up and prints the links"
        yield links, running
        if not running.done():  # a failed test: let the match run out (the sim stops on its own)
            running.exception(FRAMES / 30 + 60)


@pytest.mark.slow
@pytest.mark.long  # 13 s or more in the full run: kept out of the default run
def test_a_person_plays_the_bait_from_the_browser(browser, match, tmp_path):
    links, running = match  # the match's sim waits for this person to press start
    page = browser.new_page(viewport={"width": 900, "height": 800})
    page.goto(links["bait"])
    assert page.locator("canvas#game").is_visible()
    wait_in_page(page, "window.tsf.phase === 'instructions'", 10_000)
    assert "BAIT" in page.locator("#text").inner_text()
    page.keyboard.press("Space")  # read the instructions: start
    wait_in_page(page, "window.tsf.phase === 'playing' && window.tsf.drawn > 5", 30_000)
    page.keyboard.down("ArrowLeft")
    page.wait_for_timeout(1000)
    page.keyboard.up("ArrowLeft")
    page.keyboard.down("Space")
    page.wait_for_timeout(300)
    page.keyboard.up("Space")
    shot = page.locator("canvas#game").screenshot(path=str(tmp_path / "page.png"))
    wait_in_page(page, "window.tsf.phase === 'ended'", FRAMES / 30 * 1000 + 20_000)
    assert "Time is up" in page.locator("#title").inner_text()
    drawn = page.evaluate("window.tsf.drawn")
    print(f"the page drew {drawn} of the match's {FRAMES} frames")
    assert drawn >= FRAMES // 2, "the page draws as the frames come (30 a second), not a few"
    summary, path = running.result(timeout=30)
    assert summary.frame == FRAMES

    recording = load(path)
    assert recording.start.policies == {"bait": HUMAN, "shooter": "mirror"}
    states = {s.frame: s for s in recording.states}
    turned = [f for f, s in states.items() if s.applied[0] == 4 and f - 1 in states]
    assert len(turned) >= 15, "about a second of held left arrow reached the sim"
    turn = GameConfig().ship_turn
    for f in turned:
        before, after = states[f - 1].ships[0][4], states[f].ships[0][4]
        assert (after - before) % 360 == pytest.approx(turn), "the bait turned left by a turn a frame"
    bait_actions = [a for _, a in recording.actions if a.role == "bait"]
    assert all(a.policy == "" and a.sender == "human/bait" for a in bait_actions)
    assert any(a.action & 1 for a in bait_actions), "space fired"
    assert any(e.kind == "missile" and e.role == "bait" for e in recording.events), "a missile left"

    from PIL import Image

    image = Image.open(io.BytesIO(shot)).convert("RGB")
    colours = image.getcolors(maxcolors=1 << 20)
    assert image.size[0] >= 700 and len(colours) > 20, "more than a blank canvas"
    drawn = sum(n for n, c in colours if c != BACKGROUND)
    assert 0.005 < drawn / (image.size[0] * image.size[1]) < 0.5
    assert any(max(abs(a - b) for a, b in zip(c, BAIT_COLOUR, strict=True)) < 30 for _, c in colours)


@pytest.mark.slow
@pytest.mark.long  # 13 s alone: kept out of the default run
def test_the_page_says_why_the_ship_died_and_when_it_comes_back(browser, match):
    """A person's bait that thrusts ahead dies (its cause shown); the agent shooter then ends the
    stalled round on purpose, which the page announces, and the count-down to the respawn runs."""
    links, running = match
    page = browser.new_page(viewport={"width": 900, "height": 800})
    page.goto(links["bait"])
    wait_in_page(page, "window.tsf.phase === 'instructions'", 10_000)
    text = page.locator("#text").inner_text()
    assert "shell hits it" in text and "blue shield" in text and "the edge kills" in text
    page.keyboard.press("Space")
    wait_in_page(page, "window.tsf.phase === 'playing'", 30_000)
    page.keyboard.down("ArrowUp")
    said: set[str] = set()
    while page.evaluate("window.tsf.phase") == "playing":
        said.update(page.evaluate("window.tsf.said"))
        page.wait_for_timeout(40)
    page.keyboard.up("ArrowUp")
    running.result(timeout=30)
    print(sorted(said))
    deaths = {"A shell hit you", "You flew into the shield", "You flew out of the arena: the edge kills"}
    assert said & deaths, "the cause of the person's death"
    assert "Your teammate ends the round so you can respawn" in said
    assert any(line.startswith("Both ships are down: you respawn in") for line in said)


def test_a_wrong_seat_token_is_refused_in_the_page(browser, bus):
    book = SeatBook({"bait": "right-token"})
    with Gateway(bus.config(listen=True), seat_handler("refused", book), Web(port=0)) as gateway:
        page = browser.new_page()
        page.goto(seat_links(gateway.url, {"bait": "wrong-token"})["bait"])
        wait_in_page(page, "window.tsf.phase === 'refused'", 10_000)
        assert page.locator("#title").inner_text() == "Not possible"
        assert page.locator("#text").inner_text() == "wrong seat token for the bait seat"


def test_a_spectator_watches_a_live_replay_in_the_page(browser, bus, tap, tmp_path):
    """`tsf replay --live` into a gateway: a spectator's page draws the recorded match and its end,
    and watching puts nothing on the bus."""
    _, recording = run_match(MatchPlan("watched", 2, 120, "lockstep", directory=tmp_path))
    recorded = tap(bus.open(listen=True), "watched")
    with Gateway(bus.config(), seat_handler("watched", SeatBook({})), Web(port=0)) as gateway:
        page = browser.new_page()
        page.goto(f"{gateway.url}?watch=1")
        wait_in_page(page, "window.tsf.phase === 'waiting'", 10_000)
        assert page.locator("#title").inner_text() == "Watching"
        sent = republish(bus.config(), recording, speed=2.0, delay=1.0)
        wait_in_page(page, "window.tsf.phase === 'ended'", 30_000)
        assert sent > 120 and page.evaluate("window.tsf.frame.frame") == 120
        assert page.evaluate("window.tsf.drawn") > 30  # frames drawn as they came (at most one per paint)
        assert page.locator("#title").inner_text() == "Time is up"
    assert not recorded.of(Action) and not recorded.is_alive("human", "bait")  # watching plays no seat
