"""The study server's faults and a lab's mistakes, on a real server with its real pool: a policy
that fails to load however it fails is a failed attempt told at once; a pool service that cannot
serve an order refuses it at once (no timeout stands in for its answer); every way back in is under
the one limit on reconnects (0: none); refusals are limited and written down once per address and
minute; a trial played again after a restart says why. (The command line's mistakes, `--check`
included, are in tests/test_mistakes.py.)"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import time
from pathlib import Path

import pytest
import websockets
from conftest import STAND_IN_TOKEN

from services.study.admission import NOT_YOURS, RECONNECTS
from services.study.core import Study, StudyConfig, Variant, variant_order
from services.study.serving import Serving
from services.study.standin import stand_in
from services.study.trial import PROBLEM
from services.study.visit import RESTARTED

ROOT = Path(__file__).resolve().parent.parent
GOOD = Variant.read("good", "B5", "S5")
LINK = {"PROLIFIC_PID": "W-1", "SESSION_ID": "sess-mine"}


def plug_in(directory: Path, monkeypatch, only_here: bool) -> str:  # noqa: ANN001 - pytest's monkeypatch
    """A bait policy from outside whose weights file is gone: it raises OSError as it loads (with
    `only_here`, everywhere but in this process: the server's checks pass, the pool's agent fails).
    Its module is importable here and in the pool's processes."""
    where, module = (f"os.getpid() != {os.getpid()}", "lab_gone_there") if only_here else ("True", "lab_gone")
    (directory / f"{module}.py").write_text(
        "import os\n\n\nclass Gone:\n    key, role, view = 'gone', 'bait', 'world'\n\n"
        f"    def __init__(self):\n        if {where}:\n"
        "            raise OSError(2, 'No such file or directory', 'weights.npz')\n\n"
        "    def reset(self, seed=None):\n        pass\n\n    def act(self, obs):\n        return 0\n"
    )
    monkeypatch.syspath_prepend(str(directory))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join((str(directory), str(ROOT))))
    return f"{module}:Gone"


def broken_first(variants: tuple[Variant, ...]) -> StudyConfig:
    """A study of shooters where P001 meets the first variant first and P002 the second."""

    def config(seed: int) -> StudyConfig:
        return StudyConfig("faults", variants, trials=1, trial_seconds=1.5, seed=seed, roles=("shooter",))

    return config(next(s for s in range(100) if [variant_order(config(s), i)[0] for i in (0, 1)] == [0, 1]))


def sidecar(directory: Path, attempt: dict) -> dict:
    return json.loads((directory / "recordings" / f"{attempt['match']}.study.json").read_text())


def test_a_policy_that_fails_to_load_with_any_error_is_a_failed_attempt_told_at_once(
    tmp_path, study_server, monkeypatch
):
    """An OSError as the trial's match is set up (a weights file gone): the participant has their id
    and is told of a problem (the socket closed 1011 with neither), the attempt is failed with why."""
    variants = (Variant.read("gone", plug_in(tmp_path, monkeypatch, only_here=False), "S5"), GOOD)
    stop, url, server = study_server(broken_first(variants), tmp_path)
    report = asyncio.run(asyncio.wait_for(stand_in(url, test=STAND_IN_TOKEN), 60))
    assert report.participant == "P001" and report.refused == PROBLEM and report.agents == [], report
    stop.set()
    [failed] = server.result(timeout=60).participants["P001"].attempts
    assert failed["status"] == "failed"
    [why] = sidecar(tmp_path, failed)["problems"]
    assert why == (
        "its match cannot be set up: FileNotFoundError: [Errno 2] No such file or directory: 'weights.npz'"
    )


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_a_pool_service_that_cannot_serve_an_order_refuses_it_and_the_slot_is_free_at_once(
    tmp_path, study_server, monkeypatch, capsys
):
    """The server's checks pass, the pool's agent cannot load the policy: it refuses the order
    (MatchRefused), and the participant is told within 5 s (302 s: three attempts of two 30-s waits
    for a token that never came), the attempt failed with the agent's reason; the only slot is free
    at once for the next participant."""
    variants = (Variant.read("gone", plug_in(tmp_path, monkeypatch, only_here=True), "S5"), GOOD)
    stop, url, server = study_server(
        broken_first(variants), tmp_path, Serving(max_matches=1, test_token=STAND_IN_TOKEN)
    )
    start = time.monotonic()
    first = asyncio.run(asyncio.wait_for(stand_in(url, test=STAND_IN_TOKEN), 60))
    told = time.monotonic() - start
    second = asyncio.run(asyncio.wait_for(stand_in(url, test=STAND_IN_TOKEN, leave_after=10), 60))
    with capsys.disabled():
        print(
            f"\nrefused pool order: participant told after {told:.2f} s; next offer {second.offers[0]:.2f} s"
        )
    assert first.refused == PROBLEM and first.agents == [] and told < 5.0, (told, first)
    assert second.agents and second.states == 10 and second.offers[0] < 5.0, "the slot was free at once"
    stop.set()
    [failed] = server.result(timeout=60).participants["P001"].attempts
    assert failed["status"] == "failed"
    why = sidecar(tmp_path, failed)["problems"][0]
    assert "the pool's agent cannot play it: policy:" in why and "FileNotFoundError" in why, why


