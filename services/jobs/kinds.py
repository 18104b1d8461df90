"""Running jobs by kind, and the plug-ins a job names: the worker's side of the contract.

A kind's runner takes the arguments of several jobs of that kind and returns each job's values (a
runner may play them together, as the table's plays cells as lanes of one batch, since a game
depends on its pair and seed only). The job system names none of its clients: each client names
its kinds and their runners (`Kinds`: the table's `table.KINDS`, the evaluation's
`evaluation.KINDS`), and whoever runs jobs is handed them (a worker process by its command,
services/commands/jobs.py). Runners are imported when first asked for, so a coordinator that only
hands out jobs never loads the engine.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from services.agent import library
from services.jobs.core import Hashes, Spec
from shared.errors import Failure, UsageError
from shared.game import GameConfig

Progress = Callable[[int, int], None]  # (values done, values in all)
Runner = Callable[[list[Spec], Progress | None], list[list]]  # (jobs, progress) -> values

Kinds = Mapping[str, str]  # a job kind -> its runner, "module:attr" (imported when first asked for)


def run(kinds: Kinds, kind: str, args: list[dict[str, Any]]) -> list[list]:
    """Each job's values, in order, by the runner `kinds` names for `kind`."""
    if kind not in kinds:
        raise Failure(f"no runner for jobs of kind {kind!r} here (this process runs {', '.join(kinds)})")
    module, attr = kinds[kind].split(":")
    return getattr(importlib.import_module(module), attr)(args)


def in_process(kinds: Kinds) -> Runner:
    """A runner that computes each job here, one at a time, by `kinds` (the reference a run on
    workers equals); its `progress` counts values (games)."""

    def run_here(todo: list[Spec], progress: Progress | None = None) -> list[list]:
        out: list[list] = []
        total, done = sum(job.size for job in todo), 0
        for job in todo:
            out += run(kinds, job.kind, [job.args])
            done += job.size
            if progress is not None:
                progress(done, total)
        return out

    return run_here


def hashes() -> Hashes:
    """The library and rules of this process."""
    return Hashes(library.manifest_hash(), GameConfig().hash())


def cannot_run(library: str, config: str, plugins: Iterable[str], ours: Hashes) -> str:
    """Why this process cannot run a job of the run's `library` and `config` hashes that needs
    `plugins` ("" when it can): the worker's fault, not the job's."""
    if (library, config) != (ours.library, ours.config):
        return (
            f"library/rules {ours.library}/{ours.config} here, {library}/{config} in the run: "
            "update this worker's checkout or image"
        )
    return import_plugins(plugins)


def failure_line(error: BaseException) -> str:
    """A failed job's error as one line: a user's mistake or a failure as it reads (it names the
    partner, seed and frame where a partner failed), anything else with its type."""
    return str(error) if isinstance(error, UsageError | Failure) else f"{type(error).__name__}: {error}"


def import_plugins(names: Iterable[str]) -> str:
    """Import every plug-in; why one cannot be ("" when all can)."""
    for name in names:
        module, _, attr = name.partition(":")
        try:
            target: Any = importlib.import_module(module)
            for part in attr.split("."):
                target = getattr(target, part)
        except Exception as error:  # noqa: BLE001 - any failure of a user's module is reported, not raised
            return f"cannot import plug-in {name}: {type(error).__name__}: {error}"[:300]
    return ""
