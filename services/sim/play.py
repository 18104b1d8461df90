"""Play whole games in-process: the core that the CLI, calibration, sweeps and evaluation share."""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass

from services.sim.engine import Game
from services.sim.observation import observe
from shared.game import ROLES, GameConfig, Policy


@dataclass(frozen=True)
class GameResult:
    seed: int
    frames: int
    kills: int
    kills_per_minute: float
    points: int
    counters: dict


def policy_seed(game_seed: int, role: str) -> int:
    """The seed a seat's policy is reset with in a game: in-process, in envs and on the bus alike."""
    return 2 * game_seed + 1 + ROLES.index(role)


def game_seed(policy_seed: int, role: str) -> int:
    """The game seed whose `policy_seed` this is (a switch's second partner, reset with one more,
    belongs to the same game)."""
    return (policy_seed - 1 - ROLES.index(role)) // 2


def switch_seed(game_seed: int, role: str, frame: int) -> int:
    """The seed a seat's policy is reset with when it is switched to from `frame` on."""
    return policy_seed(game_seed, role) * 1_000_003 + frame


Trace = Callable[[Game, int, int], None]


def play(
    bait: Policy, shooter: Policy, seed: int = 0, config: GameConfig | None = None, trace: Trace | None = None
) -> GameResult:
    """One full game between two policies, each reset with a seed derived from the game's.
    `trace(game, bait_action, shooter_action)` sees every frame just before it is stepped."""
    game = Game(config, seed)
    bait.reset(policy_seed(seed, "bait"))
    shooter.reset(policy_seed(seed, "shooter"))
    while not game.done:
        actions = (
            bait.act(observe(game, "bait", bait.view)),
            shooter.act(observe(game, "shooter", shooter.view)),
        )
        if trace is not None:
            trace(game, *actions)
        game.step(*actions)
    return GameResult(seed, game.frame, game.kills, game.kills_per_minute(), game.points, game.counters())


@dataclass(frozen=True)
class Summary:
    games: int
    mean: float  # kills per minute
    stderr: float

    def __str__(self) -> str:
        return f"{self.mean:.2f} ± {self.stderr:.2f} kills/min over {self.games} games"


def summarize(results: list[GameResult]) -> Summary:
    values = [r.kills_per_minute for r in results]
    stderr = statistics.stdev(values) / math.sqrt(len(values)) if len(values) > 1 else 0.0
    return Summary(len(values), statistics.fmean(values), stderr)