async def hello(url: str, message: dict) -> dict:
    """A client that says `message` (consenting if asked) and leaves at its id, or its refusal."""
    async with websockets.connect(url.replace("http", "ws", 1) + "ws") as ws:
        await ws.send(json.dumps({"type": "hello", **message}))
        async for text in ws:
            answer = json.loads(text)
            if answer["type"] == "consent":
                await ws.send(json.dumps({"type": "consent"}))
            elif answer["type"] in ("participant", "refused"):
                return answer
    return {"type": "closed"}


def answers(url: str, message: dict, times: int) -> list[str]:
    async def all_of() -> list[str]:
        said = [await hello(url, message) for _ in range(times)]
        return [a.get("reason", a["type"]) for a in said]

    return asyncio.run(all_of())


CONFIG = StudyConfig("back", (GOOD,), trials=1, trial_seconds=1.5, seed=1)


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_every_way_back_in_is_under_the_reconnect_limit_and_0_is_none(tmp_path, study_server):
    """The platform's link reopened 20 times: the first RECONNECT_BURST resume, then RECONNECTS
    (all 20 were taken); with --reconnects 0, neither the id and key nor the link lets anyone back."""
    _, url, _ = study_server(CONFIG, tmp_path / "limited")
    [me] = answers(url, {"link": LINK}, 1)
    assert me == "participant"
    again = answers(url, {"link": LINK}, 20)
    assert again[:5] == ["participant"] * 5 and again[5:] == [RECONNECTS] * 15, again

    _, url, _ = study_server(CONFIG, tmp_path / "none", Serving(test_token=STAND_IN_TOKEN, reconnects=0))
    first = asyncio.run(hello(url, {"link": LINK}))
    resume = {"participant": first["participant"], "key": first["key"]}
    assert answers(url, resume, 1) == answers(url, {"link": LINK}, 1) == [RECONNECTS]


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_refusals_are_limited_and_written_down_once_per_address_and_minute(tmp_path, study_server, caplog):
    """200 hellos with a worker id that has begun and no proof: RECONNECT_BURST are refused as
    NOT_YOURS, the rest as RECONNECTS; one journal line and two warnings (200 and 200 before)."""
    stop, url, server = study_server(CONFIG, tmp_path)
    assert answers(url, {"link": LINK}, 1) == ["participant"]
    with caplog.at_level(logging.WARNING, "tsf.study"):
        said = answers(url, {"link": {**LINK, "SESSION_ID": "sess-guessed"}}, 200)
    assert [s.split(" If this")[0] for s in said[:5]] == [NOT_YOURS] * 5 and said[5:] == [RECONNECTS] * 195
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings == [
        "refused P001 from 127.0.0.1: unproven (said once a minute per address)",
        "refused 127.0.0.1: too many refused attempts (said once a minute per address)",
    ]
    stop.set()
    server.result(timeout=60)
    journal = [json.loads(line) for line in (tmp_path / "study.jsonl").read_text().splitlines()]
    assert [line["refused"] for line in journal if "refused" in line] == ["unproven"]


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_a_trial_played_again_after_a_restart_says_why(tmp_path, study_server):
    """An attempt an earlier server left running (it stopped mid-game) is settled failed; the
    participant back in is told their last game was cut short by the server's stop."""
    study = Study(CONFIG, tmp_path)
    participant = study.arrive()
    study.record(study.next_trial(participant), "running")
    study.close()
    stop, url, server = study_server(CONFIG, tmp_path)
    back = asyncio.run(stand_in(url, resume=(participant.id, participant.key), test=STAND_IN_TOKEN))
    assert back.done and back.again == 1 and back.why == [RESTARTED], back
    stop.set()
    statuses = [a["status"] for a in server.result(timeout=60).participants[participant.id].attempts]
    assert statuses == ["failed", "done"], statuses


def test_check_refuses_a_study_another_server_serves(tmp_path, capsys):
    """`tsf study --check` says what `tsf study` would: the study's directory is served already."""
    from importlib import resources

    from services.commands.app import app
    from services.commands.entry import run
    from services.study.runner import one_server

    config = tmp_path / "static.toml"
    config.write_text((resources.files("services.study") / "configs" / "static.toml").read_text())
    lock = one_server(tmp_path / "studies" / "static")
    try:
        status = run(
            app, ["study", str(config), "--check", "--port", "0", "--out", str(tmp_path / "studies")]
        )
    finally:
        lock.close()
    [line] = capsys.readouterr().err.splitlines()
    assert status == 2 and line == (
        f"tsf study: --out {tmp_path}/studies/static: another study server (pid {os.getpid()}) serves this "
        "study; stop it first"
    )
    assert run(app, ["study", str(config), "--check", "--port", "0", "--out", str(tmp_path / "studies")]) == 0
