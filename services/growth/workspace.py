"""A growth's output directory and what its stages share: the spec it is bound to, its libraries
(`population/`, `responses/`, `staging/`, `library/`), the engine that runs a stage's jobs, the
population's split sides, and each stage's wall time (`timing.json`).

Which library plays while a stage runs is TSF_LIBRARY's business, as everywhere: `jobs` names the
libraries a stage's games play from while its jobs run.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any

from services.growth import KINDS as GROWTH
from services.jobs import core
from services.jobs.kinds import Runner
from services.population.families import Member, Spec
from services.table.table import KINDS as SELF_PLAY
from shared.errors import UsageError
from shared.files import write_json

Engine = Callable[[str], AbstractContextManager[Runner]]  # a stage's name -> its jobs' runner
Say = Callable[[str], None]
KINDS = SELF_PLAY | GROWTH  # the job kinds a run hands out (the grown library's table too)


class Workspace:
    """One growth's output directory, its spec, its engine and where its stages say what they do."""

    def __init__(self, spec: Spec, out: Path, engine: Engine, say: Say = print, workers: int = 1) -> None:
        self.spec, self.out, self.engine, self.say, self.workers = spec, Path(out), engine, say, workers
        self.population_dir, self.responses_dir = self.out / "population", self.out / "responses"
        self.staging, self.runs, self.library_dir = (
            self.out / "staging",
            self.out / "runs",
            self.out / "library",
        )

    def bind(self) -> None:
        """The output directory belongs to one spec: another's is refused before anything runs."""
        self.out.mkdir(parents=True, exist_ok=True)
        bound = self.out / "spec.json"
        if bound.exists():
            was = json.loads(bound.read_text())["population"]
            if was != self.spec.text_hash:
                raise UsageError(
                    "--out", self.out, f"was grown from another population spec ({was}); use a new --out"
                )
        else:
            bound.write_text(json.dumps({"population": self.spec.text_hash}) + "\n")

    def timed(self, stage: str, work: Callable, *args: object) -> Any:  # noqa: ANN401 - the stage's
        """A stage's result; the wall seconds of a stage that ran (not one read back) go to
        timing.json, where a run's sessions add up."""
        started = time.monotonic()
        result = work(self, *args)
        seconds = time.monotonic() - started
        if seconds > 1.0:
            path = self.out / "timing.json"
            timing = json.loads(path.read_text()) if path.exists() else {}
            timing[stage] = round(timing.get(stage, 0.0) + seconds, 1)
            write_json(path, timing)
        return result

    def sides(self) -> dict[str, str]:
        """Every partner name's split side: a stand-in is on its member's."""
        record = json.loads((self.out / "population.json").read_text())["members"]
        sides = {row["name"]: row["split"] for rows in record.values() for row in rows}
        for name, side in list(sides.items()):
            for stand_in in self.spec.stand_ins(name):
                sides[stand_in] = side
        return sides

    def side(self, members: list[tuple[Member, str]], side: str, stand_ins: bool = True) -> list[str]:
        """The names of `members` on `side`, then (with `stand_ins`) their stand-ins."""
        names = [m.name for m, s in members if s == side]
        return names + ([s for n in names for s in self.spec.stand_ins(n)] if stand_ins else [])

    def jobs(self, stage: str, jobs: list, roots: list[Path]) -> list[list]:
        """Each job's values, run by the stage's engine with `roots` (those that are libraries yet)
        in TSF_LIBRARY."""
        with self.playing(roots), self.engine(stage) as run:
            return run(jobs)

    def playing(self, roots: list[Path]) -> AbstractContextManager[None]:
        """TSF_LIBRARY naming those of `roots` that are libraries yet, while the block runs."""
        return _library_roots([r for r in roots if is_library(r)])


def train_job(
    key: str, root: Path, levels: dict[str, int], runs: Path, warm_start: bool = False
) -> core.Spec:
    """A job that trains `key` of the library at `root` to each level (key -> steps, in order):
    training.train_levels; with `warm_start`, imitating its recipe's demonstrator first."""
    args = {"key": key, "library": str(root), "levels": levels, "runs": str(runs)}
    args |= {"warm_start": True} if warm_start else {}
    return core.spec(f"train-{key}", "train", args, 1)


def is_library(root: Path) -> bool:
    return (root / "registry.toml").exists()


@contextmanager
def _library_roots(roots: list[Path]) -> Iterator[None]:
    """TSF_LIBRARY naming `roots` (beside the shipped library) while the block runs: what the
    workers started in it and the games played in it use."""
    before = os.environ.get("TSF_LIBRARY")
    os.environ["TSF_LIBRARY"] = os.pathsep.join(str(r.resolve()) for r in roots)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("TSF_LIBRARY", None)
        else:
            os.environ["TSF_LIBRARY"] = before
