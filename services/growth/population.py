"""Stage 1, the population: the spec's members per seat (families.py), the events runs trained to
each level first (jobs of kind `train`); `population.json` lists every member with its split side.

A recipe being trained sits in `staging/`, in no library in use, so that a training job never
changes the library hash that the other jobs are checked against; the trained levels are adopted
into `population/`, a library of its own, named in TSF_LIBRARY while its members play.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from services.agent import library
from services.agent.library import NAMED
from services.growth.workspace import Workspace, is_library, train_job
from services.population.families import EventsRun, Member, Spec
from shared.files import write_json
from shared.game import ROLES

# The shipped populations' trained members (library.NAMED), adopted where a spec's events runs are
# theirs: the first version's PPO runs (population.toml, population-2.toml) and the third's TRPO runs.
SHIPPED = ("population", "population-3")


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
    trained = library.manifest(ws.population_dir) if (ws.population_dir / "manifest.json").exists() else {}
    runs = [run for run in runs if not set(run.level_keys()) <= set(trained)]
    for name in SHIPPED:  # the same recipes, trained to the same steps: the same members
        shipped = [run for run in runs if _shipped(ws, run, NAMED[name])]
        if shipped:
            keys = [k for r in shipped for k in r.level_keys()]
            library.adopt_members(NAMED[name], ws.population_dir, keys)
            ws.say(f"population: {len(shipped)} events runs as the shipped {name} trained them")
            runs = [run for run in runs if run not in shipped]
    if not runs:
        return
    jobs = [train_job(run.key, ws.staging, _levels(run), ws.runs) for run in runs]
    ws.say(f"population: training {len(runs)} events runs to {len(runs[0].levels)} levels each")
    ws.jobs("population", jobs, roots=[])
    library.adopt_members(ws.staging, ws.population_dir, [k for run in runs for k in run.level_keys()])


def _levels(run: EventsRun) -> dict[str, int]:
    """Each level's key and the steps it is trained to."""
    return {k: int(run.steps * level) for k, level in zip(run.level_keys(), run.levels, strict=True)}


def _shipped(ws: Workspace, run: EventsRun, root: Path) -> bool:
    """Whether the shipped population at `root` holds every level of `run` under the recipe this
    spec gives it, trained to the steps it asks (`tsf train KEY --steps N`, as its manifest records
    the command): a growth of a new spec over the same events runs trains nothing."""
    if not is_library(root):
        return False
    ours, theirs, made = library.registry(ws.population_dir), library.registry(root), library.manifest(root)
    return all(
        key in theirs
        and key in made
        and library.recipe_hash(theirs[key]) == library.recipe_hash(ours[key])
        and f" --steps {steps} " in f"{made[key].get('command', '')} "
        for key, steps in _levels(run).items()
    )


def events_recipe(spec: Spec, run: EventsRun) -> dict:
    """The registry fields of an events run: its algorithm on its random event weights."""
    seat = spec.seats[run.role]
    recipe = {
        "role": run.role,
        "family": "events",
        "description": f"{run.algorithm} on random event weights "
        + ", ".join(f"{k} {v:g}" for k, v in run.weights.items()),
        "algorithm": run.algorithm,
        "learned": list(seat.learned),
        "features": seat.features,
        "reward": "events",
        "weights": run.weights,
        "steps": run.steps,
        "seed": run.seed,
        "partners": list(seat.partners),
    }
    return recipe | ({"frame": "world"} if run.role == "shooter" else {})
