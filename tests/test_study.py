"""The whole study end to end with headless stand-in participants over the page's WebSocket
protocol: consent, balanced roles, sessions with hidden agents, a drop-out who resumes, and every
trial recorded with its sidecar."""

from __future__ import annotations

import asyncio
import json
import threading
from concurrent.futures import ThreadPoolExecutor

from services.launch import HUMAN
from services.recorder.recording import load
from services.study.core import StudyConfig, Variant
from services.study.runner import run_study
from services.study.standin import stand_in
from shared.game import other

VARIANTS = (Variant("strong", "B5", "S5"), Variant("adaptive", adapter="adaptive-T30-cem"))


def test_stand_ins_run_the_study_with_a_drop_out_who_resumes(tmp_path, wait_until):
    config = StudyConfig(
        "e2e", VARIANTS, trials=1, trial_seconds=1.5, seed=3, consent="Agree?", end="Bye now."
    )
    stop, urls = threading.Event(), []
    with ThreadPoolExecutor(1) as pool:
        server = pool.submit(
            run_study, config, tmp_path, port=0, stop=stop, on_ready=lambda g: urls.append(g.url)
        )
        try:
            assert wait_until(lambda: urls or server.done(), timeout=10) and urls
            url = urls[0]
            leaver = asyncio.run(stand_in(url, leave_after=10))
            assert not leaver.done and leaver.agents == ["Agent 1"] and leaver.participant == "P001"
            refused = asyncio.run(stand_in(url, resume=(leaver.participant, "not-the-key")))
            assert refused.refused == "unknown participant or resume key"
            back = asyncio.run(stand_in(url, resume=(leaver.participant, leaver.key)))
            second = asyncio.run(stand_in(url))
            dropped = tmp_path / "recordings" / "e2e-P001-s1t1.study.json"
            assert wait_until(dropped.exists, timeout=20), "the cut trial runs out and is written down"
        finally:
            stop.set()
        study = server.result(timeout=10)

    assert back.done and back.role == leaver.role and back.agents == ["Agent 1", "Agent 2"]
    assert second.done and second.participant == "P002" and second.role == other(leaver.role)
    assert (leaver.consent, second.consent, back.consent) == ("Agree?", "Agree?", "")  # asked once
    assert back.end == second.end == "Bye now."
    assert len(back.kills) == len(second.kills) == 2

    attempts = {p.id: [(a["session"], a["trial"], a["attempt"], a["status"]) for a in p.attempts]
                for p in study.participants.values()}  # fmt: skip
    assert attempts == {
        "P001": [(1, 1, 1, "dropped"), (1, 1, 2, "done"), (2, 1, 1, "done")],
        "P002": [(1, 1, 1, "done"), (2, 1, 1, "done")],
    }
    for participant in study.participants.values():
        met = []
        for attempt in participant.attempts:
            sidecar = json.loads((tmp_path / "recordings" / f"{attempt['match']}.study.json").read_text())
            assert sidecar["participant"] == participant.id and sidecar["role"] == participant.role
            assert (sidecar["session"], sidecar["trial"], sidecar["status"]) == (
                attempt["session"], attempt["trial"], attempt["status"]
            )  # fmt: skip
            assert sidecar["agent"] == f"Agent {attempt['session']}"
            variant = next(v for v in VARIANTS if v.name == sidecar["variant"])
            met.append(variant.name)
            recording = load(tmp_path / "recordings" / f"{attempt['match']}.tsflog")
            agent_role = other(participant.role)
            adaptive = variant.adaptive(agent_role, 0)
            agent = adaptive.name if adaptive else getattr(variant, agent_role)
            assert recording.start.policies == {participant.role: HUMAN, agent_role: agent}
            assert bool(recording.adapter) == bool(variant.adapter)  # the adapter watched the person
            assert recording.summary.kills == sidecar["kills"]
            human = [a for _, a in recording.actions if a.role == participant.role]
            assert human and all(a.sender == f"human/{participant.role}" for a in human)
            if attempt["status"] == "done":
                assert any(s.applied[config.roles.index(participant.role)] for s in recording.states)
        assert sorted(set(met)) == sorted(v.name for v in VARIANTS)  # each variant met
