"""What the page draws, pixel for pixel: frames of real games (the engine, seeded, scripted
policies), narrated by the gateway's core as in a match, drawn in Debian's Chromium through the
page's own hook (tsf.render) and compared with the reference pictures in docs/figures/ (the docs
show what this test checks), where Chromium's sans-serif is the references' font.
`TSF_UPDATE_FIGURES=1` redraws the references (look at them before committing). Skipped, with
the reason, where Chromium is missing."""

from __future__ import annotations

import functools
import io
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import CHROMIUM

from services.agent.scripted import scripted_policy
from services.human.core import Narrator, event_view, setup, view
from services.human.gateway import Gateway, Web
from services.sim.engine import Game
from services.sim.match import event_messages, state_message
from services.sim.observation import observe
from services.sim.play import policy_seed
from shared.game import DEATH_CAUSES, ROLES, GameConfig

pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
FIGURES = Path(__file__).resolve().parent.parent / "docs" / "figures"
# A pixel differs if a channel differs by more than TOLERANCE, and at most DIFFERING of them may:
# about 47 pixels, fewer than a missile's glow (80), far fewer than a shut opening (1.8 %). Drawn
# twice here, a state gives the same pixels; another Chromium may shade edges a little otherwise.
TOLERANCE = 16
DIFFERING = 0.0001
FONT = "DejaVu Sans"  # the references' text: fontconfig's sans-serif on Debian (fonts-dejavu-core)


def sans_serif() -> str:
    """The family fontconfig gives Chromium for sans-serif, "" where fc-match is missing."""
    if shutil.which("fc-match") is None:
        return ""
    found = subprocess.run(["fc-match", "-f", "%{family}", "sans-serif"], capture_output=True, text=True)
    return found.stdout.split(",")[0].strip()


def game_frames(seed: int, bait: str | int, shooter: str | int, role: str, frames: int = 1800):
    """Play a game; yield (state view narrated for `role`'s seat beside agents, its events), frame by
    frame. A policy is a scripted key, or an action it holds."""
    config = GameConfig(frames=frames)
    game = Game(config, seed)
    players = {
        r: scripted_policy(p, r) if isinstance(p, str) else p
        for r, p in zip(ROLES, (bait, shooter), strict=True)
    }
    for r, player in players.items():
        if not isinstance(player, int):
            player.reset(policy_seed(seed, r))
    narrator = Narrator(role, True, config.respawn_delay)
    while not game.done:
        actions = [p if isinstance(p, int) else p.act(observe(game, r, p.view)) for r, p in players.items()]
        game.step(*actions)
        state = state_message(game, "page", "sim", tuple(actions))
        shown = [e for e in map(event_view, event_messages(game, "page", "sim")) if e is not None]
        # as the page gets them: the JSON of the contract's messages
        yield json.loads(view(state, narrator(state)).encode()), [json.loads(e.encode()) for e in shown]


def scene(game: list, pick) -> tuple[dict, list[dict]]:  # noqa: ANN001 - a predicate
    """The first frame of `game` (game_frames' list) that `pick(frame, events so far)` takes, and
    the events sent up to it."""
    events: list[dict] = []
    for frame, shown in game:
        events += shown
        if pick(frame, events):
            return frame, events
    raise AssertionError("no frame of the game fits the scene")


def first(events: list[dict], kind: str, role: str | None = None) -> int | None:
    return next((e["frame"] for e in events if e["kind"] == kind and role in (None, e["role"])), None)


@functools.cache
def scenes() -> dict[str, tuple[dict, list[dict], str]]:
    """The four pictures: the bait's death (the agent shooter ends the round), both ships down
    (the count-down), the fortress's opening with missiles in flight, and the round's end (a kill)."""
    diver = list(game_frames(5, 2, "mirror", "bait", 600))  # the person's bait thrusts ahead until it dies
    pair = list(game_frames(1, "circle", "mirror", "shooter", 900))
    kill = first([e for _, shown in pair for e in shown], "kill")
    assert kill is not None, "the scripted pair kills"
    return {
        "death": (*scene(diver, lambda f, e: f["frame"] >= (first(e, "death", "bait") or 1e9) + 8), "bait"),
        "respawn": (*scene(diver, lambda f, e: f["respawn"] is not None and f["respawn"] <= 18), "bait"),
        "opening": (
            *scene(pair, lambda f, e: kill - 12 <= f["frame"] and f["fortress"][2] > 0 and f["missiles"]),
            "shooter",
        ),
        "round_end": (*scene(pair, lambda f, e: f["frame"] == kill + 10), "shooter"),
    }


@pytest.fixture(scope="module")
def page(browser):  # noqa: ANN001, ANN201 - a Playwright browser and page
    """The page as the gateway serves it (its CSP and script), with a socket that says nothing."""

    async def silent(ws, z):  # noqa: ANN001
        await ws.wait_closed()

    with Gateway(None, silent, Web(port=0)) as gateway:
        page = browser.new_page(viewport={"width": 900, "height": 800})
        page.goto(gateway.url)
        yield page


