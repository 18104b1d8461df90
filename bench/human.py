"""A person's seat through the human gateway, against an agent's seat, in real-time matches.

By default a WebSocket client stands in for the browser (it holds keys and reads every frame). Measured: the
sim's round trip over both seats; per seat, from the recording, the recorder's receive time of
each action minus the state's send time (both on this machine's clock; the recorder runs at low
CPU priority, so its tail shows the machine's load as much as the seat's); and how many of the
match's frames reached the client.

    .venv/bin/python bench/human.py [--seconds 20]

`--page`: the page itself in Debian's Chromium (Playwright), through the real gateway: the delay
from a key press to the ship's response on screen, in frames and ms, and what drawing a frame
costs. `--play-test ROLE`: a scripted player at human timing (Playwright key events: a reaction
time, intermittent decisions, held keys) plays ROLE from the page against a library agent; its
kills/min, beside the same pair's in-process figure at machine timing (`--reaction-ms`,
`--decide-ms`, `--hold-ms` change the timing: Timing).

    .venv/bin/python bench/human.py --page [--presses 30]
    .venv/bin/python bench/human.py --play-test bait [--policy circle --partner S5 --games 3 --seconds 60]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import json
import math
import random
import statistics
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import websockets

from services.adapter.seat import SeatSpec
from services.agent.seats import policy_for
from services.human.core import action_keys
from services.human.play import play_with_people
from services.recorder.recording import load
from services.runtime.launch import MatchPlan
from services.sim.observation import as_observation
from services.sim.play import play, summarize
from shared.game import FPS, HUMAN, GameConfig, other


async def browser(link: str) -> int:
    """Join, start, hold thrust and count the frames received until the match's end."""
    query = parse_qs(urlsplit(link).query)
    frames = 0
    async with websockets.connect(f"ws://{urlsplit(link).netloc}/ws") as ws:
        await ws.send(json.dumps({"type": "join", "role": "bait", "token": query["token"][0]}))
        keys = {"left": False, "right": False, "thrust": True, "fire": False}
        await ws.send(json.dumps({"type": "keys", **keys}))
        await ws.send(json.dumps({"type": "ready"}))
        while (message := json.loads(await ws.recv()))["type"] != "end":
            frames += message["type"] == "state"
    return frames


def answer_ms(recording, role: str) -> list[float]:  # noqa: ANN001 - a Recording
    sent = {state.frame: state.sent_ns for state in recording.states}
    return [(t - sent[a.frame]) / 1e6 for t, a in recording.actions if a.role == role and a.frame in sent]


# ---------------------------------------------------------------- the page in Chromium

CHROMIUM = "/usr/bin/chromium"  # Debian's; never a downloaded browser
KEY_NAMES = {"left": "ArrowLeft", "right": "ArrowRight", "thrust": "ArrowUp", "fire": "Space"}
# What the bench records in the page: each key press (the event's time) and each frame drawn.
RECORD = """() => {
  window.bench = { keys: [], draws: [] };
  document.addEventListener("keydown", (e) => { if (!e.repeat) window.bench.keys.push(e.timeStamp); }, true);
  tsf.onDraw = (s) => window.bench.draws.push([performance.now(), s.frame, s.ships[0][2]]);
}"""


@contextlib.contextmanager
def seat_page(partner: str, seconds: float, role: str = "bait"):  # noqa: ANN201 - (page, future)
    """A real-time match with a person's seat (`role`) played from Chromium's page against `partner`,
    started (the page's Start pressed): yields (page, the running match)."""
    from playwright.sync_api import sync_playwright

    links: list[dict[str, str]] = []
    ready = threading.Event()
    seats = {role: SeatSpec.parse(HUMAN), other(role): SeatSpec.parse(partner)}
    with (
        tempfile.TemporaryDirectory() as directory,
        ThreadPoolExecutor(1) as pool,
        sync_playwright() as playwright,
    ):
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        plan = MatchPlan(
            f"bench-page-{role}", frames=round(seconds * FPS), directory=Path(directory), **seats
        )
        running = pool.submit(
            play_with_people, plan, port=0, on_links=lambda urls: (links.append(urls), ready.set())
        )
        if not ready.wait(60):
            raise SystemExit(f"the match did not start: {running.exception(0)}")
        page = browser.new_page(viewport={"width": 900, "height": 800})
        page.goto(links[0][role] + "&obs=1")
        until(page, "window.tsf.phase === 'instructions'", 30)
        page.keyboard.press("Space")
        until(page, "window.tsf.phase === 'playing'", 60)
        yield page, running
        until(page, "window.tsf.phase === 'ended'", seconds + 60)
        browser.close()


