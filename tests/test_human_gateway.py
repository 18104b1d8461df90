"""The human gateway on a real bus with a real sim and agent, driven by a WebSocket client as a
browser would: seats by token, held keys as that seat's actions, a dropped connection leaves the
ship idle and the match goes on."""

from __future__ import annotations

import asyncio
import json
import re
import subprocess
import sys
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from urllib.parse import parse_qs, urlsplit

import pytest
import websockets

from services.agent.service import run_agent
from services.human.core import SeatBook
from services.human.gateway import REFUSED, Gateway, Web, seat_handler
from services.human.play import play_with_people
from services.population.seat import SeatSpec
from services.recorder.recording import load
from services.runtime.launch import MatchPlan
from services.sim.service import run_sim
from shared import keys
from shared.game import HUMAN, GameConfig
from shared.messages import Action, State, Summary

MATCH = "human"
TOKEN = "bait-token"


def socket_url(gateway: Gateway) -> str:
    return f"ws://{gateway.web.host}:{gateway.port}/ws"


async def join(gateway: Gateway, role: str, token: str):  # noqa: ANN201 - a client connection
    ws = await websockets.connect(socket_url(gateway))
    await ws.send(json.dumps({"type": "join", "role": role, "token": token}))
    return ws, json.loads(await ws.recv())


def keys_message(**held: bool) -> str:
    return json.dumps({"type": "keys", "left": False, "right": False, "thrust": False, "fire": False, **held})


@pytest.fixture
def gateway(bus):
    with Gateway(
        bus.config(listen=True), seat_handler(MATCH, SeatBook({"bait": TOKEN})), Web(port=0)
    ) as opened:
        yield opened


def test_one_address_holds_at_most_per_address_sockets(bus):
    with Gateway(
        bus.config(listen=True), seat_handler(MATCH, SeatBook({})), Web(port=0, per_address=2)
    ) as gateway:

        async def scenario() -> int:
            held = [await websockets.connect(socket_url(gateway)) for _ in range(2)]
            try:
                await websockets.connect(socket_url(gateway))
            except websockets.InvalidStatus as refused:
                assert "server" not in refused.response.headers  # no version banner
                status = refused.response.status_code
            await held[0].close()
            await asyncio.sleep(0.2)
            again = await websockets.connect(socket_url(gateway))  # a free place again
            for ws in [*held, again]:
                await ws.close()
            return status

        assert asyncio.run(scenario()) == 429


def test_the_page_is_served_and_only_it(gateway):
    page = urllib.request.urlopen(gateway.url, timeout=5)
    assert page.status == 200 and b"<canvas" in page.read()
    script = urllib.request.urlopen(gateway.url + "tsf.js", timeout=5)
    assert script.headers["Content-Type"].startswith("text/javascript")
    with pytest.raises(urllib.error.HTTPError) as missing:
        urllib.request.urlopen(gateway.url + "../pyproject.toml", timeout=5)
    assert missing.value.code == 404


def test_wrong_token_taken_seat_and_closed_seat_are_refused(gateway):
    async def scenario() -> list:
        answers = []
        ws, answer = await join(gateway, "bait", "guess")
        await ws.wait_closed()
        answers.append((answer, ws.close_code))
        holder, welcome = await join(gateway, "bait", TOKEN)
        assert welcome["type"] == "welcome" and welcome["role"] == "bait"
        for role in ("bait", "shooter"):
            ws, answer = await join(gateway, role, TOKEN)
            await ws.wait_closed()
            answers.append((answer, ws.close_code))
        await holder.close()
        ws, welcome = await join(gateway, "bait", TOKEN)  # free again once its holder left
        answers.append((welcome["type"], None))
        await ws.close()
        return answers

    wrong, taken, closed, again = asyncio.run(scenario())
    assert wrong == ({"type": "refused", "reason": "wrong seat token for the bait seat"}, REFUSED)
    assert taken[0]["reason"] == "the bait seat is already taken by another connection"
    assert taken[1] == REFUSED
    assert "not open to people" in closed[0]["reason"]
    assert again == ("welcome", None)


