"""The study server's limits on a crowd, a reverse proxy and hostile clients, on a real server:
the per-address limits count the address a trusted proxy forwards (and no one else's header),
reloads of one participant are limited (each one cut a trial and wrote a failed attempt), and so
are a dashboard's attempts; every refusal over a limit is logged once per address and minute."""

from __future__ import annotations

import asyncio
import json
import logging

import pytest
import websockets
from conftest import STAND_IN_TOKEN

from services.human.gateway import Web
from services.study.admission import BUSY, RECONNECTS
from services.study.core import StudyConfig, Variant
from services.study.dashboard import TOO_MANY, WRONG
from services.study.serving import Serving
from shared.bus import free_endpoint

CONFIG = StudyConfig("limits", (Variant.read("s", "B5", "S5"),), trials=1, trial_seconds=1.5, seed=1)


async def arrive(url: str, forwarded: str = "", hello: dict | None = None) -> dict:
    """A client that says hello (consenting if asked) and leaves at its id, or its refusal: the
    last message it got."""
    headers = {"X-Forwarded-For": forwarded} if forwarded else {}
    async with websockets.connect(url.replace("http", "ws", 1) + "ws", additional_headers=headers) as ws:
        await ws.send(json.dumps(hello or {"type": "hello"}))
        async for text in ws:
            message = json.loads(text)
            if message["type"] == "consent":
                await ws.send(json.dumps({"type": "consent"}))
            elif message["type"] in ("participant", "refused", "trial", "queue", "wait"):
                return message
    return {"type": "closed"}


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_behind_a_trusted_proxy_each_forwarded_client_has_its_own_limit(tmp_path, study_server, caplog):
    """Five ids a forwarded address at once (the limit per address), then BUSY for it, while another
    forwarded address is served; from an untrusted peer the header is not read (a client could
    write any address in it): all its clients share its own address's limit."""
    serving = Serving(test_token=STAND_IN_TOKEN, arrivals_per_address=0.001)
    _, trusting, _ = study_server(CONFIG, tmp_path / "trusting", serving, Web(port=0, trusted=("127.0.0.1",)))
    _, plain, _ = study_server(CONFIG, tmp_path / "plain", serving)

    async def crowd(url: str, addresses: list[str]) -> list[str]:
        answers = [await arrive(url, a) for a in addresses]
        return [m.get("reason", m["type"]) for m in answers]

    with caplog.at_level(logging.WARNING, "tsf.study"):
        one = asyncio.run(crowd(trusting, ["10.0.0.1"] * 7 + ["10.0.0.2"]))
        forged = asyncio.run(crowd(plain, [f"10.0.1.{i}" for i in range(7)]))
    assert one == ["participant"] * 5 + [BUSY, BUSY, "participant"]
    assert forged == ["participant"] * 5 + [BUSY, BUSY]
    said = [r.getMessage() for r in caplog.records if "over the limits on new participants" in r.getMessage()]
    assert said == [
        "refused 10.0.0.1: over the limits on new participants (said once a minute per address)",
        "refused 127.0.0.1: over the limits on new participants (said once a minute per address)",
    ]


def test_reloads_of_one_participant_are_limited_and_each_limited_one_cuts_nothing(tmp_path, study_server):
    """A participant whose page reconnects again and again: the first reconnects resume (each cut
    the trial being set up, and wrote a failed attempt), then RECONNECTS, and nothing is written."""
    stop, url, server = study_server(CONFIG, tmp_path, Serving(test_token=STAND_IN_TOKEN))

    async def reloads() -> list[str]:
        me = await arrive(url)
        resume = {"type": "hello", "participant": me["participant"], "key": me["key"]}
        answers = []
        for _ in range(12):
            answer = await arrive(url, hello=resume)
            answers.append(answer.get("reason") if answer["type"] == "refused" else "resumed")
        return answers

    answers = asyncio.run(reloads())
    assert answers[:5] == ["resumed"] * 5 and answers[-1] == RECONNECTS, answers
    assert answers.count(RECONNECTS) >= 6  # the bucket refills one every 10 s
    stop.set()
    study = server.result(timeout=60)
    assert len(study.participants["P001"].attempts) <= 2 * (12 - answers.count(RECONNECTS)) + 2


def test_dashboard_attempts_are_limited_per_address_and_logged_once_a_minute(tmp_path, study_server, caplog):
    port = int(free_endpoint().rsplit(":", 1)[1])
    token = "dashboard-token-for-tests-0123"
    serving = Serving(test_token=STAND_IN_TOKEN, dashboard=Web(port=port), dashboard_token=token)
    study_server(CONFIG, tmp_path, serving)

    async def attempts(n: int, token: str) -> list[str]:
        answers = []
        for _ in range(n):
            async with websockets.connect(f"ws://127.0.0.1:{port}/ws") as ws:
                await ws.send(json.dumps({"type": "dashboard", "token": token}))
                message = json.loads(await ws.recv())
                answers.append(message.get("reason", message["type"]))
        return answers

    with caplog.at_level(logging.WARNING, "tsf.study.dashboard"):
        answers = asyncio.run(attempts(30, "not-the-token-0123456789"))
        right = asyncio.run(attempts(1, token))
    assert answers[:10] == [WRONG] * 10 and answers[-1] == TOO_MANY and answers.count(TOO_MANY) >= 18
    assert right == [TOO_MANY], "an address over the limit waits, whatever it shows"
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("dashboard: refused")]
    assert said == [f"dashboard: refused a socket from 127.0.0.1: {WRONG} (said once a minute)"]
