"""A study's people as an evaluation population: one proxy per participant (`tsf eval --partners-from`).

Each participant of the partners' seat gets a proxy of their own, trained on their recordings with
one or more of their trials held out (a split by recording: one person cannot be split by person),
into OUT/<participant>; a proxy already there whose recordings are the same files (by hash) is
loaded instead of retrained. Recordings without a study sidecar, participants of the other seat
and attempts not marked done are left out and named.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from services.agent.library import file_hash
from services.population.human_like import STAND_INS
from services.population.partners import fitted_people
from services.population.seat import HUMANS
from services.proxy import trainer
from services.proxy.data import study_record
from shared.errors import UsageError

if TYPE_CHECKING:
    from services.proxy.train import Settings

PER_PERSON_HELD_OUT = 0.2  # the share of a participant's recordings held out (at least one)


def people(directory: Path, role: str) -> tuple[dict[str, list[Path]], list[str]]:
    """The recordings of each participant of `role` in a study's directory, and what was left out."""
    paths = sorted(Path(directory).glob("*.tsflog"))
    if not paths:
        raise UsageError("--partners-from", directory, "holds no recordings (*.tsflog)")
    found: dict[str, list[Path]] = {}
    excluded = []
    for path in paths:
        record = study_record(path)
        if not record.get("participant"):
            excluded.append(f"{path}: no study sidecar naming its participant")
        elif record.get("status", "done") != "done":
            excluded.append(f"{path}: attempt marked {record['status']} by the study")
        elif record.get("role") != role:
            excluded.append(f"{path}: participant {record['participant']} played the {record.get('role')}")
        else:
            found.setdefault(str(record["participant"]), []).append(path)
    if not found:
        raise UsageError("--partners-from", directory, f"has no participant of the {role} seat")
    return found, excluded


def _current(directory: Path, paths: list[Path]) -> bool:
    """Whether the proxy in `directory` was trained on exactly these recordings."""
    try:
        record = json.loads((directory / "manifest.json").read_text())
    except (OSError, ValueError):
        return False
    return sorted(r["sha256"] for r in record.get("recordings", [])) == sorted(map(file_hash, paths))


def study_partners(
    directory: Path, role: str, out: Path, settings: Settings | None = None
) -> tuple[dict[str, str], list[str]]:
    """Partner names (proxy:DIR) by participant, training the proxies that are not there yet, and
    what was left out. Needs the `train` extra when something is to be trained."""
    found, excluded = people(directory, role)
    partners = {}
    for person, paths in sorted(found.items()):
        target = Path(out) / person
        if not _current(target, paths):
            trainer().train(paths, role, target, settings, PER_PERSON_HELD_OUT, by="recording")
        partners[person] = f"proxy:{target}"
    return partners, excluded


def partners_from(directory: Path, role: str, out: Path) -> tuple[dict[str, str], list[str]]:
    """The partners of `role`'s seat by participant, from a directory of `tsf humans fit` (each
    participant's fitted stand-in, humans:DIR@NAME) or a study's recordings (one proxy each, trained
    into `out` if need be, `study_partners`); and a line for each participant left out."""
    if (directory / STAND_INS).is_file():
        return {name: f"{HUMANS}{directory}@{name}" for name in fitted_people(directory)[1]}, []
    return study_partners(directory, role, out)