def until(page, expression: str, seconds: float) -> None:  # noqa: ANN001 - a Playwright page
    deadline = time.monotonic() + seconds
    while not page.evaluate(expression):
        if time.monotonic() > deadline:
            raise SystemExit(f"the page never reached {expression}")
        page.wait_for_timeout(20)


def key_to_screen(presses: int, seed: int) -> None:
    """Press and release the left arrow `presses` times at random moments; for each press, the
    frames from the last frame drawn before it to the first drawn whose bait heading turned, and
    the milliseconds from the key event to that draw. The bait sits at its spawn point (outside
    the fortress's region, so nothing else turns or kills it) against the agent S5."""
    rng = random.Random(seed)
    seconds = presses * 1.2 + 5
    with seat_page("S5", seconds) as (page, running):
        page.evaluate(RECORD)
        page.wait_for_timeout(500)
        for _ in range(presses):
            page.keyboard.down("ArrowLeft")
            page.wait_for_timeout(250)
            page.keyboard.up("ArrowLeft")
            page.wait_for_timeout(rng.uniform(400, 800))
        record = page.evaluate("window.bench")
        frame = page.evaluate("window.tsf.frame")
        cost = page.evaluate(
            """(s) => { const t = performance.now();
               for (let i = 0; i < 300; i++) tsf.render(tsf.geometry, s, [], 'bait');
               return (performance.now() - t) / 300; }""",
            frame,
        )
    running.result(60)
    frames, ms = [], []
    draws = record["draws"]
    for pressed in record["keys"]:
        before = [d for d in draws if d[0] <= pressed]
        if not before:
            continue
        _, f0, heading = before[-1]
        turned = next((d for d in draws if d[0] > pressed and d[2] != heading), None)
        if turned is not None:
            frames.append(turned[1] - f0)
            ms.append(turned[0] - pressed)
    print(f"key press -> the ship turning on screen, in Chromium through the gateway, {len(frames)} presses:")
    print(
        f"  frames (from the frame on screen at the press): median {statistics.median(frames)}, "
        f"p90 {statistics.quantiles(frames, n=10)[8]:.0f}, max {max(frames)}; "
        f"ms: median {statistics.median(ms):.0f}, p90 {statistics.quantiles(ms, n=10)[8]:.0f}, "
        f"max {max(ms):.0f}"
    )
    span = draws[-1][1] - draws[0][1] + 1
    print(
        f"  the page drew {len(draws)} of the {span} frames the sim played meanwhile; "
        f"drawing one frame costs {cost:.2f} ms"
    )


@dataclass(frozen=True)
class Timing:
    """A scripted player's timing. The defaults are human timing, our choices within what people
    show: a visual choice reaction time of 200-300 ms, corrections a few times a second, key
    presses of 100 ms and more."""

    reaction_ms: float = 250.0  # median of a lognormal (sigma 0.2): from the frame seen to the keys
    decide_ms: tuple[float, float] = (100.0, 200.0)  # uniform: time between two decisions
    hold_ms: float = 100.0  # a key stays down (or up) at least this long

    def __str__(self) -> str:
        low, high = self.decide_ms
        every = f"a decision every {low:g}-{high:g} ms"
        return f"reaction {self.reaction_ms:g} ms, {every}, holds {self.hold_ms:g}+ ms"


