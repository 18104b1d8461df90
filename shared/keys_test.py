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
        (keys.ruling(M, "shooter"), "tsf/m-1_a/ruling/shooter"),
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


@pytest.mark.parametrize("namespace", keys.NAMESPACES)
def test_a_namespace_is_no_match_id(namespace: str) -> None:
    with pytest.raises(ValueError, match=f"--match {namespace}: is a bus namespace"):
        keys.state(namespace)
    assert (
        keys.pool_order(namespace) == f"tsf/pool/{namespace}/order"
    )  # a pool, sweep or host may be named so
    assert keys.parse(f"tsf/host/{namespace}/alive").worker == namespace


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
    for key in (keys.action, keys.policy, keys.ruling):
        with pytest.raises(ValueError, match="unknown role"):
            key(M, role)
    with pytest.raises(ValueError, match="unknown role"):
        keys.alive(M, "agent", role)


@pytest.mark.parametrize("service", ["", "*", "viewer", "Sim"])
def test_unknown_service(service: str) -> None:
    with pytest.raises(ValueError, match="unknown service"):
        keys.alive(M, service)


@pytest.mark.parametrize(
    ("key", "parts"),
    [
        (keys.state(M), keys.Key(M, "state")),
        (keys.summary(M), keys.Key(M, "summary")),
        (keys.action(M, "bait"), keys.Key(M, "action", role="bait")),
        (keys.policy(M, "shooter"), keys.Key(M, "policy", role="shooter")),
        (keys.ruling(M, "bait"), keys.Key(M, "ruling", role="bait")),
        (keys.alive(M, "sim"), keys.Key(M, "alive", service="sim")),
        (keys.alive(M, "human", "shooter"), keys.Key(M, "alive", role="shooter", service="human")),
        (keys.job_coordinator("s1"), keys.Key("s1", "coordinator")),
        (keys.job_worker("s1", "w-2"), keys.Key("s1", "worker", worker="w-2")),
        (keys.job_order("s1", "w-2"), keys.Key("s1", "job", worker="w-2")),
        (keys.job_result("s1"), keys.Key("s1", "result")),
        (keys.host_alive("lab-2"), keys.Key("", "alive", worker="lab-2")),
        (keys.host_status("lab-2"), keys.Key("", "status", worker="lab-2")),
        (keys.host_offer("lab-2"), keys.Key("", "offer", worker="lab-2")),
        (keys.host_stop("lab-2"), keys.Key("", "stop", worker="lab-2")),
        (keys.host_done("lab-2"), keys.Key("", "done", worker="lab-2")),
        (keys.host_recording("lab-2", M), keys.Key(M, "recording", worker="lab-2")),
        (keys.pool_order("lab"), keys.Key("", "order", worker="lab")),
        (keys.pool_stop("lab"), keys.Key("", "stop", worker="lab")),
        (keys.pool_refused("lab"), keys.Key("", "refused", worker="lab")),
        (keys.pool_alive("lab", "sim"), keys.Key("", "alive", service="sim", worker="lab")),
    ],
)
def test_parse_inverts_every_builder(key: str, parts: keys.Key) -> None:
    assert keys.parse(key) == parts


@pytest.mark.parametrize(
    "bad",
    [
        keys.actions(M),
        keys.everything(M),
        "tsf/m/state/extra",
        "tsf/m/action",
        "tsf/m/action/pilot",
        "tsf/m/alive/ghost",
        "tsf/m/alive/agent/bait/x",
        keys.host_alive(),
        keys.host_recording("lab-2"),
        "tsf/host/lab-2/offer/x",
        "tsf/host/lab-2/recording",
        keys.pool_alive("lab"),
        "tsf/pool/lab/alive/ghost",
        "tsf/pool/lab/order/x",
        "tsf/sweep/state",  # no match is called sweep, host or pool: their keys are namespaces
        "tsf/host/state",
        "tsf/pool/state",
        "other/m/state",
        "bait",
        "",
    ],
)
def test_parse_refuses_what_no_builder_makes(bad: str) -> None:
    with pytest.raises(ValueError):
        keys.parse(bad)
