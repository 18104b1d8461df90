"""`tsf humans fit` on recordings made through the real gateway: stand-ins of known skill take part
in a study over the page's WebSocket protocol (their keys sent as the page sends them, the page's
delay real, not modelled: input_ms=0), and the fit, whose stand-ins model the page's delay, finds
their policy and skill again (docs/humans.md, Recovery)."""

from __future__ import annotations

import asyncio

import pytest
from conftest import STAND_IN_TOKEN

from services.adapter.humans import fit
from services.study.core import StudyConfig, Variant
from services.study.runner import Serving
from services.study.standin import stand_in

RECOVERY = 0.25  # the skill's error this test allows (docs/humans.md: the figures it gives)
SKILLS = (0.1, 0.9)  # the stand-ins' skills, one person each


@pytest.mark.slow
def test_fit_recovers_stand_ins_who_played_through_the_gateway(tmp_path, study_server):
    config = StudyConfig("gateway_fit", (Variant.read("s", "B5", "S4"),), trials=3, roles=("bait",), seed=7)
    stop, url, server = study_server(config, tmp_path, Serving(test_token=STAND_IN_TOKEN))
    try:

        async def people():  # noqa: ANN202 - their reports
            return await asyncio.gather(
                *(
                    stand_in(
                        url,
                        {"bait": f"human(B5,skill={skill},input_ms=0)"},
                        seed=3 * (40 + i),  # trials 0, 1, 2 of a person of their own
                        test=STAND_IN_TOKEN,
                        address=f"127.0.0.{i + 2}",
                    )
                    for i, skill in enumerate(SKILLS)
                )
            )

        reports = asyncio.run(asyncio.wait_for(people(), 900))
    finally:
        stop.set()
    server.result(timeout=60)
    assert all(r.done for r in reports), [(r.participant, r.refused) for r in reports]
    skills = {r.participant: skill for r, skill in zip(reports, SKILLS, strict=True)}
    fitted = fit(sorted((tmp_path / "recordings").glob("*.tsflog")), "bait")
    print({name: (person["policy"], person["skill"], skills[name]) for name, person in fitted.items()})
    assert fitted.keys() == skills.keys()
    for name, skill in skills.items():
        assert fitted[name]["policy"] == "B5"
        assert abs(fitted[name]["skill"] - skill) <= RECOVERY, (name, skill, fitted[name])
