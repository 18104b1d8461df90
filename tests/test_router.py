"""The secured deployment: services log in to a router whose access control drops spoofed puts."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest
import zenoh

from services.agent.scripted import CircleBait, MirrorShooter
from services.agent.service import run_agent
from services.sim.play import play
from services.sim.service import run_sim
from shared import keys
from shared.bus import BusConfig, session
from shared.game import GameConfig
from shared.messages import Action, PolicySwitch, State, Summary
from shared.router import USERS, access_control, run_router

MATCH = "secured"
FRAMES = 90
SEED = 7


def password(user: str) -> str:
    return f"pw-{user}"


@pytest.fixture
def credentials(tmp_path: Path) -> Path:
    path = tmp_path / "credentials.txt"
    path.write_text("".join(f"{user}:{password(user)}\n" for user in USERS))
    return path


def client(endpoint: str, user: str, secret: str | None = None, wait: float = 10.0) -> BusConfig:
    secret = password(user) if secret is None else secret
    return BusConfig("client", (), (endpoint,), user=user, password=secret, wait_router=wait)


def test_access_control_denies_every_known_user_but_the_writers() -> None:
    acl = access_control()
    denied = {
        p["rules"][0]: set(s["usernames"]) for p, s in zip(acl["policies"], acl["subjects"], strict=True)
    }
    assert denied["sim"] == set(USERS) - {"sim"}
    assert denied["bait-seat"] == set(USERS) - {"agent-bait", "human-bait"}
    assert "recorder" in set.intersection(*denied.values())  # the recorder writes nothing


def test_wrong_password_is_refused(endpoint: str, credentials: Path, background, wait_until) -> None:  # noqa: ANN001
    background(run_router, (endpoint,), credentials)
    with session(client(endpoint, "recorder")):  # the right password gets in once the router is up
        pass
    with pytest.raises(zenoh.ZError), session(client(endpoint, "recorder", "guess", wait=0.5)):
        pass


def test_spoofed_puts_are_dropped_and_the_match_is_unchanged(
    endpoint: str,
    credentials: Path,
    background,
    tap,
    wait_until,  # noqa: ANN001
) -> None:
    background(run_router, (endpoint,), credentials)
    with session(client(endpoint, "recorder")) as watcher, session(client(endpoint, "agent-bait")) as spoofer:
        seen = tap(watcher, MATCH)
        for role, policy in (("bait", "circle"), ("shooter", "mirror")):
            background(run_agent, client(endpoint, f"agent-{role}"), MATCH, role, policy, SEED)
        assert wait_until(lambda: seen.is_alive("agent", "bait") and seen.is_alive("agent", "shooter"))
        done = threading.Event()

        def spoof() -> None:  # a logged-in bait agent tries to write what is not its own
            frame = 0
            while not done.is_set():
                spoofer.put(
                    keys.state(MATCH), State(match=MATCH, frame=frame, sender="spoof", frames=FRAMES).encode()
                )
                spoofer.put(
                    keys.action(MATCH, "shooter"),
                    Action(match=MATCH, frame=frame, sender="spoof", role="shooter", action=5).encode(),
                )
                spoofer.put(
                    keys.policy(MATCH, "shooter"),
                    PolicySwitch(
                        match=MATCH, frame=frame, sender="spoof", role="shooter", policy="idle"
                    ).encode(),
                )
                frame += 1
                done.wait(0.005)

        spoofing = threading.Thread(target=spoof)
        spoofing.start()
        try:
            summary = run_sim(client(endpoint, "sim"), MATCH, SEED, GameConfig(frames=FRAMES), "lockstep")
        finally:
            done.set()
            spoofing.join()
        assert wait_until(lambda: seen.of(Summary))
        senders = {m.sender for kind in (State, Action, PolicySwitch) for m in seen.of(kind)}
        assert senders == {"sim", "agent/bait", "agent/shooter"}  # nothing from the spoofer got through
    clean = play(CircleBait(), MirrorShooter(), SEED, GameConfig(frames=FRAMES))
    assert (summary.kills, summary.points, summary.counters) == (clean.kills, clean.points, clean.counters)
    assert summary.drops == {}
