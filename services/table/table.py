"""The self-play table P: mean kills per minute of every bait-shooter pair of the library.

The pure core of sweeps: a table is split into jobs (a pair and some seeds), a job is played
in-process (`run_job`), and results are assembled into a `Table` bound to the library manifest
and the game config it was measured with, so that a stale table is refused rather than trusted.
Seeds are the job's, never the worker's, so a table is the same whoever computes it.
"""

from __future__ import annotations

import json
import math
import statistics
from dataclasses import dataclass, field
from pathlib import Path

from services.agent import library, networks
from shared.game import SEEDS, GameConfig
from shared.provenance import provenance

TABLE_VERSION = 1
DEFAULT_TABLE = library.table_path()  # with TSF_LIBRARY: the table in your library directory


class StaleTable(ValueError):
    """A table measured with another library or other rules than the ones loaded now."""


@dataclass(frozen=True)
class Job:
    bait: str
    shooter: str
    seeds: tuple[int, ...]

    @property
    def id(self) -> str:
        return f"{self.bait}-{self.shooter}-{self.seeds[0]}-{len(self.seeds)}"


CHUNK = 20  # games per job: a whole cell at the default 20 games
LANES = 640  # games a worker plays as the lanes of one batch (whole jobs): half the 9x7 table at 20


def jobs(baits: list[str], shooters: list[str], games: int, chunk: int = CHUNK) -> list[Job]:
    """Every pair's seeds 0..games-1, cut into chunks of at most `chunk` games."""
    return [
        Job(b, s, tuple(range(start, min(start + chunk, games))))
        for b in baits
        for s in shooters
        for start in range(0, games, chunk)
    ]


def run_job(job: Job, config: GameConfig | None = None) -> list[float]:
    """Kills per minute of each of the job's games (see `run_jobs`)."""
    return run_jobs([job], config)[0]


def run_jobs(todo: list[Job], config: GameConfig | None = None) -> list[list[float]]:
    """Kills per minute of each game of each job, all played as lanes of one batch: each policy
    answers once per frame for the lanes of every job it plays in (policies loaded fresh, so
    nothing carries over). Each game depends on its pair and seed only (see batch_play), so a job's
    results are the same whichever jobs share its batch."""
    from services.sim.batch_play import play_pairs  # bulk play only: the table's readers never load numba

    baits = list(dict.fromkeys(job.bait for job in todo))
    shooters = list(dict.fromkeys(job.shooter for job in todo))
    lanes = [(baits.index(job.bait), shooters.index(job.shooter), seed) for job in todo for seed in job.seeds]
    bait_of, shooter_of, seeds = (list(column) for column in zip(*lanes, strict=True))
    played = play_pairs(
        [networks.load(k, config) for k in baits],
        [networks.load(k, config) for k in shooters],
        bait_of, shooter_of, seeds, config,
    )  # fmt: skip
    out, start = [], 0
    for job in todo:
        out.append([result.kills_per_minute for result in played[start : start + len(job.seeds)]])
        start += len(job.seeds)
    return out


KINDS = {"table": f"{__name__}:run_cells"}  # the job kind a sweep hands out, for services/jobs


def run_cells(args: list[dict]) -> list[list[float]]:
    """The job system's runner for `table` jobs ({bait, shooter, seeds}): `run_jobs`, checked."""
    todo = []
    for a in args:
        seeds = tuple(a["seeds"])
        if not seeds or not all(isinstance(s, int) and s in SEEDS for s in seeds):
            raise ValueError(f"seeds must be 1 or more of {SEEDS}: {list(seeds)[:5]}")
        for role in ("bait", "shooter"):
            if a[role] not in library.keys(role):
                raise ValueError(f"{a[role]!r} is not a {role} of the library")
        todo.append(Job(a["bait"], a["shooter"], seeds))
    return run_jobs(todo)


def stderr(values: list[float]) -> float:
    """The standard error of a mean of per-game values (0 for one game)."""
    return statistics.stdev(values) / math.sqrt(len(values)) if len(values) > 1 else 0.0


@dataclass(frozen=True)
class Table:
    """P[bait][shooter] with the per-game results behind it and what it was measured with."""

    baits: tuple[str, ...]
    shooters: tuple[str, ...]
    games: int
    results: dict[str, dict[str, list[float]]]  # bait -> shooter -> kills/min per seed 0..games-1
    library: str = field(default_factory=library.manifest_hash)
    config: str = field(default_factory=lambda: GameConfig().hash())
    version: int = TABLE_VERSION

    def mean(self, bait: str, shooter: str) -> float:
        return statistics.fmean(self.results[bait][shooter])

    def stderr(self, bait: str, shooter: str) -> float:
        return stderr(self.results[bait][shooter])

    def best_shooter(self, bait: str) -> str:
        return max(self.shooters, key=lambda s: self.mean(bait, s))

    def best_bait(self, shooter: str) -> str:
        return max(self.baits, key=lambda b: self.mean(b, shooter))

    def overall_mean(self) -> float:
        return statistics.fmean(self.mean(b, s) for b in self.baits for s in self.shooters)

    def save(self, path: Path) -> None:
        record = {
            "version": self.version,
            "library": self.library,
            "config": self.config,
            "games": self.games,
            "seeds": list(range(self.games)),
            "baits": list(self.baits),
            "shooters": list(self.shooters),
            "mean": {b: {s: round(self.mean(b, s), 6) for s in self.shooters} for b in self.baits},
            "stderr": {b: {s: round(self.stderr(b, s), 6) for s in self.shooters} for b in self.baits},
            "results": self.results,
            "provenance": provenance(self.library, "self") | {"config": self.config},
        }
        path.write_text(json.dumps(record, indent=1) + "\n")

    @classmethod
    def load(cls, path: Path = DEFAULT_TABLE, check: bool = True, config: GameConfig | None = None) -> Table:
        """A saved table; with `check`, refused (StaleTable) unless it matches the library and rules."""
        if not path.exists():
            raise StaleTable(f"no table at {path}: measure it with `tsf sweep --out {path}`")
        record = json.loads(path.read_text())
        if record.get("version") != TABLE_VERSION:
            raise StaleTable(f"{path}: table format {record.get('version')}, expected {TABLE_VERSION}")
        table = cls(
            tuple(record["baits"]), tuple(record["shooters"]), record["games"], record["results"],
            record["library"], record["config"],
        )  # fmt: skip
        if check:
            now = (library.manifest_hash(), (config or GameConfig()).hash())
            if (table.library, table.config) != now:
                raise StaleTable(
                    f"{path} was measured with library {table.library} and rules {table.config}, but "
                    f"the library is now {now[0]} and the rules {now[1]}: remeasure it with "
                    f"`tsf sweep --out {path}`"
                )
        return table


def assemble(
    baits: list[str], shooters: list[str], games: int, results: dict[str, list[float]], chunk: int = 10
) -> Table:
    """A table from job results keyed by job id (every job of `jobs(...)` must be there)."""
    table: dict[str, dict[str, list[float]]] = {b: {s: [] for s in shooters} for b in baits}
    for job in jobs(baits, shooters, games, chunk):
        table[job.bait][job.shooter].extend(results[job.id])
    return Table(tuple(baits), tuple(shooters), games, table)
