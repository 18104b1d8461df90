"""Cross-play games as jobs of the job system (kind `pairs`): teams of a bait and a shooter, each
named in the partner grammar, over seeds; a worker plays every job it is handed as the lanes of one
batch (evaluate.play_teams), so a value depends on its team and seed only."""

from __future__ import annotations

import itertools

from services.evaluation.evaluate import play_teams
from services.jobs.core import Spec, spec
from services.population.seat import seats_of

PAIRS = 128  # teams of one job (x seeds games): a batch of a few hundred lanes


def pair_jobs(label: str, teams: list[tuple[str, str]], seeds: list[int]) -> list[Spec]:
    """The games of every team over `seeds`, as jobs of at most PAIRS teams."""
    chunks = [teams[i : i + PAIRS] for i in range(0, len(teams), PAIRS)]
    return [
        spec(
            f"{label}-{i}",
            "pairs",
            {"teams": [list(t) for t in chunk], "seeds": list(seeds)},
            len(chunk) * len(seeds),
        )
        for i, chunk in enumerate(chunks)
    ]


def run_pair_jobs(args: list[dict]) -> list[list]:
    """Each job's kills/min, team by team and seed by seed; jobs of the same seeds share a batch."""
    out: list[list | None] = [None] * len(args)
    by_seeds = itertools.groupby(
        sorted(range(len(args)), key=lambda i: args[i]["seeds"]), lambda i: args[i]["seeds"]
    )
    for seeds, group in by_seeds:
        jobs = list(group)
        teams = [seats_of(t) for i in jobs for t in args[i]["teams"]]
        kills = play_teams(teams, list(seeds)).tolist()
        for i in jobs:
            out[i] = [k for row in kills[: len(args[i]["teams"])] for k in row]
            kills = kills[len(args[i]["teams"]) :]
    return out
