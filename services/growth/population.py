"""Stage 1, the population: the spec's members per seat (families.py), the events runs trained to
each level first (jobs of kind `train`); `population.json` lists every member with its split side.

A recipe being trained sits in `staging/`, in no library in use, so that a training job never
changes the library hash that the other jobs are checked against; the trained levels are adopted
into `population/`, a library of its own, named in TSF_LIBRARY while its members play.
"""

from __future__ import annotations

import json
from dataclasses import asdict

from services.agent import library
from services.growth.workspace import Workspace, train_job
from services.population.families import EventsRun, Member, Spec
from shared.files import write_json
from shared.game import ROLES


def population(ws: Workspace) -> dict[str, list[tuple[Member, str]]]:
    """Every member of each seat with its split side; the events runs trained first."""
    done = ws.out / "population.json"
    if not done.exists():
        _train_events(ws)
        rows = {}
        for role in ROLES:
            members = ws.spec.members(role)
            sides = ws.spec.split_of(members)
            rows[role] = [asdict(m) | {"split": sides[m.name]} for m in members]
        write_json(done, {"population": ws.spec.text_hash, "members": rows})
    record = json.loads(done.read_text())["members"]
    return {
        role: [(Member(**{k: v for k, v in row.items() if k != "split"}), row["split"]) for row in rows]
        for role, rows in record.items()
    }


def _train_events(ws: Workspace) -> None:
    """The events runs trained in `staging/` to each level, the levels adopted into `population/`."""
    runs = [run for role in ROLES for run in ws.spec.events_runs(role)]
    library.record(ws.staging, {run.key: events_recipe(ws.spec, run) for run in runs})
    library.record(
        ws.population_dir, {k: events_recipe(ws.spec, run) for run in runs for k in run.level_keys()}
    )
    jobs = [
        train_job(
            run.key,
            ws.staging,
            {k: int(run.steps * level) for k, level in zip(run.level_keys(), run.levels, strict=True)},
            ws.runs,
        )
        for run in runs
    ]
    ws.say(f"population: training {len(runs)} events runs to {len(runs[0].levels)} levels each")
    ws.jobs("population", jobs, roots=[])
    library.adopt_members(ws.staging, ws.population_dir, [k for run in runs for k in run.level_keys()])


def events_recipe(spec: Spec, run: EventsRun) -> dict:
    """The registry fields of an events run: PPO on its random event weights."""
    seat = spec.seats[run.role]
    recipe = {
        "role": run.role,
        "family": "events",
        "description": "PPO on random event weights "
        + ", ".join(f"{k} {v:g}" for k, v in run.weights.items()),
        "algorithm": "PPO",
        "learned": list(seat.learned),
        "features": seat.features,
        "reward": "events",
        "weights": run.weights,
        "steps": run.steps,
        "seed": run.seed,
        "partners": list(seat.partners),
    }
    return recipe | ({"frame": "world"} if run.role == "shooter" else {})
