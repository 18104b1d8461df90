"""The stand-ins' calibration: how human-like partners of each skill score, in pairs and with
library teammates, against the study's human pairs (about 2.6 kills/min; docs/humans.md).

Three groups of teams per skill, each bait policy paired as the shipped table pairs it:
- **pairs**: `human(Bk)` with `human(S)`, S the table's best shooter for Bk, both of that skill;
- **bait stand-in**: `human(Bk)` with that library shooter S itself;
- **shooter stand-in**: `human(Sj)` with the table's best library bait for Sj.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.adapter.evaluate import play_teams
from services.adapter.human_like import SKILLS
from services.agent import library
from services.table.table import Table
from shared.game import GameConfig

GROUPS = ("pairs", "bait stand-in", "shooter stand-in")
STUDY_PAIRS = 2.6  # kills/min: the original study's human-human teams


@dataclass(frozen=True)
class Row:
    """One group at one skill: mean kills/min over its teams and seeds, its standard error."""

    skill: str
    group: str
    mean: float
    stderr: float
    games: int


def teams(skill: str, table: Table) -> dict[str, list[tuple[str, str]]]:
    """The (bait, shooter) partner names of every group at `skill` (a SKILLS name or a number)."""
    person = "" if skill == "typical" else f",skill={skill}"
    baits, shooters = library.keys("bait"), library.keys("shooter")
    best = {b: table.best_shooter(b) for b in baits}
    return {
        "pairs": [(f"human({b}{person})", f"human({best[b]}{person})") for b in baits],
        "bait stand-in": [(f"human({b}{person})", best[b]) for b in baits],
        "shooter stand-in": [(table.best_bait(s), f"human({s}{person})") for s in shooters],
    }


def calibration(
    skills: tuple[str, ...] = tuple(SKILLS), seeds: int = 12, config: GameConfig | None = None
) -> list[Row]:
    """Every group at every skill, over game seeds 0..seeds-1 (seeds // 3 people, three trials
    each), all games in one batch."""
    table = Table.load()
    plan = [
        (skill, group, team) for skill in skills for group, ts in teams(skill, table).items() for team in ts
    ]
    kills = play_teams([team for *_, team in plan], list(range(seeds)), config)
    rows = []
    for skill in skills:
        for group in GROUPS:
            scores = np.concatenate(
                [k for (s, g, _), k in zip(plan, kills, strict=True) if (s, g) == (skill, group)]
            )
            rows.append(
                Row(
                    skill,
                    group,
                    float(scores.mean()),
                    float(scores.std(ddof=1) / np.sqrt(len(scores))),
                    len(scores),
                )
            )
    return rows
