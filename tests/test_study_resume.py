"""A participant who comes back through the platform's link from another browser (a crashed tab, a
phone) resumes where they left off when the link proves it is theirs: signed for their worker id,
or carrying the platform's session id they began with. A stranger who knows only a worker id is
refused with whom to contact, and the refusal is journalled, logged and on the dashboard. Stand-ins
over the page's WebSocket protocol, a real study server."""

from __future__ import annotations

import asyncio
import logging

import pytest
from conftest import STAND_IN_TOKEN

from services.study.admission import CONTACT, NOT_YOURS, TAKEN
from services.study.core import Admission, Study, StudyConfig, Variant
from services.study.crowd import Crowd
from services.study.dashboard import overview
from services.study.serving import Serving
from services.study.standin import stand_in
from shared.secret import signature

VARIANTS = (Variant.read("s", "B5", "S5"),)
MINE = {"STUDY_ID": "S-1", "SESSION_ID": "sess-mine"}


def config(**crowd: object) -> StudyConfig:
    return StudyConfig("back", VARIANTS, trials=2, trial_seconds=1.0, crowd=Crowd(**crowd))


def take_part(url: str, **options: object):  # noqa: ANN201 - a StandInReport
    return asyncio.run(stand_in(url, test=STAND_IN_TOKEN, worker="W-1", **options))


@pytest.mark.long
@pytest.mark.slow
def test_the_platforms_link_resumes_in_another_browser_and_a_stranger_is_refused(
    tmp_path, study_server, caplog
) -> None:
    stop, url, server = study_server(config(contact="lab@example.org"), tmp_path)
    first = take_part(url, link=MINE, leave_after=5)  # the tab crashes in the first trial
    stranger = take_part(url, link={**MINE, "SESSION_ID": "sess-guessed"})
    bare = take_part(url)  # the worker id alone
    with caplog.at_level(logging.WARNING, logger="tsf.study"):
        again = take_part(url, link=MINE)  # another browser: no resume key, the same link
    stop.set()
    study = server.result(timeout=60)
    assert first.participant == "P001" and not first.done
    for refused in (stranger, bare):
        assert refused.refused == f"{NOT_YOURS} If this is wrong, please contact lab@example.org."
    assert again.done and again.participant == "P001" and again.consent == "", "resumed, not asked again"
    assert again.key == first.key and len(again.kills) == 2
    (participant,) = study.participants.values()
    assert participant.refused == ["unproven"], "the second within the minute is not written down again"
    assert [a["status"] for a in participant.attempts] == ["failed", "done", "done"]
    reread = Study(config(contact="lab@example.org"), tmp_path)  # the journal keeps the refusals
    assert reread.participants["P001"].refused == ["unproven"]
    reread.close()


def test_a_finished_participant_is_refused_or_shown_their_end_again(tmp_path, study_server) -> None:
    stop, url, server = study_server(config(completion_code="C0DE"), tmp_path)
    done = take_part(url, link=MINE)
    back = take_part(url, link=MINE)  # their own link: the end again, with the code
    stranger = take_part(url, link={"SESSION_ID": "other"})
    stop.set()
    server.result(timeout=60)
    assert done.done and back.done and back.code == done.code == "C0DE" and back.kills == []
    assert stranger.refused == f"{TAKEN} If this is wrong, please contact {CONTACT}."


@pytest.mark.slow
@pytest.mark.long  # 13 s alone: kept out of the default run
def test_signed_links_resume_and_never_refuses_every_return(tmp_path, study_server) -> None:
    secret = b"a-link-secret-of-the-lab-0123"
    serving = Serving(test_token=STAND_IN_TOKEN, link_secret=secret)
    stop, url, server = study_server(config(), tmp_path / "signed", serving)
    sig = signature(secret, "W-1")
    first = take_part(url, sig=sig, leave_after=5)
    again = take_part(url, sig=sig)  # a signed link is the worker's own, session id or not
    stop.set()
    server.result(timeout=60)
    assert again.done and again.participant == first.participant == "P001"

    stop, url, server = study_server(config(resume="never"), tmp_path / "never")
    first = take_part(url, link=MINE, leave_after=5)
    again = take_part(url, link=MINE)
    resumed = asyncio.run(stand_in(url, test=STAND_IN_TOKEN, resume=(first.participant, first.key)))
    stop.set()
    study = server.result(timeout=60)
    assert again.refused.startswith(NOT_YOURS) and resumed.done, "only the study's own resume link"
    (shown,) = overview(study, Admission(1))["participants"]
    assert (shown["refused"], shown["state"]) == (1, "finished")
