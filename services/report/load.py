"""Recordings for the report: each one checked, exported to Parquet and read back with pandas.

A recording is left out of the analyses, and named in the report with the reason, when it cannot be
read, has no start or no summary (a truncated log, or a match that never ended), or when the engine
does not reproduce its states. Damage after the start and before or after the summary (a torn
tail, damaged records skipped, frames lost or never recorded, duplicates) is named too, but the
recording is still used: its result is known; its states are not checked against the engine then.

The study runner (services/study) leaves a JSON sidecar beside each recording, `<match>.study.json`
(a plain `<match>.json` is read too): its `participant`, `role` (the participant's seat),
`variant`, `session`, `trial` and `attempt` are used where present (services/report/analysis.py),
and an attempt whose `status` is not `done` (a participant who dropped out) is named and left out.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from services.recorder.export import export
from services.recorder.export import paths as table_paths
from services.recorder.recording import load, replay
from shared.game import GameConfig

SIDECAR_FIELDS = ("participant", "role", "variant", "session", "trial", "attempt", "status")
SIDECARS = (".study.json", ".json")


@dataclass(frozen=True)
class Match:
    """One usable recording, as pandas frames read from its Parquet export."""

    name: str
    path: Path
    tables: dict[str, pd.DataFrame]
    meta: dict[str, str] = field(default_factory=dict)  # the sidecar's fields, where there is one

    @property
    def info(self) -> pd.Series:
        return self.tables["match"].iloc[0]

    @property
    def policies(self) -> dict[str, str]:
        return dict(self.info["policies"])

    @property
    def config(self) -> GameConfig:
        config = self.info["config"]  # a struct: lists come back as arrays
        return GameConfig.from_dict({k: v.tolist() if hasattr(v, "tolist") else v for k, v in config.items()})

    @property
    def kills_per_minute(self) -> float:
        return float(self.info["kills_per_minute"])


@dataclass(frozen=True)
class Problem:
    name: str
    path: str
    reason: str
    used: bool  # True: noted, but the recording is still in the analyses


def load_matches(
    paths: list[Path], parquet: Path, progress: Callable[[int, int], None] | None = None
) -> tuple[list[Match], list[Problem]]:
    """Check and export each recording into `parquet` (`<name>.<table>.parquet`); the usable ones, and
    every problem. `progress(done, total)` is told before each recording and at the end."""
    matches: list[Match] = []
    problems: list[Problem] = []
    names: set[str] = set()
    told = progress or (lambda done, total: None)
    for done, path in enumerate(paths):
        told(done, len(paths))
        name = _unique(path.name.removesuffix(".tsflog"), names)

        def problem(reason: str, used: bool = False, name: str = name, path: Path = path) -> None:
            problems.append(Problem(name, str(path), reason, used))

        try:
            recording = load(path)
        except (OSError, ValueError) as error:
            problem(f"unreadable: {error}")
            continue
        if recording.start is None:
            problem("no start record: the log is truncated or not a match's")
            continue
        if recording.summary is None:
            last = recording.states[-1].frame if recording.states else "none"
            problem(f"no summary: the log is truncated or the match never ended (last state {last})")
            continue
        if recording.problems():
            problem("; ".join(recording.problems()), used=True)
        elif mismatches := replay(recording):
            problem(f"{len(mismatches)} states differ from the engine's, first at frame {mismatches[0]}")
            continue
        meta = _sidecar(path)
        if meta.get("status", "done") != "done":
            problem(f"the study marked this attempt {meta['status']}")
            continue
        export(recording, parquet, name)
        tables = {t: pd.read_parquet(path) for t, path in table_paths(parquet, name).items()}
        matches.append(Match(name, path, tables, meta))
    told(len(paths), len(paths))
    return matches, problems


def _unique(name: str, taken: set[str]) -> str:
    unique, n = name, 1
    while unique in taken:
        n += 1
        unique = f"{name}-{n}"
    taken.add(unique)
    return unique


def _sidecar(path: Path) -> dict[str, str]:
    """The study metadata beside a recording, as text ({} where there is none or it is unreadable)."""
    stem = path.name.removesuffix(".tsflog")
    for suffix in SIDECARS:
        sidecar = path.with_name(stem + suffix)
        if not sidecar.exists():
            continue
        try:
            record = json.loads(sidecar.read_text())
        except (OSError, ValueError):
            return {}
        if isinstance(record, dict):
            return {k: str(record[k]) for k in SIDECAR_FIELDS if record.get(k) not in (None, "")}
    return {}