def drawn(page, frame: dict, events: list[dict], role: str) -> np.ndarray:  # noqa: ANN001
    from PIL import Image

    geometry = {"type": "setup", **setup(GameConfig())}
    said = page.evaluate(
        "([g, s, e, r]) => { tsf.render(g, s, e, r); return tsf.said; }", [geometry, frame, events, role]
    )
    shot = page.locator("canvas#game").screenshot()
    return np.asarray(Image.open(io.BytesIO(shot)).convert("RGB")).astype(int), said


def widest(page) -> float:  # noqa: ANN001
    """The width of the longest line the page says now, in its font."""
    return page.evaluate(
        """() => { const c = document.createElement("canvas").getContext("2d");
           c.font = "bold 18px sans-serif";
           return Math.max(0, ...tsf.said.map((t) => c.measureText(t).width)); }"""
    )


SAYS = {
    "death": ["Your teammate ends the round so you can respawn"],
    "respawn": ["You flew out of the arena", "Your teammate", "Both ships are down: you respawn in 0.6 s"],
    "opening": [],
    "round_end": ["Fortress destroyed!"],
}


@pytest.mark.parametrize("name", SAYS)
def test_the_page_draws_each_scene_as_its_reference(page, name: str) -> None:
    from PIL import Image

    frame, events, role = scenes()[name]
    image, said = drawn(page, frame, events, role)
    for words in SAYS[name]:
        assert any(line.startswith(words) for line in said), f"the page says {words!r}: {said}"
    if name == "death":
        assert said[0] in (
            "You flew into the shield",
            "A shell hit you",
            "You flew out of the arena: the edge kills",
        )
    if name == "opening":
        assert said == [] and frame["fortress"][2] > 0
    assert widest(page) <= image.shape[1] - 24, "every line the page says fits the arena's width"
    again, _ = drawn(page, frame, events, role)
    assert (again == image).all(), "a given state draws the same pixels"
    reference = FIGURES / f"page_{name}.png"
    if sans_serif() != FONT:  # another font changes as many pixels as another scene does
        pytest.skip(f"the references are drawn in {FONT}; this machine's sans-serif is {sans_serif()!r}")
    if os.environ.get("TSF_UPDATE_FIGURES"):
        Image.fromarray(image.astype(np.uint8)).save(reference)
    assert reference.exists(), f"no reference {reference.name}: run with TSF_UPDATE_FIGURES=1 and look at it"
    expected = np.asarray(Image.open(reference).convert("RGB")).astype(int)
    assert expected.shape == image.shape
    differing = (np.abs(expected - image).max(axis=2) > TOLERANCE).mean()
    assert differing <= DIFFERING, f"{differing:.2%} of the pixels differ from {reference.name}"


def test_the_scenes_differ_where_they_should(page) -> None:
    """Not one picture for all: the death, the opening and the kill each change many pixels; and
    the comparison is fine enough to see the opening shut, or one missile fewer."""
    pictures = {name: drawn(page, *scene_)[0] for name, scene_ in scenes().items()}
    names = list(pictures)
    for a, b in zip(names, names[1:], strict=False):
        assert (np.abs(pictures[a] - pictures[b]).max(axis=2) > TOLERANCE).mean() > 0.002, (a, b)
    frame, events, role = scenes()["opening"]
    shut = {**frame, "fortress": [frame["fortress"][0], 1, 0, frame["fortress"][3]]}
    for changed in (shut, {**frame, "missiles": frame["missiles"][1:]}):  # the comparison sees either
        image = drawn(page, changed, events, role)[0]
        assert (np.abs(image - pictures["opening"]).max(axis=2) > TOLERANCE).mean() > DIFFERING


def test_sound_is_off_until_the_person_turns_it_on(page) -> None:
    """Off by default; M (or the button) turns it on and off, and the browser remembers."""
    button = page.locator("#sound")
    assert (
        page.evaluate("localStorage.getItem('tsf-sound')") is None and button.inner_text() == "Sound: off (M)"
    )
    page.keyboard.press("KeyM")
    assert (
        button.inner_text() == "Sound: on (M)" and page.evaluate("localStorage.getItem('tsf-sound')") == "on"
    )
    frame, events, role = scenes()["round_end"]
    drawn(page, frame, events, role)  # a kill's tone played: WebAudio, no file, no error
    button.click()
    assert button.inner_text() == "Sound: off (M)"


def test_beside_a_person_the_page_says_when_the_ship_comes_back(page) -> None:
    """No agent partner ending the round: the page says what ends it instead."""
    frame, events, role = scenes()["death"]
    _, said = drawn(page, {**frame, "ending": False}, events, role)
    assert said[1] == "You respawn when the fortress falls or both ships are down"
    assert widest(page) <= 710 - 24


def test_each_roles_instructions_name_every_rule_that_kills(page) -> None:
    """Every death cause of the rules (a new one fails here until the page names it)."""
    words = {"shell": "a shell hits it", "shield": "touches the blue shield", "border": "the edge kills"}
    assert set(words) == set(DEATH_CAUSES)
    for role in ROLES:
        text = page.evaluate("(role) => instructions(role)", role)
        assert role.upper() in text and all(w in text for w in words.values()), role