def test_held_keys_play_the_seat_and_a_dropped_connection_leaves_it_idle(bus, gateway, tap, background):
    z = bus.open()
    recorded = tap(z, MATCH)
    background(run_agent, bus.config(), MATCH, "shooter", "mirror")
    sim = background(run_sim, bus.config(), MATCH, 0, GameConfig(frames=120), wait_players=20)

    async def person() -> list[dict]:
        ws, welcome = await join(gateway, "bait", TOKEN)
        assert welcome["type"] == "welcome"
        await ws.send("not json")  # counted and dropped; the connection stays
        await ws.send(keys_message(left=True))
        await ws.send(json.dumps({"type": "ready"}))
        frames = []
        while len(frames) < 40:
            message = json.loads(await ws.recv())
            if message["type"] == "state":
                frames.append(message)
                if len(frames) == 20:
                    await ws.send(keys_message(left=True, fire=True))
        await ws.close()  # the person goes away mid-match
        return frames

    frames = asyncio.run(person())
    summary = sim.result(timeout=30)  # the match ran to its end without its bait
    assert summary.frame == 120
    actions = recorded.of(Action, keys.action(MATCH, "bait"))
    assert actions and all(a.sender == "human/bait" and a.policy == "" for a in actions)
    assert {a.action for a in actions} == {4, 5}  # left, then left + fire
    states = {s.frame: s for s in recorded.of(State)}
    assert any(s.applied[0] == 4 for s in states.values())
    last_human = max(a.frame for a in actions)
    assert all(states[f].applied[0] == 0 for f in range(last_human + 3, 121) if f in states)
    assert frames[-1]["frame"] > frames[0]["frame"]  # the page got the frames as they came
    assert recorded.of(Summary)


async def play_through(link: str, **held: bool) -> dict:
    """A person who opens `link`, presses start, holds `held` and waits for the match's end."""
    query = parse_qs(urlsplit(link).query)
    async with websockets.connect(f"ws://{urlsplit(link).netloc}/ws") as ws:
        role, token = query["role"][0], query["token"][0]
        await ws.send(json.dumps({"type": "join", "role": role, "token": token}))
        await ws.send(keys_message(**held))  # held before the start, so every action plays them
        await ws.send(json.dumps({"type": "ready"}))
        while (message := json.loads(await ws.recv()))["type"] != "end":
            pass
        return message


def test_tsf_play_prints_the_link_and_plays_with_the_adaptive_agent(tmp_path):
    """`tsf play --role shooter --partner adaptive`, as a person runs it, with a scripted client."""
    command = [
        sys.executable,
        "-m",
        "services.commands",
        "play",
        "--role",
        "shooter",
        "--partner",
        "adaptive",
    ]
    command += ["--window", "30", "--duration", "3", "--port", "0", "--out", str(tmp_path), "--match", "play"]
    with subprocess.Popen(command, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True) as tsf:
        try:
            line = tsf.stdout.readline()
            link = re.search(r"shooter: open (http://\S+)", line)
            assert link, line
            end = asyncio.run(play_through(link.group(1), right=True, thrust=True))
            assert tsf.wait(30) == 0
        finally:
            tsf.kill()
    recording = load(tmp_path / "play.tsflog")
    assert recording.summary.kills == end["kills"] and recording.summary.frame == 90
    grown = "adaptive-T30-bayes-dwell-ood-guard_partners-groups"  # `tsf play`'s default: the grown library's
    assert recording.start.policies == {"bait": grown, "shooter": "human"}
    assert recording.adapter and all(status.role == "bait" for status in recording.adapter)
    assert {a.action for _, a in recording.actions if a.role == "shooter"} == {10}  # right + thrust


