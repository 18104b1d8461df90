"""One participant's visit: their practice game, attention checks (services/study/crowd.py) and
trials in order, each run by the TrialRunner (services/study/trial.py); a failed trial is offered
again, and a problem is shown once RETRIES in a row failed; at the end the completion code and the
platform's redirect."""

from __future__ import annotations

import logging

from services.human.core import points
from services.study.connection import Socket
from services.study.core import Participant, Study, Trial
from services.study.crowd import FAILS, attention_check
from services.study.trial import PROBLEM, TrialRunner
from shared import page
from shared.game import GameConfig
from shared.page import Done, Problem, Screened

log = logging.getLogger("tsf.study")
RETRIES = 3  # failed attempts in a row before the participant is told of a problem
SCREENED = "Thank you. This study cannot go on: two attention checks were not passed."
FAILED = "The last game could not be completed; please play it again."
CUT = "Your last game was cut short when the page was closed or reloaded; please play it again."
RESTARTED = "Your last game was cut short when the study server stopped; please play it again."


class Visit:
    """One participant's session: their practice game, attention checks and trials in order, a
    failed trial offered again, until the study is done for them or they leave."""

    def __init__(
        self, study: Study, runner: TrialRunner, socket: Socket, participant: Participant, obs: bool
    ) -> None:
        self.study, self.runner, self.socket, self.participant, self.obs = (
            study,
            runner,
            socket,
            participant,
            obs,
        )

    def offer(self, trial: Trial, last: int | None, why: str) -> page.Trial:
        """The `trial` message: where the game sits in the study, what to read first, and why it
        is played again ("": it is not)."""
        config = self.study.config
        return page.Trial(
            role=trial.role, agent=trial.agent, last=last, session=trial.session,
            sessions=len(config.variants), trial=trial.trial, trials=config.trials, again=bool(why), why=why,
            practice=trial.practice,
            instructions=config.instructions.get(trial.role, ""),
            points=points(GameConfig()) if config.show_points else None,
        )  # fmt: skip

    async def attend(self, trial: Trial) -> bool:
        """The attention check due before `trial`, if any; False (the page sent on to the
        screened-out address) once the participant has failed FAILS, or if they left."""
        config, socket, participant = self.study.config, self.socket, self.participant
        if config.crowd.check_due(trial.session, trial.trial, len(participant.checks)):
            check, word = attention_check(f"{config.seed}/{participant.id}/check/{len(participant.checks)}")
            socket.send(check)
            if not await socket.wait_for("answer"):
                return False
            self.study.check(participant, socket.answer == word)
        if participant.screened:
            redirect = config.crowd.redirect(config.crowd.screened_out_url, participant.code)
            socket.send(Screened(text=SCREENED, redirect=redirect))
            log.info("participant %s is screened out: %d attention checks failed", participant.id, FAILS)
            await socket.close()
            return False
        return True

    def replayed(self, trial: Trial) -> str:
        """Why `trial`, the first of this visit, is played again ("" if it is its first attempt):
        its last attempt was cut short, by the server's stop (settled by the next server's
        reconcile: `TrialRunner.cut`) or by the page's leaving (a reload, a closed tab)."""
        if trial.practice or trial.attempt == 1:
            return ""
        earlier = [
            a for a in self.participant.attempts if (a["session"], a["trial"]) == (trial.session, trial.trial)
        ]
        return RESTARTED if earlier and earlier[-1]["match"] in self.runner.cut else CUT

    async def run(self) -> None:
        """The participant's remaining trials, after a practice game if the study has one and they
        have not begun; a failed trial is offered again, and a problem is shown once RETRIES in a
        row failed before the participant could play them to the end: a game played to its end and
        judged failed (under overload, the server's recorder fell behind; or the page stopped
        answering) never sends its player away, it is offered again. A trial played again says why."""
        study, socket, participant, matches = self.study, self.socket, self.participant, self.runner.matches
        last, failures, why = None, 0, None  # why: the next trial is played again because ... (None: first)
        await matches.end_previous(participant.id)  # a reload's practice game still running out
        practice = study.practice(participant)
        if (
            practice is not None
            and await self.runner.play(socket, practice, self.obs, self.offer(practice, None, "")) is None
        ):
            return
        while True:
            await matches.end_previous(participant.id)  # settled first: never a trial twice
            trial = study.next_trial(participant)
            if trial is None:
                break
            if not await self.attend(trial):
                return
            why = self.replayed(trial) if why is None else why
            sidecar = await self.runner.play(socket, trial, self.obs, self.offer(trial, last, why))
            if sidecar is None:
                return
            if sidecar["status"] == "failed":
                failures, why = failures + (not sidecar["played"]), FAILED
                if failures < RETRIES:
                    continue
                socket.send(Problem(text=PROBLEM))
                await socket.close()
                return
            last, failures, why = sidecar["kills"], 0, ""
        await self.done()

    async def done(self) -> None:
        """The study is over for the participant: the end text, their code and the redirect."""
        study, participant = self.study, self.participant
        crowd = study.config.crowd
        code = crowd.code(participant.code)
        redirect = crowd.redirect(crowd.completion_url, code)
        text = study.config.end_text(bool(redirect))
        self.socket.send(Done(text=text, code=code, redirect=redirect))
        log.info("participant %s is done", participant.id)
        await self.socket.close()