def play_test(
    role: str, policy_key: str, partner: str, seconds: float, games: int, seed: int, timing: Timing
) -> None:
    """`games` real-time matches in which a scripted player plays `role` from the page with keys, as
    a person would: it looks at the frame on screen every `decide_ms`, picks the keys `policy_key`
    would play, and presses them `reaction_ms` later, each key held `hold_ms` at least."""
    rng = random.Random(seed)
    rates = []
    for game in range(games):
        policy = policy_for(policy_key, role)
        policy.reset(seed + game)
        with seat_page(partner, seconds, role) as (page, running):
            held = dict.fromkeys(KEY_NAMES, False)
            changed = dict.fromkeys(KEY_NAMES, 0.0)
            planned: list[tuple[float, dict[str, bool]]] = []
            decide = time.monotonic()
            while page.evaluate("window.tsf.phase") == "playing":
                now = time.monotonic()
                if now >= decide:
                    frame = page.evaluate("window.tsf.frame")
                    action = policy.act(as_observation(frame["obs"], policy.view))
                    delay = rng.lognormvariate(math.log(timing.reaction_ms), 0.2) / 1000
                    planned.append((now + delay, dataclasses.asdict(action_keys(action))))
                    decide = now + rng.uniform(*timing.decide_ms) / 1000
                while planned and planned[0][0] <= now:
                    _, wanted = planned.pop(0)
                    for key, down in wanted.items():
                        if down != held[key] and now - changed[key] >= timing.hold_ms / 1000:
                            (page.keyboard.down if down else page.keyboard.up)(KEY_NAMES[key])
                            held[key], changed[key] = down, now
                page.wait_for_timeout(10)
        summary, _ = running.result(60)
        rates.append(summary.kills_per_minute)
        print(
            f"  game {game + 1}: {summary.kills} kills in {summary.frame / FPS:.0f} s, "
            f"{summary.points} points"
        )
    se = statistics.stdev(rates) / math.sqrt(len(rates)) if len(rates) > 1 else float("nan")
    print(
        f"scripted {role} {policy_key} from the page ({timing}), with {partner}: "
        f"{statistics.mean(rates):.2f} kills/min (s.e. {se:.2f}) over {games} games of {seconds:.0f} s"
    )
    seats = {role: policy_key, other(role): partner}
    config = GameConfig(frames=round(seconds * FPS))
    machine = summarize(
        [
            play(policy_for(seats["bait"], "bait"), policy_for(seats["shooter"], "shooter"), s, config)
            for s in range(20)
        ]
    )
    print(f"  the same pair in-process, at machine timing: {machine}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="length of the match")
    parser.add_argument("--page", action="store_true", help="key press -> screen in Chromium")
    parser.add_argument("--presses", type=int, default=30, help="key presses timed (--page)")
    parser.add_argument("--play-test", choices=("bait", "shooter"), help="a scripted player at human timing")
    parser.add_argument("--policy", help="what the scripted player plays (default circle / mirror)")
    parser.add_argument("--partner", help="the library agent beside it (default S5 / B5)")
    parser.add_argument("--games", type=int, default=3, help="games played (--play-test)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reaction-ms", type=float, default=Timing.reaction_ms, help="median reaction time")
    parser.add_argument(
        "--decide-ms", type=float, nargs=2, default=Timing.decide_ms, help="between decisions"
    )
    parser.add_argument("--hold-ms", type=float, default=Timing.hold_ms, help="shortest key press")
    args = parser.parse_args()
    if args.page:
        key_to_screen(args.presses, args.seed)
        return
    if args.play_test:
        role = args.play_test
        policy = args.policy or ("circle" if role == "bait" else "mirror")
        partner = args.partner or ("S5" if role == "bait" else "B5")
        timing = Timing(args.reaction_ms, tuple(args.decide_ms), args.hold_ms)
        play_test(role, policy, partner, args.seconds, args.games, args.seed, timing)
        return
    frames = round(args.seconds * FPS)
    links: list[dict[str, str]] = []
    ready = threading.Event()
    with tempfile.TemporaryDirectory() as directory, ThreadPoolExecutor(1) as pool:
        seats = {"bait": SeatSpec.parse(HUMAN), "shooter": SeatSpec.parse("S5")}
        plan = MatchPlan("bench-human", frames=frames, directory=Path(directory), **seats)
        running = pool.submit(
            play_with_people, plan, port=0, on_links=lambda urls: (links.append(urls), ready.set())
        )
        ready.wait(30)
        received = asyncio.run(browser(links[0]["bait"]))
        summary, path = running.result(60)
        recording = load(path)
        print(f"real time, {summary.frame} frames; the client received {received} frames")
        t = summary.timing
        print(
            f"  both seats, as the sim measures (state -> action -> sim): median "
            f"{t['round_trip_ms_p50']:.2f} ms, p99 {t['round_trip_ms_p99']:.2f} ms"
        )
        for role, who in (("bait", "person via the gateway"), ("shooter", "agent S5")):
            times = answer_ms(recording, role)
            p99 = statistics.quantiles(times, n=100)[98]
            print(
                f"  {role} ({who}): state sent -> action at the recorder: median "
                f"{statistics.median(times):.2f} ms, p99 {p99:.2f} ms over {len(times)} actions"
            )


if __name__ == "__main__":
    main()
