"""`tsf humans fit` on recordings made through the real gateway: stand-ins of known skill, and of
known parameters, take part in a study over the page's WebSocket protocol (their keys sent as the
page sends them, the page's delay real, not modelled: input_ms=0), and the fit, whose stand-ins
model the page's delay, finds their policy, skill and parameters again (docs/humans.md, Recovery)."""

from __future__ import annotations

import asyncio

import pytest
from conftest import STAND_IN_TOKEN

from services.proxy.humans import fit, human_with
from services.study.core import StudyConfig, Variant
from services.study.serving import Serving
from services.study.standin import stand_in

RECOVERY = 0.25  # the skill's error this test allows (docs/humans.md: the figures it gives)
SKILLS = (0.1, 0.9)  # the stand-ins' skills, one person each
KNOWN = {  # and two people of known parameters (a sloppier second one, lapses 6 a minute and slips
    # 8 %, was taken for B9 in one run: docs/humans.md)
    "reaction_ms": (180, 270),
    "look_ms": (100, 250),
    "lapses": (1, 3),
    "slip": (0.02, 0.05),
    "foresight": (0.8, 0.3),
    "hold_ms": (67, 100),
    "fire_ms": (133, 200),
    "fire_gap_ms": (67, 100),
}


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_fit_recovers_stand_ins_who_played_through_the_gateway(tmp_path, study_server):
    hands = [f"human(B5,skill={skill},input_ms=0)" for skill in SKILLS]
    truths = [{name: values[i] for name, values in KNOWN.items()} for i in range(2)]
    hands += [human_with("B5", truth, input_ms=0) for truth in truths]
    config = StudyConfig("gateway_fit", (Variant.read("s", "B5", "S4"),), trials=3, roles=("bait",), seed=7)
    stop, url, server = study_server(config, tmp_path, Serving(test_token=STAND_IN_TOKEN))
    try:

        async def people():  # noqa: ANN202 - their reports
            return await asyncio.gather(
                *(
                    stand_in(
                        url,
                        {"bait": person},
                        seed=3 * (40 + i),  # trials 0, 1, 2 of a person of their own
                        test=STAND_IN_TOKEN,
                        address=f"127.0.0.{i + 2}",
                    )
                    for i, person in enumerate(hands)
                )
            )

        reports = asyncio.run(asyncio.wait_for(people(), 900))
    finally:
        stop.set()
    server.result(timeout=60)
    assert all(r.done for r in reports), [(r.participant, r.refused) for r in reports]
    skills = {r.participant: skill for r, skill in zip(reports, SKILLS, strict=False)}
    known = {r.participant: truth for r, truth in zip(reports[len(SKILLS) :], truths, strict=True)}
    fitted = fit(sorted((tmp_path / "recordings").glob("*.tsflog")), "bait")
    print({name: (person["policy"], person["skill"], skills.get(name)) for name, person in fitted.items()})
    assert fitted.keys() == skills.keys() | known.keys()
    assert all(person["policy"] == "B5" for person in fitted.values())
    for name, skill in skills.items():
        assert abs(fitted[name]["skill"] - skill) <= RECOVERY, (name, skill, fitted[name])
    for name, truth in known.items():
        found, errors = fitted[name]["parameters"], fitted[name]["errors"]
        print(name, {k: (v, round(found[k], 3), round(errors.get(k, 0.0), 3)) for k, v in truth.items()})
        assert abs(found["hold_ms"] - truth["hold_ms"]) < 1000 / 30, (name, found)
        for parameter, error in errors.items():
            assert abs(found[parameter] - truth[parameter]) <= 3 * error, (name, parameter, found, errors)
