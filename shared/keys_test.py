"""Every key of the bus, exactly, and the validation that keeps wildcards out of match ids."""

from __future__ import annotations

import pytest

from shared import keys

M = "m-1_a"


@pytest.mark.parametrize(
    ("key", "expected"),
    [
        (keys.state(M), "tsf/m-1_a/state"),
        (keys.action(M, "bait"), "tsf/m-1_a/action/bait"),
        (keys.action(M, "shooter"), "tsf/m-1_a/action/shooter"),
        (keys.policy(M, "bait"), "tsf/m-1_a/policy/bait"),
        (keys.policy(M, "shooter"), "tsf/m-1_a/policy/shooter"),
        (keys.start(M), "tsf/m-1_a/start"),
        (keys.event(M), "tsf/m-1_a/event"),
        (keys.summary(M), "tsf/m-1_a/summary"),
        (keys.alive(M, "sim"), "tsf/m-1_a/alive/sim"),
        (keys.alive(M, "recorder"), "tsf/m-1_a/alive/recorder"),
        (keys.alive(M, "agent", "bait"), "tsf/m-1_a/alive/agent/bait"),
        (keys.alive(M, "human", "shooter"), "tsf/m-1_a/alive/human/shooter"),
        (keys.actions(M), "tsf/m-1_a/action/*"),
        (keys.seats_alive(M), "tsf/m-1_a/alive/*/*"),
        (keys.everything(M), "tsf/m-1_a/**"),
    ],
)
def test_key(key: str, expected: str) -> None:
    assert key == expected


def test_match_id_limits() -> None:
    assert keys.check_match("a") == "a"
    assert keys.check_match("A" * 64) == "A" * 64


MATCH_KEYS = [
    keys.state,
    keys.start,
    keys.event,
    keys.summary,
    keys.actions,
    keys.seats_alive,
    keys.everything,
]


@pytest.mark.parametrize("bad", ["", "*", "**", "a*", "a/b", "/", "a" * 65, "a b", "a.b", "é", None, 3])
def test_invalid_match_id(bad: object) -> None:
    with pytest.raises(ValueError, match="invalid match id"):
        keys.check_match(bad)  # type: ignore[arg-type]
    for key in MATCH_KEYS:
        with pytest.raises(ValueError):
            key(bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        keys.action(bad, "bait")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        keys.alive(bad, "agent", "bait")  # type: ignore[arg-type]


@pytest.mark.parametrize("role", ["", "*", "pilot", "Bait", "bait/x"])
def test_unknown_role(role: str) -> None:
    for key in (keys.action, keys.policy):
        with pytest.raises(ValueError, match="unknown role"):
            key(M, role)
    with pytest.raises(ValueError, match="unknown role"):
        keys.alive(M, "agent", role)


@pytest.mark.parametrize("service", ["", "*", "viewer", "Sim"])
def test_unknown_service(service: str) -> None:
    with pytest.raises(ValueError, match="unknown service"):
        keys.alive(M, service)


def test_role_of() -> None:
    for role in ("bait", "shooter"):
        assert keys.role_of(keys.action(M, role)) == role
        assert keys.role_of(keys.policy(M, role)) == role
        assert keys.role_of(keys.alive(M, "agent", role)) == role
    assert keys.role_of("bait") == "bait"
    for bad in (keys.state(M), keys.alive(M, "sim"), keys.actions(M), ""):
        with pytest.raises(ValueError):
            keys.role_of(bad)
