"""A live sim's matches as lanes of the batched engine: every match that a clock's pass plays a
frame of is stepped in one call (batch.BatchGame.step of those lanes), and every match's
observations are computed from the arrays at once, where a match on its own `Game` cost a
Python pass per match (the pymunk step and the observations: about a quarter of a pooled
match's sim, docs/architecture.md, "Where a participant's CPU goes").

Matches of one GameConfig share an engine (a practice's and a trial's differ in length); a match
takes a free lane at its first frame and frees it when it closes, and an engine grows when it has
none free. A `Lane` reads one lane as the message builders (match.py) read a `Game`, so a frame's
messages are built by the one code either way: the values are the scalar engine's bit for bit
(batch_test.py), and a match's recording is the one its own `Game` gave (tests/test_sim_lanes.py).

Everything here runs on the clock's thread."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from services.sim.batch import BatchGame
from services.sim.engine import Event
from services.sim.observation import world_rows
from shared.game import ROLES, GameConfig


class Engine:
    """One GameConfig's lanes: the engine, the lanes free, the actions of the lanes due to step,
    what a state message reads of each lane as Python values (`rows`, read for all the lanes
    just stepped at once), and the world views of every lane (computed once a frame for all)."""

    def __init__(self, config: GameConfig) -> None:
        self.game = BatchGame(1, config)
        self.free = [0]
        self.due: list[int] = []
        self.actions = np.zeros((2, 1), np.int64)
        self.rows: dict[int, Row] = {}
        self.views: np.ndarray | None = None  # (seat, lane, 64) float64

    def take(self, seed: int) -> int:
        if not self.free:
            held = self.game.n
            self.game.grow(2 * held)
            self.free = list(range(held, 2 * held))
            self.actions = np.zeros((2, 2 * held), np.int64)
        lane = min(self.free)  # the lowest: the lanes held stay few and together
        self.free.remove(lane)
        self.game.reset([lane], [seed])
        self._read(np.array([lane]))
        return lane

    def step(self) -> None:
        lanes, self.due = np.array(self.due, np.int64), []
        self.game.step(self.actions[0], self.actions[1], lanes)
        self._read(lanes)

    def _read(self, lanes: np.ndarray) -> None:
        """The rows of `lanes` as they are now, each array read once for all of them."""
        s, self.views = self.game.state, None
        ints = np.stack([s.frame, s.vulnerable, s.lock, s.since_shell, s.kills, s.points])[
            :, lanes
        ].T.tolist()
        facing, up = s.facing[lanes].tolist(), s.fortress_alive[lanes].tolist()
        ships = np.stack([s.x, s.y, s.vx, s.vy, s.heading], axis=2)[lanes].tolist()
        alive, hashes = s.alive[lanes].tolist(), self.game.state_hashes(lanes)
        for k, i in enumerate(lanes.tolist()):
            missiles = [[*m[:4], int(m[4])] for m in s.missiles[i, : s.n_missiles[i]].tolist()]
            self.rows[i] = Row(
                *ints[k], facing[k], up[k], [Ship(*v, a) for v, a in zip(ships[k], alive[k], strict=True)],
                missiles, s.shells[i, : s.n_shells[i]].tolist(), hashes[k],
            )  # fmt: skip

    def world_views(self, lane: int) -> np.ndarray:
        """(seat, 64): the lane's world-view values, computed for every lane once a frame."""
        if self.views is None:
            self.views = np.stack([world_rows(self.game, role) for role in ROLES])
        return self.views[:, lane]


class Row(NamedTuple):
    """What a state message reads of a lane, as Python numbers (the owner of a missile an int, as
    the scalar engine's)."""

    frame: int
    vulnerable: int
    lock: int
    since_shell: int
    kills: int
    points: int
    facing: float
    fortress_alive: bool
    ships: list[Ship]
    missiles: list[list]
    shells: list[list[float]]
    hash: str


class Lanes:
    """Every match of a sim process, as lanes of one engine per GameConfig."""

    def __init__(self) -> None:
        self.engines: dict[GameConfig, Engine] = {}

    def take(self, config: GameConfig, seed: int) -> Lane:
        """A lane for a new game of `config` seeded `seed`, as `Game(config, seed)` would start."""
        engine = self.engines.get(config) or self.engines.setdefault(config, Engine(config))
        return Lane(engine, engine.take(seed))

    def step(self) -> None:
        """Play one frame of every lane `Lane.play` named since the last step: one call an engine."""
        for engine in self.engines.values():
            if engine.due:
                engine.step()


def warm() -> None:
    """Load the compiled engine and observations (numba's cache; compiled first where it is cold):
    a sim does it before its tokens say it is up, so that no match's first frame waits for it."""
    engine = Engine(GameConfig(frames=2))
    Lane(engine, 0).play((0, 0))
    engine.step()
    engine.world_views(0)


class Ship(NamedTuple):
    """A ship's fields that a state message reads, as Python numbers."""

    x: float
    y: float
    vx: float
    vy: float
    heading: float
    alive: bool


class Lane:
    """One match's game: a lane of an engine, read as match.py reads a `Game` (the same names, as
    Python numbers). `play` sets its actions for the next step; `free` gives the lane back."""

    def __init__(self, engine: Engine, lane: int) -> None:
        self.engine, self.lane = engine, lane
        self.config = engine.game.config
        self.seed = int(engine.game.seeds[lane])

    def play(self, actions: tuple[int, int]) -> None:
        """Step this lane, with these actions, at the next `Lanes.step`."""
        self.engine.actions[:, self.lane] = actions
        self.engine.due.append(self.lane)

    def free(self) -> None:
        self.engine.free.append(self.lane)

    def _row(self, name: str) -> object:
        return getattr(self.engine.rows[self.lane], name)

    frame = property(lambda self: self._row("frame"))
    facing = property(lambda self: self._row("facing"))
    fortress_alive = property(lambda self: self._row("fortress_alive"))
    vulnerable = property(lambda self: self._row("vulnerable"))
    lock = property(lambda self: self._row("lock"))
    since_shell = property(lambda self: self._row("since_shell"))
    kills = property(lambda self: self._row("kills"))
    points = property(lambda self: self._row("points"))
    ships = property(lambda self: self._row("ships"))
    missiles = property(lambda self: self._row("missiles"))
    shells = property(lambda self: self._row("shells"))

    @property
    def done(self) -> bool:
        return self.frame >= self.config.frames

    @property
    def events(self) -> list[Event]:
        return self.engine.game.events(self.lane)

    def state_hash(self) -> str:
        return self._row("hash")

    def counters(self) -> dict[str, dict]:
        return self.engine.game.counters(self.lane)

    def kills_per_minute(self) -> float:
        return self.engine.game.kills_per_minute()[self.lane].item()

    def views(self) -> np.ndarray:
        """(seat in ROLES order, 64): each seat's world-view observation values, float64."""
        return self.engine.world_views(self.lane)

    def world_views(self) -> dict[str, list[float]]:
        """Each seat's world-view observation values, as observation.world_views gives a Game's."""
        return dict(zip(ROLES, self.views().tolist(), strict=True))