def test_two_people_play_one_match(tmp_path, wait_until):
    """`--partner human`: both seats from browsers, each with its own link."""
    person = SeatSpec.parse(HUMAN)
    plan = MatchPlan("pair", 0, 60, bait=person, shooter=person, directory=tmp_path, wait_players=30)
    links: list[dict[str, str]] = []
    with ThreadPoolExecutor(1) as pool:
        running = pool.submit(play_with_people, plan, port=0, on_links=links.append)
        assert wait_until(lambda: links or running.done(), timeout=30) and links

        async def both() -> list[dict]:
            return await asyncio.gather(
                play_through(links[0]["bait"], thrust=True), play_through(links[0]["shooter"], fire=True)
            )

        ends = asyncio.run(both())
        summary, path = running.result(timeout=30)
    assert ends[0] == ends[1] and summary.frame == 60
    played = {(a.role, a.sender, a.action) for _, a in load(path).actions}
    assert played == {("bait", "human/bait", 2), ("shooter", "human/shooter", 1)}


def raw_request(gateway: Gateway, *headers: str) -> bytes:
    """The status line a raw HTTP upgrade request with exactly `headers` gets."""
    import socket

    lines = ["GET /ws HTTP/1.1", *headers, "Upgrade: websocket", "Connection: Upgrade"]
    lines += ["Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13", "", ""]
    with socket.create_connection((gateway.web.host, gateway.port), timeout=5) as s:
        s.sendall("\r\n".join(lines).encode())
        return s.recv(4096).split(b"\r\n", 1)[0]


def test_two_host_or_origin_headers_are_refused_with_400_and_the_scheme_must_match(gateway):
    host = f"Host: {gateway.web.host}:{gateway.port}"
    own = f"Origin: http://{gateway.web.host}:{gateway.port}"
    assert raw_request(gateway, host, own) == b"HTTP/1.1 101 Switching Protocols"
    assert raw_request(gateway, host, host, own) == b"HTTP/1.1 400 Bad Request"
    assert raw_request(gateway, host, own, "Origin: http://evil.example") == b"HTTP/1.1 400 Bad Request"
    https = f"Origin: https://{gateway.web.host}:{gateway.port}"  # a page over TLS of the same host
    assert raw_request(gateway, host, https) == b"HTTP/1.1 403 Forbidden"
    assert raw_request(gateway, host, "Origin: http://evil.example") == b"HTTP/1.1 403 Forbidden"


def test_a_rebinding_domain_is_refused_and_a_configured_public_origin_is_taken(gateway):
    """A page of evil.example whose name now points at this server sends Host and Origin both
    evil.example: refused (421) by a server listening on an IP without --origin; localhost and the
    IP are taken, and a public name given as an origin (a reverse proxy's) is taken too."""
    evil = (f"Host: evil.example:{gateway.port}", f"Origin: http://evil.example:{gateway.port}")
    assert raw_request(gateway, *evil) == b"HTTP/1.1 421 Misdirected Request"
    assert (
        raw_request(gateway, "Origin: http://evil.example") == b"HTTP/1.1 421 Misdirected Request"
    )  # no Host
    local = (f"Host: localhost:{gateway.port}", f"Origin: http://localhost:{gateway.port}")
    assert raw_request(gateway, *local) == b"HTTP/1.1 101 Switching Protocols"
    public = ("Host: study.example.org", "Origin: https://study.example.org")
    assert raw_request(gateway, *public) == b"HTTP/1.1 421 Misdirected Request"
    web = Web(port=0, origins=("https://study.example.org",))
    with Gateway(None, seat_handler(MATCH, SeatBook({})), web) as proxied:
        assert raw_request(proxied, *public) == b"HTTP/1.1 101 Switching Protocols"
        assert (
            raw_request(proxied, "Host: Study.Example.org", public[1]) == b"HTTP/1.1 101 Switching Protocols"
        )
        evil = (f"Host: evil.example:{proxied.port}", f"Origin: http://evil.example:{proxied.port}")
        assert raw_request(proxied, *evil) == b"HTTP/1.1 421 Misdirected Request"
