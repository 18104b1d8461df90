"""The sim service's pure core: which action each seat plays, and the messages a frame produces."""

from __future__ import annotations

import time

from services.sim.engine import Game
from services.sim.observation import world_views
from shared.game import NOOP, ROLES
from shared.messages import Action, GameEvent, Start, State, Summary


class Seats:
    """The latest action of each seat. A seat with no fresh action keeps its last one; a seat whose
    player is gone (by liveliness) plays no-op until it returns."""

    def __init__(self) -> None:
        self.latest = dict.fromkeys(ROLES, NOOP)
        self.frame = dict.fromkeys(ROLES, -1)  # the state frame the latest action answered
        self.players = dict.fromkeys(ROLES, 0)  # live services holding each seat
        self.failures = dict.fromkeys(ROLES, 0)  # frames each seat's policy failed on (its count)
        self.failed: list[Action] = []  # actions that report a new failure, for the recording

    def offer(self, action: Action) -> bool:
        """Take an action unless an answer to a later frame is already in; returns whether taken."""
        if action.failure and action.failures > self.failures[action.role]:
            self.failures[action.role] = action.failures
            self.failed.append(action)
        if action.frame < self.frame[action.role]:
            return False
        self.latest[action.role] = action.action
        self.frame[action.role] = action.frame
        return True

    def failure_events(self, match: str, sender: str) -> list[GameEvent]:
        """The failures reported since the last call, as `policy_failure` events (count: why)."""
        failed, self.failed = self.failed, []
        return [
            GameEvent(
                match=match,
                frame=a.frame,
                sender=sender,
                kind="policy_failure",
                role=a.role,
                detail=f"{a.failures}: {a.failure}"[:200],
            )  # fmt: skip
            for a in failed
        ]

    def arrive(self, role: str) -> None:
        self.players[role] += 1

    def leave(self, role: str) -> None:
        self.players[role] = max(0, self.players[role] - 1)
        if not self.players[role]:
            self.latest[role] = NOOP

    def present(self, role: str) -> bool:
        return self.players[role] > 0

    def answered(self, frame: int) -> bool:
        """Whether every present seat has answered the state of `frame` (lockstep's condition)."""
        return all(self.frame[r] >= frame or not self.present(r) for r in ROLES)

    def actions(self) -> tuple[int, int]:
        return tuple(self.latest[r] if self.present(r) else NOOP for r in ROLES)  # type: ignore[return-value]


def start_message(game: Game, match: str, sender: str, mode: str, policies: dict[str, str]) -> Start:
    return Start(
        match=match,
        frame=game.frame,
        sender=sender,
        seed=game.seed,
        mode=mode,
        config=game.config.to_dict(),
        policies=policies,
    )


def state_message(game: Game, match: str, sender: str, applied: tuple[int, int]) -> State:
    return State(
        match=match,
        frame=game.frame,
        sender=sender,
        obs=world_views(game),
        ships=[[s.x, s.y, s.vx, s.vy, s.heading, float(s.alive)] for s in game.ships],
        fortress=[game.facing, float(game.fortress_alive), game.vulnerable, game.lock, game.since_shell],
        missiles=[list(m) for m in game.missiles],
        shells=[list(s) for s in game.shells],
        kills=game.kills,
        points=game.points,
        frames=game.config.frames,
        hash=game.state_hash(),
        applied=list(applied),
        sent_ns=time.time_ns(),
    )


def event_messages(game: Game, match: str, sender: str) -> list[GameEvent]:
    return [
        GameEvent(match=match, frame=e.frame, sender=sender, kind=e.kind, role=e.role, detail=e.detail)
        for e in game.events
    ]


def summary_message(
    game: Game,
    match: str,
    sender: str,
    drops: dict[str, int],
    timing: dict[str, float],
    failures: dict[str, int] | None = None,
) -> Summary:
    return Summary(
        match=match,
        frame=game.frame,
        sender=sender,
        kills=game.kills,
        kills_per_minute=game.kills_per_minute(),
        points=game.points,
        counters=game.counters(),
        drops=dict(drops),
        timing=timing,
        failures={role: n for role, n in (failures or {}).items() if n},
    )
