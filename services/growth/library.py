"""Stage 7, the library: the selected members under keys of their own (GB1.., GS1..), a library
that plays without the study's; its self-play table P with a heatmap, the adapter's calibration,
and the partner groups the adaptive agent identifies (`groups.json`: each group's members and what
each member of ours scores with it, with their out-of-library thresholds). Built once: a run
resumed after it reads it back. The figures on the test population are summary.py's.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np

from services.agent import library
from services.growth import choice
from services.growth.choice import Grid
from services.growth.groups import competence, grouped, joined
from services.growth.workspace import Workspace, is_library
from services.population.adaptive import AdapterConfig
from services.table.plot import heatmap
from services.table.sweep import cell_spec
from services.table.table import CHUNK, Table, assemble, jobs
from shared.files import write_json
from shared.game import other

GROUPS = "groups.json"  # the partner groups the adaptive agent identifies, in the grown library
MERGED = "merged.json"  # the run's record of the groups merged because the filter confused them
MEMBERS = "members.json"  # the grown library's keys -> the names of the members they stand for
# A recipe's fields that a grown library's entry keeps, where they are set.
FIELDS = (
    "role",
    "family",
    "algorithm",
    "learned",
    "features",
    "reward",
    "weights",
    "speed_cap",
    "thrust_rule",
    "temperature",
    "steps",
    "seed",
    "partners",
    "rule",
)


def build(
    ws: Workspace, selection: dict, held_out: dict[str, Grid], groups: dict, grouping: dict[str, Grid]
) -> None:
    """The grown library with its tables, and its partner groups, each made once."""
    if not (ws.library_dir / "calibration.json").exists():
        members(ws, selection)
        tables(ws)
    if not (ws.library_dir / GROUPS).exists():
        partner_groups(ws, selection, held_out, groups, grouping)


def members(ws: Workspace, selection: dict) -> dict[str, str]:
    """The selected members under the grown library's keys, each with its recipe (and weights):
    a self-contained library (the study's library is not needed to play it)."""
    entries, manifest, names = {}, {}, {}
    study = library.registry(library.LIBRARY)
    responses = library.registry(ws.responses_dir) if is_library(ws.responses_dir) else {}
    if ws.library_dir.exists():
        shutil.rmtree(ws.library_dir)
    for ours, steps in selection.items():
        for i, name in enumerate(steps[-1]["library"]):
            key = f"{ws.spec.keys[ours]}{i + 1}"
            names[key] = name
            source = study.get(name) or responses.get(name)
            if source is None:  # a rule with its settings
                entries[key] = {
                    "role": ours,
                    "family": name.split("(")[0],
                    "description": f"the rule {name}",
                    "rule": rule_settings(name),
                }
                continue
            entries[key] = recipe_fields(source) | {"description": f"{name}: {source.description}"}
            if source.algorithm:
                entry = library.manifest(source.root)[name]
                manifest[key] = library.copy_member(source.root, entry, ws.library_dir, key) | {
                    "source": name
                }
    library.write_registry(ws.library_dir, entries)
    library.write_manifest(ws.library_dir, manifest)
    write_json(ws.library_dir / MEMBERS, names)
    return names


def tables(ws: Workspace) -> None:
    """The grown library's self-play table P and the adapter's calibration, measured with the
    grown library alone in use (what a table is bound to), and P's heatmap."""
    with ws.playing([ws.library_dir]):
        baits = [k for k in library.keys("bait") if k.startswith(ws.spec.keys["bait"])]
        shooters = [k for k in library.keys("shooter") if k.startswith(ws.spec.keys["shooter"])]
        games = 16
        todo = jobs(baits, shooters, games, CHUNK)
        values = ws.jobs("table", [cell_spec(job) for job in todo], roots=[ws.library_dir])
        results = {job.id: v for job, v in zip(todo, values, strict=True)}
        table = assemble(baits, shooters, games, results, CHUNK)
        table.save(ws.library_dir / "table.json")
        heatmap(Table.load(ws.library_dir / "table.json"), ws.out / "table.png")
    _calibrate(ws, "calibration.json", [])


def partner_groups(
    ws: Workspace, selection: dict, held_out: dict[str, Grid], groups: dict, grouping: dict[str, Grid]
) -> None:
    """groups.json: per seat of ours, the partner groups the adaptive agent identifies (their
    training and validation members) and the mean kills/min of each group with each member of
    ours (services/adapter/core.py reads it as a Payoff), then their out-of-library thresholds
    and confusion (`tsf calibrate-adapter --partners groups`). Where the spec asks the groups to be
    identified (`groups.identify`), the groups the calibrated filter confuses are merged
    (choice.merge, at the default window), written again and calibrated again; MERGED records it."""
    views = _views(ws, selection, held_out, groups, grouping)
    _write_groups(ws, views, {ours: None for ours in views})
    target = ws.spec.groups["identify"]
    if not target:
        return
    seats = json.loads((ws.library_dir / GROUPS).read_text())["seats"]
    parts, record = {}, {}
    for ours, seat in seats.items():
        confusion = _confusion(seat)
        values = np.array([g["values"] for g in seat["groups"]], float)
        weight = np.array([g["partners"] for g in seat["groups"]], float)
        parts[ours] = choice.merge(confusion, values, weight, target, ws.spec.groups["regret"])
        record[ours] = {
            "window": AdapterConfig.window,
            "groups": [[seat["groups"][j]["name"] for j in part] for part in parts[ours]],
            "identified": round(choice.identified(confusion), 4),
            "expected": round(choice.expected(confusion, values, weight), 4),
        }
    if any(len(parts[s]) < len(seats[s]["groups"]) for s in seats):
        _write_groups(ws, views, parts)
        merged = json.loads((ws.library_dir / GROUPS).read_text())["seats"]
        for ours, seat in merged.items():
            record[ours]["identified after"] = round(choice.identified(_confusion(seat)), 4)
            ws.say(f"groups of {other(ours)}s merged for our {ours}: {record[ours]['groups']}")
    write_json(ws.out / MERGED, record)


def _confusion(seat: dict) -> np.ndarray:
    """A seat's calibrated confusion (true, estimated) at the default agent's window."""
    return np.array(seat["confusion"][str(AdapterConfig.window)], float)


def merged_label(ws: Workspace, ours: str, label: np.ndarray) -> np.ndarray:
    """The groups' labels (as grouped) as the library's groups name them: where groups were merged
    for our seat `ours` (MERGED), each label is its merged group's."""
    path = ws.out / MERGED
    parts = json.loads(path.read_text())[ours]["groups"] if path.exists() else None
    if not parts:
        return label
    return joined(label, [[int(name[1:]) - 1 for name in part] for part in parts])  # G2 -> 1


def _views(
    ws: Workspace, selection: dict, held_out: dict[str, Grid], groups: dict, grouping: dict[str, Grid]
) -> dict:
    """Per seat of ours, what its groups are made from: the grouped training members and their
    groups, the competent validation partners, their members, our selected teammates."""
    sides, views = ws.sides(), {}
    for ours, steps in selection.items():
        partner_role = other(ours)
        train, label = grouped(grouping[partner_role], groups[partner_role]["groups"])
        held = held_out[partner_role]
        best = competence(held.only([p for p in held.partners if sides[p] == "validation"]))
        validation = held.only([p for p, v in best.items() if v >= ws.spec.groups["floor"]])
        played = [p for p in validation.partners if not p.startswith("human(")]
        views[ours] = (train, label, validation, played, steps[-1]["library"])
    return views


def _write_groups(ws: Workspace, views: dict, parts: dict[str, list[list[int]] | None]) -> None:
    """groups.json from `views`, each seat's groups joined as `parts` says (None: as grouped), then
    calibrated."""
    names, seats = json.loads((ws.library_dir / MEMBERS).read_text()), {}
    for ours, (train, label, validation, played, teammates) in views.items():
        if parts[ours] is not None:
            label = joined(label, parts[ours])
        seats[ours] = {
            "teammates": [key_of(names, t, ws.spec.keys[ours]) for t in teammates],
            "names": teammates,
            "groups": choice.partner_groups(train, label, validation, played, teammates),
        }
    write_json(ws.library_dir / GROUPS, {"version": 1, "population": ws.spec.text_hash, "seats": seats})
    _calibrate(ws, GROUPS, ["--partners", "groups"])


def _calibrate(ws: Workspace, name: str, options: list[str]) -> None:
    """`tsf calibrate-adapter OPTIONS --out library/NAME` with the grown library alone in use (its
    members, its groups), in an interpreter of its own: this one's table and payoff were read
    before the grown library was in use. Its journal goes once it is done: not the library's."""
    path = ws.library_dir / name
    command = [sys.executable, "-m", "services.commands", "calibrate-adapter", *options]
    command += ["--workers", str(ws.workers), "--out", str(path)]
    env = os.environ | {"TSF_LIBRARY": str(ws.library_dir.resolve())}
    subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL)
    path.with_name(f"{name}.journal").unlink(missing_ok=True)


def key_of(names: dict[str, str], name: str, prefix: str) -> str:
    """The grown library's key of a selected member of the seat whose keys begin with `prefix`
    (members.json: key -> name)."""
    return next(k for k, n in names.items() if n == name and k.startswith(prefix))


def recipe_fields(recipe: library.Recipe) -> dict:
    """A recipe's registry fields that are set (its view as `frame` where it is not the role's)."""
    fields = {}
    for name in FIELDS:
        value = getattr(recipe, name)
        if value not in (None, "", 0, 0.0, (), {}):
            fields[name] = list(value) if isinstance(value, tuple) else value
    if recipe.view != "role":
        fields["frame"] = recipe.view
    return fields


def rule_settings(name: str) -> dict[str, float]:
    """A rule's settings from its name in the partner grammar: `circle(radius=150)` -> radius 150."""
    inside = name[name.index("(") + 1 : -1]
    return {k: float(v) for k, v in (part.split("=") for part in inside.split(","))}
