"""The match host's bookkeeping, apart from the bus: offers in and out, refusals, chunks, and the
seal on every message."""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path

import pytest

from services.population.seat import SeatSpec
from services.runtime.launch import MatchPlan
from services.study.host import Host, offer_of, plan_of, sha256
from shared import keys
from shared.bus import BusConfig
from shared.game import HUMAN
from shared.messages import (
    CHUNK,
    MatchOffer,
    MatchStop,
    MessageError,
    authentic,
    decode,
    recording_query,
    sealed,
)

ROUTER = BusConfig(connect=("tcp/10.0.0.1:7447",))
PERSON_AND_S5 = {"bait": SeatSpec.parse(HUMAN), "shooter": SeatSpec.parse("S5")}
SECRET = b"the-hosts-secret-0123"


@pytest.mark.parametrize(
    "seats",
    [
        PERSON_AND_S5,
        {"shooter": SeatSpec.parse(HUMAN), "bait": SeatSpec.parse("adaptive-T30-cem")},
    ],
)
def test_an_offer_asks_for_the_same_match_run_on_the_host(seats: dict, tmp_path: Path) -> None:
    plan = MatchPlan("st-P001-s1t1", 9, 300, directory=Path("study"), wait_players=900, timeout=1000, **seats)
    offer = decode(offer_of(plan, "study").encode(), MatchOffer)
    there = plan_of(offer, tmp_path)
    assert there.seats == plan.seats and there.policies() == plan.policies() and there.adapter == plan.adapter
    assert (there.match, there.seed, there.frames, there.wait_players, there.timeout) == (
        plan.match, 9, 300, 900, 1000
    )  # fmt: skip
    assert there.directory == tmp_path


def test_an_offer_the_host_cannot_fill_is_refused(tmp_path: Path) -> None:
    plan = MatchPlan("m", **PERSON_AND_S5)
    offer = offer_of(plan, "study")
    with pytest.raises(ValueError, match="--shooter"):
        plan_of(dataclasses.replace(offer, shooter="S99"), tmp_path)
    with pytest.raises(ValueError, match="adaptive agent"):
        plan_of(dataclasses.replace(offer, adapter="adaptive-T30-cem"), tmp_path)
    host = Host("lab-1", 1, tmp_path, SECRET)
    assert host.refusal(offer) == ""
    assert "update its checkout" in host.refusal(dataclasses.replace(offer, library="0" * 16))
    host.running["other"] = (threading.Event(), threading.Thread())
    assert host.refusal(offer) == "host lab-1 has no free slot" and host.status().free == 0
    host.running.clear()
    host.finished["m"] = tmp_path / "m.tsflog"
    assert "offered before" in host.refusal(offer)


def test_a_recording_is_served_in_chunks_that_add_up_to_its_hash(tmp_path: Path) -> None:
    path = tmp_path / "m.tsflog"
    path.write_bytes(bytes(range(256)) * (CHUNK // 100))
    host = Host("lab-1", 1, tmp_path, SECRET)
    key = keys.host_recording("lab-1", "m")

    def chunk(offset: int):  # noqa: ANN202 - a RecordingChunk
        """The chunk the server's signed query gets."""
        parameters = dict(p.split("=") for p in recording_query(key, offset, SECRET).split("?")[1].split(";"))
        return host.chunk(key, parameters["offset"], parameters["auth"])

    with pytest.raises(ValueError, match="no recording of m"):
        chunk(0)
    host.finished["m"] = path
    data = b""
    while len(data) < path.stat().st_size:
        served = chunk(len(data))
        assert served.size == path.stat().st_size and 0 < len(served.data) <= CHUNK
        assert authentic(served, SECRET) and not authentic(served, b"another-secret-0123")
        data += served.data
    assert data == path.read_bytes() and len(sha256(path)) == 64
    assert chunk(len(data)).data == b""
    signed = recording_query(key, 0, SECRET).rsplit("=", 1)[1]
    for offset, auth in (("0", ""), ("0", None), ("1", signed), ("0", signed.upper()), ("0", "é" * 64)):
        with pytest.raises(MessageError, match="unauthenticated"):
            host.chunk(key, offset, auth)


def test_a_message_is_authentic_only_as_sealed_with_the_secret(tmp_path: Path) -> None:
    """A host takes an offer or a stop only if the study's secret sealed it, and seals its own."""
    host = Host("lab-1", 1, tmp_path, SECRET)
    offer = offer_of(MatchPlan("m", **PERSON_AND_S5), "study")
    good = decode(sealed(offer, SECRET).encode(), MatchOffer)  # as it arrives
    host.check(good)
    for bad in (
        offer,  # unsealed
        sealed(offer, b"another-secret-0123"),
        dataclasses.replace(good, seed=1),  # altered after sealing
        dataclasses.replace(good, auth=good.auth.upper()),
    ):
        with pytest.raises(MessageError, match="unauthenticated"):
            host.check(bad)
    with pytest.raises(MessageError, match="unauthenticated"):
        host.check(MatchStop(match="m", frame=0, sender="study"))
    assert authentic(host.status(), SECRET) and not authentic(host.status(), b"another-secret-0123")
    with pytest.raises(ValueError, match="secret"):
        Host("lab-1", 1, tmp_path, b"")
