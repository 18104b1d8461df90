"""Stages 2 and 5, cross-play: partners of each seat with every candidate teammate of the other
seat, over the spec's seeds (`grouping`: the training members with the study's policies and the
rule grid; `held-out`: the validation and test members, with their stand-ins, with the best
responses too). The search (search.py) plays the settings it found with the held-out partners
the same way (`search-held-out`).

The games are jobs of the job system (kind `pairs`): teams of a bait and a shooter, each named in
the partner grammar, over seeds; a worker plays every job it is handed as the lanes of one batch
(evaluate.play_teams), so a value depends on its team and seed only."""

from __future__ import annotations

import itertools
import json

import numpy as np

from services.agent import library
from services.evaluation.evaluate import play_teams
from services.growth.choice import Grid
from services.growth.workspace import Workspace, is_library
from services.jobs.core import Spec, spec
from services.population.seat import seats_of
from shared.files import write_json
from shared.game import ROLES, other

PAIRS = 128  # teams of one job (x seeds games): a batch of a few hundred lanes


def crossplay(
    ws: Workspace, stage: str, partners: dict[str, list[str]], teammates: dict[str, list[str]] | None = None
) -> dict[str, Grid]:
    """Every partner of each seat with every candidate teammate of the other seat (or the
    `teammates` given for the partners of each seat), over the spec's seeds; written to STAGE.json."""
    done = ws.out / f"{stage}.json"
    if not done.exists():
        seeds = list(range(ws.spec.games))
        plan, jobs = {}, []
        for role in ROLES:
            candidates = (
                teammates[role]
                if teammates
                else candidates_of(ws, other(role), responses=stage != "grouping")
            )
            teams = [(p, c) if role == "bait" else (c, p) for p in partners[role] for c in candidates]
            mine = pair_jobs(f"{stage}-{role}", teams, seeds)
            plan[role] = (partners[role], candidates, slice(len(jobs), len(jobs) + len(mine)))
            jobs += mine
        games = sum(job.size for job in jobs)
        ws.say(f"{stage}: {games:,} games of cross-play")
        values = ws.jobs(stage, jobs, roots=[ws.population_dir, ws.responses_dir])
        record = {}
        for role, (rows, columns, theirs) in plan.items():
            kills = kills_of(values[theirs], len(rows), len(columns), len(seeds))
            record[role] = {"partners": rows, "candidates": columns, "kills": kills}
        write_json(done, record)
    record = json.loads(done.read_text())
    return {r: Grid.of(g) for r, g in record.items()}


def kills_of(values: list[list], partners: int, teammates: int, seeds: int) -> list:
    """The values of pair jobs over (partner, teammate) teams, as a cross-play file holds them:
    (partners, teammates, seeds) kills/min, rounded."""
    flat = [v for job in values for v in job]
    return np.reshape(flat, (partners, teammates, seeds)).round(4).tolist()


def candidates_of(ws: Workspace, role: str, responses: bool) -> list[str]:
    """The teammates of `role` a library may be chosen from: the study's policies, the rule
    grid's training members (so that no test partner is also a candidate), and (once trained)
    the best responses."""
    sides = ws.sides()
    chosen = [
        m.name
        for m in ws.spec.members(role)
        if m.family == "library" or (m.family == "rule" and sides[m.name] == "train")
    ]
    if not responses:
        return chosen
    trained = library.registry(ws.responses_dir) if is_library(ws.responses_dir) else {}
    return chosen + [k for k, r in trained.items() if r.role == role]


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
