"""Recordings of stand-in people, made in-process: what proxies are measured on without real people.

A stand-in person is a partner of the partner grammar (services/population/partners.py), typically a
human-like hand on a library policy (`human(B5)`); the agent is a policy key. Each trial is played
in lockstep on the engine and written as the recorder writes a match (the same log, start, states,
actions, events and summary messages; the start names the person's seat "human" as the launcher
does, a person's actions name no policy), with the study runner's sidecar beside it (participant,
role, status). Recording through the gateway and the headless stand-in (services/study/standin.py)
plays in real time, a minute a trial; this is the same data without the wait (docs/proxies.md says
why it was used).

Trial seeds: participant p's trial t is game seed `base + 3 p + t` for t < 3, so a human-like hand's
person (seed // SESSION_TRIALS, human_like.py) is the same over a participant's three trials.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from services.agent.player import Player
from services.population.partners import make_partner
from services.recorder.log import LogWriter
from services.sim.engine import Game
from services.sim.match import event_messages, start_message, state_message, summary_message
from shared import keys
from shared.game import HUMAN, ROLES, GameConfig, other


def trial_seed(base: int, participant: int, trial: int) -> int:
    """The game seed of a participant's trial (module docstring)."""
    return base + 3 * participant + trial


def record_trial(
    path: Path,
    person: str,
    role: str,
    agent: str,
    seed: int,
    participant: str,
    config: GameConfig | None = None,
    status: str = "done",
) -> Path:
    """Play one trial of `person` (a partner name) in `role`'s seat with `agent` in the other and
    write its recording at `path` (replacing one there) and the study sidecar beside it. Returns
    the path."""
    match = path.name.removesuffix(".tsflog")
    game = Game(config or GameConfig(), seed)
    players = {
        role: Player(role, person, seed, load=make_partner),
        other(role): Player(other(role), agent, seed),
    }
    applied = (0, 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)  # the log appends to what it finds
    with LogWriter(path) as log:
        announced = {role: HUMAN, other(role): agent}
        log.write(keys.start(match), start_message(game, match, "sim", "lockstep", announced).encode())
        while True:
            state = state_message(game, match, "sim", applied)
            log.write(keys.state(match), state.encode())
            for event in event_messages(game, match, "sim"):
                log.write(keys.event(match), event.encode())
            if game.done:
                break
            answers = [players[r].act(state, f"agent/{r}") for r in ROLES]
            answers = [replace(a, policy="") if a.role == role else a for a in answers]  # a person's
            for answer in answers:
                log.write(keys.action(match, answer.role), answer.encode())
            applied = tuple(a.action for a in answers)
            game.step(*applied)
        log.write(keys.summary(match), summary_message(game, match, "sim", {}, {}).encode())
    sidecar = {"participant": participant, "role": role, "agent": agent, "seed": seed, "status": status}
    path.with_name(f"{match}.study.json").write_text(json.dumps(sidecar, indent=1) + "\n")
    return path
