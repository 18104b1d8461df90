"""The match host's bookkeeping, apart from the bus: offers in and out, refusals, chunks."""

from __future__ import annotations

import dataclasses
import threading
from pathlib import Path

import pytest

from services.adapter.core import AdapterConfig
from services.runtime.launch import MatchPlan
from services.study.host import Host, offer_of, plan_of, sha256
from shared.bus import BusConfig
from shared.game import HUMAN
from shared.messages import CHUNK, MatchOffer, decode

ROUTER = BusConfig(connect=("tcp/10.0.0.1:7447",))


@pytest.mark.parametrize(
    "seats",
    [
        {"bait": HUMAN, "shooter": "S5"},
        {"shooter": HUMAN, "adapter": AdapterConfig.parse("adaptive-T30-cem", role="bait", seed=9)},
    ],
)
def test_an_offer_asks_for_the_same_match_run_on_the_host(seats: dict, tmp_path: Path) -> None:
    plan = MatchPlan("st-P001-s1t1", 9, 300, directory=Path("study"), wait_players=900, timeout=1000, **seats)
    offer = decode(offer_of(plan, "study").encode(), MatchOffer)
    there = plan_of(offer, tmp_path, ROUTER)
    assert there.policies() == plan.policies() and there.adapter == plan.adapter
    assert (there.match, there.seed, there.frames, there.wait_players, there.timeout) == (
        plan.match, 9, 300, 900, 1000
    )  # fmt: skip
    assert there.directory == tmp_path and there.peers == ROUTER.connect, "its sim joins the router"


def test_an_offer_the_host_cannot_fill_is_refused(tmp_path: Path) -> None:
    plan = MatchPlan("m", bait=HUMAN, shooter="S5")
    offer = offer_of(plan, "study")
    with pytest.raises(ValueError, match="--shooter"):
        plan_of(dataclasses.replace(offer, shooter="S99"), tmp_path, ROUTER)
    with pytest.raises(ValueError, match="adaptive agent"):
        plan_of(dataclasses.replace(offer, adapter="adaptive-T30-cem"), tmp_path, ROUTER)
    host = Host("lab-1", 1, tmp_path)
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
    host = Host("lab-1", 1, tmp_path)
    with pytest.raises(ValueError, match="no recording of m"):
        host.chunk("m", 0)
    host.finished["m"] = path
    data = b""
    while len(data) < path.stat().st_size:
        chunk = host.chunk("m", len(data))
        assert chunk.size == path.stat().st_size and 0 < len(chunk.data) <= CHUNK
        data += chunk.data
    assert data == path.read_bytes() and len(sha256(path)) == 64
    assert host.chunk("m", len(data)).data == b""
