"""`tsf library grow`: a library grown for coverage, from a partner population to a named library.

The stages, each written to the output directory when it is done, so that a run killed at any
point resumes where it stopped (a stage's jobs from the engine's journal, a training from its
checkpoint):

1. population  the spec's members per seat (families.py); the events runs trained to each level
               (jobs of kind `train`); `population.json` lists every member with its split side.
2. grouping    cross-play of the training members with the candidate teammates of the other seat
               (the study's policies and the rule grid), jobs of kind `pairs`.
3. groups      the training members grouped by what works with them (choice.groups).
4. responses   one best response per group, trained with PPO against the group's members and
               their stand-ins (the spec's `response` recipe).
5. held-out    cross-play of the validation and test members, with their stand-ins, with every
               candidate: the study's policies, the rules and the responses.
6. selection   per seat, the greedy coverage selection on the validation population (choice.select).
7. library     the grown library: the selected members under keys of their own (GB1.., GS1..), its
               self-play table P, the adapter's calibration, the partner groups the adaptive agent
               identifies (`groups.json`: each group's members and what each member of ours scores
               with it), the members against the partner groups with standard errors, a heatmap,
               and the test population's figures (`summary.md`).

Which library plays while a stage runs is TSF_LIBRARY's business, as everywhere: the population and
the responses are libraries of their own (`population/`, `responses/`), named in TSF_LIBRARY while
their members play; a recipe being trained sits in `staging/`, in no library in use, so that a
training job never changes the library hash that the other jobs are checked against.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from services.agent import library
from services.growth import KINDS as GROWTH
from services.growth import choice
from services.growth.choice import Grid
from services.growth.crossplay import pair_jobs
from services.jobs import core
from services.jobs.kinds import Runner
from services.population.families import Member, Spec
from services.table.plot import heatmap
from services.table.sweep import cell_spec
from services.table.table import CHUNK, Table, assemble, jobs
from services.table.table import KINDS as SELF_PLAY
from shared.errors import UsageError
from shared.game import ROLES, other

Engine = Callable[[str], AbstractContextManager[Runner]]  # a stage's name -> its jobs' runner
Say = Callable[[str], None]
PREFIX = {"bait": "GB", "shooter": "GS"}  # the grown library's keys
GROUPS = "groups.json"  # the partner groups the adaptive agent identifies, in the grown library
RESPONSE = {"bait": "RB", "shooter": "RS"}  # a best response's key while it is a candidate
KINDS = SELF_PLAY | GROWTH  # the job kinds a run hands out (the grown library's table too)


def train_job(key: str, root: Path, levels: dict[str, int], runs: Path) -> core.Spec:
    """A job that trains `key` of the library at `root` to each level (key -> steps, in order):
    training.train_levels."""
    args = {"key": key, "library": str(root), "levels": levels, "runs": str(runs)}
    return core.spec(f"train-{key}", "train", args, 1)


class Grow:
    """One run of the pipeline over an output directory (see the module docstring)."""

    def __init__(self, spec: Spec, out: Path, engine: Engine, say: Say = print, workers: int = 1) -> None:
        self.spec, self.out, self.engine, self.say, self.workers = spec, Path(out), engine, say, workers
        self.population_dir, self.responses_dir = self.out / "population", self.out / "responses"
        self.staging, self.runs, self.library_dir = (
            self.out / "staging",
            self.out / "runs",
            self.out / "library",
        )

    def run(self) -> dict:
        self._bind()
        members = self._timed("population", self.population)
        train = {r: self._side(members[r], "train", stand_ins=False) for r in ROLES}
        grouping = self._timed("grouping", self.crossplay, "grouping", train)
        groups = self._timed("groups", self.groups, grouping)
        self._timed("responses", self.responses, groups)
        held = {r: self._side(members[r], "validation") + self._side(members[r], "test") for r in ROLES}
        held_out = self._timed("held-out", self.crossplay, "held-out", held)
        selection = self._timed("selection", self.selection, held_out)
        return self._timed("library", self.library, selection, held_out, groups, grouping)

    def _timed(self, stage: str, work: Callable, *args: object) -> Any:  # noqa: ANN401 - the stage's
        """A stage's result; the wall seconds of a stage that ran (not one read back) go to
        timing.json, where a run's sessions add up."""
        started = time.monotonic()
        result = work(*args)
        seconds = time.monotonic() - started
        if seconds > 1.0:
            path = self.out / "timing.json"
            timing = json.loads(path.read_text()) if path.exists() else {}
            timing[stage] = round(timing.get(stage, 0.0) + seconds, 1)
            _write(path, timing)
        return result

    # --- the stages ----------------------------------------------------------------------------

    def _bind(self) -> None:
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

    def population(self) -> dict[str, list[tuple[Member, str]]]:
        """Every member of each seat with its split side; the events runs trained first."""
        done = self.out / "population.json"
        if not done.exists():
            runs = [run for role in ROLES for run in self.spec.events_runs(role)]
            self._registry(self.staging, {run.key: self._events_recipe(run) for run in runs})
            self._registry(
                self.population_dir,
                {k: self._events_recipe(run) for run in runs for k in run.level_keys()},
            )
            jobs = [
                train_job(
                    run.key,
                    self.staging,
                    {
                        k: int(run.steps * level)
                        for k, level in zip(run.level_keys(), run.levels, strict=True)
                    },
                    self.runs,
                )
                for run in runs
            ]
            self.say(f"population: training {len(runs)} events runs to {len(runs[0].levels)} levels each")
            self._jobs("population", jobs, roots=[])
            self._adopt(self.staging, self.population_dir, [k for run in runs for k in run.level_keys()])
            rows = {}
            for role in ROLES:
                members = self.spec.members(role)
                sides = self.spec.split_of(members)
                rows[role] = [asdict(m) | {"split": sides[m.name]} for m in members]
            _write(done, {"population": self.spec.text_hash, "members": rows})
        record = json.loads(done.read_text())["members"]
        return {
            role: [(Member(**{k: v for k, v in row.items() if k != "split"}), row["split"]) for row in rows]
            for role, rows in record.items()
        }

    def crossplay(self, stage: str, partners: dict[str, list[str]]) -> dict[str, Grid]:
        """Every partner of each seat with every candidate teammate of the other seat, over the
        spec's seeds; written to STAGE.json."""
        done = self.out / f"{stage}.json"
        if not done.exists():
            seeds = list(range(self.spec.games))
            plan, jobs = {}, []
            for role in ROLES:
                candidates = self.candidates(other(role), responses=stage != "grouping")
                teams = [(p, c) if role == "bait" else (c, p) for p in partners[role] for c in candidates]
                mine = pair_jobs(f"{stage}-{role}", teams, seeds)
                plan[role] = (partners[role], candidates, slice(len(jobs), len(jobs) + len(mine)))
                jobs += mine
            games = sum(job.size for job in jobs)
            self.say(f"{stage}: {games:,} games of cross-play")
            values = self._jobs(stage, jobs, roots=[self.population_dir, self.responses_dir])
            record = {}
            for role, (rows, columns, theirs) in plan.items():
                flat = [v for job in values[theirs] for v in job]
                record[role] = {
                    "partners": rows,
                    "candidates": columns,
                    "kills": np.reshape(flat, (len(rows), len(columns), len(seeds))).round(4).tolist(),
                }
            _write(done, record)
        record = json.loads(done.read_text())
        return {r: Grid.of(g) for r, g in record.items()}

    def groups(self, grouping: dict[str, Grid]) -> dict[str, dict]:
        """Each seat's training members grouped by what works with them (choice.groups)."""
        done = self.out / "groups.json"
        if not done.exists():
            record = {}
            for role, grid in grouping.items():
                label, tried = choice.groups(
                    grid, int(self.spec.groups["most"]), self.spec.groups["regret"], self.spec.seed
                )
                members = [
                    [p for p, g in zip(grid.partners, label, strict=True) if g == j]
                    for j in range(label.max() + 1)
                ]
                record[role] = {"groups": members, "tried": tried}
                self.say(
                    f"groups of {role}s: {len(members)} ({', '.join(str(len(m)) for m in members)} members)"
                )
            _write(done, record)
        return json.loads(done.read_text())

    def responses(self, groups: dict[str, dict]) -> None:
        """A best response of the other seat for every group, trained into `responses/`."""
        recipes = {}
        for role, record in groups.items():
            ours = other(role)
            for j, members in enumerate(record["groups"]):
                recipe = dict(self.spec.seats[ours].response)
                recipe |= {
                    "role": ours,
                    "family": "response",
                    "description": f"PPO best response to {role} group {j + 1} ({len(members)} members), "
                    "with their stand-ins",
                    "algorithm": "PPO",
                    "seed": self.spec.seed + 1000 + 10 * ROLES.index(ours) + j,
                    "partners": self.response_partners(members),
                }
                if ours == "shooter":
                    recipe["frame"] = "world"
                recipes[f"{RESPONSE[ours]}{j + 1}"] = recipe
        trained = library.manifest(self.responses_dir) if _is_library(self.responses_dir) else {}
        todo = [k for k in recipes if k not in trained]
        if not todo:
            return
        self._registry(self.staging, recipes)
        self._registry(self.responses_dir, recipes)
        jobs = [train_job(k, self.staging, {k: int(recipes[k]["steps"])}, self.runs) for k in todo]
        self.say(f"responses: training {len(jobs)} best responses")
        self._jobs("responses", jobs, roots=[self.population_dir])
        self._adopt(self.staging, self.responses_dir, list(recipes))

    def response_partners(self, members: list[str]) -> list[str]:
        """What a best response to a group trains with: its members, and a stand-in of each of the
        first few (one per skill level, in turn)."""
        skills = self.spec.skills
        stand_ins = [self.spec.stand_ins(m)[i % len(skills)] for i, m in enumerate(members[: len(skills)])]
        return [*members, *stand_ins]

    def selection(self, held_out: dict[str, Grid]) -> dict[str, list[dict]]:
        """Per seat of ours, the greedy selection's steps on the validation population."""
        done = self.out / "selection.json"
        if not done.exists():
            sides = self._sides()
            record = {}
            for role, grid in held_out.items():
                grid = _rows(grid, [p for p in grid.partners if sides[p] == "validation"])
                steps = choice.select(grid, int(self.spec.selection["most"]), self.spec.selection["gain"])
                record[other(role)] = steps
                last = steps[-1]
                size, room = len(last["library"]), last["headroom"]
                self.say(f"selection, {other(role)} seat: {size} members, headroom {room:+.1%} on validation")
            _write(done, record)
        return json.loads(done.read_text())

    def library(
        self, selection: dict, held_out: dict[str, Grid], groups: dict, grouping: dict[str, Grid]
    ) -> dict:
        """The grown library with its tables (built once), and the figures on the test population
        (computed from the files each time: summary.json and summary.md)."""
        if not (self.library_dir / "calibration.json").exists():
            self._build_library(selection)
            self._tables()
        if not (self.library_dir / GROUPS).exists():
            self._partner_groups(selection, held_out, groups, grouping)
        names = json.loads((self.library_dir / "members.json").read_text())
        sides = self._sides()
        summary: dict = {"population": self.spec.text_hash, "members": names, "seats": {}}
        for ours, steps in selection.items():
            grid = held_out[other(ours)]
            chosen = steps[-1]["library"]
            study = [c for c in grid.candidates if c in self.spec.seats[ours].library]
            test = [p for p in grid.partners if sides[p] == "test"]
            people = [p for p in test if p.startswith("human(")]
            members = [p for p in test if p not in people]
            figures = {}
            for label, rows in (("members", members), ("stand-ins", people), ("both", test)):
                figures[label] = figures_on(_rows(grid, rows), chosen, study)
            label = _labels(grouping[other(ours)], groups[other(ours)]["groups"])
            assigned = choice.place(grid, grouping[other(ours)], label)
            summary["seats"][ours] = {
                "curve": steps,
                "test": figures,
                "groups": self._group_table(chosen, grid, assigned, int(label.max()) + 1),
                "partners": {p: f"G{g + 1}" for p, g in zip(grid.partners, assigned.tolist(), strict=True)},
            }
        _write(self.out / "summary.json", summary)
        (self.out / "summary.md").write_text(markdown(summary))
        return summary

    # --- the library's parts -------------------------------------------------------------------

    def candidates(self, role: str, responses: bool) -> list[str]:
        """The teammates of `role` a library may be chosen from: the study's policies, the rule
        grid's training members (so that no test partner is also a candidate), and (once trained)
        the best responses."""
        sides = self._sides()
        chosen = [
            m.name
            for m in self.spec.members(role)
            if m.family == "library" or (m.family == "rule" and sides[m.name] == "train")
        ]
        if not responses:
            return chosen
        trained = library.registry(self.responses_dir) if _is_library(self.responses_dir) else {}
        return chosen + [k for k, r in trained.items() if r.role == role]

    def _build_library(self, selection: dict) -> dict[str, str]:
        """The selected members under the grown library's keys, each with its recipe (and weights):
        a self-contained library (the study's library is not needed to play it)."""
        entries, files, names = {}, {}, {}
        study = library.registry(library.LIBRARY)
        responses = library.registry(self.responses_dir) if _is_library(self.responses_dir) else {}
        for ours, steps in selection.items():
            for i, name in enumerate(steps[-1]["library"]):
                key = f"{PREFIX[ours]}{i + 1}"
                names[key] = name
                if name in study or name in responses:
                    source = study.get(name) or responses[name]
                    entries[key] = _recipe_fields(source) | {"description": f"{name}: {source.description}"}
                    if source.algorithm:
                        files[key] = (source.root, name)
                else:  # a rule with its settings
                    spec = _rule_settings(name)
                    entries[key] = {
                        "role": ours,
                        "family": name.split("(")[0],
                        "description": f"the rule {name}",
                        "rule": spec,
                    }
        if self.library_dir.exists():
            shutil.rmtree(self.library_dir)
        self._registry(self.library_dir, entries)
        manifest = {}
        for key, (root, name) in files.items():
            entry = _copied(library.manifest(root)[name], root, self.library_dir, key)
            manifest[key] = entry | {"source": name}
        _write(self.library_dir / "manifest.json", manifest)
        _write(self.library_dir / "members.json", names)
        return names

    def _tables(self) -> None:
        """The grown library's self-play table P and the adapter's calibration, measured with the
        grown library alone in use (what a table is bound to), and P's heatmap."""
        with self._roots([self.library_dir]):
            baits, shooters = library.keys("bait"), library.keys("shooter")
            baits, shooters = (
                [k for k in baits if k.startswith(PREFIX["bait"])],
                [k for k in shooters if k.startswith(PREFIX["shooter"])],
            )
            games = 16
            todo = jobs(baits, shooters, games, CHUNK)
            values = self._jobs("table", [cell_spec(job) for job in todo], roots=[self.library_dir])
            results = {job.id: v for job, v in zip(todo, values, strict=True)}
            table = assemble(baits, shooters, games, results, CHUNK)
            table.save(self.library_dir / "table.json")
            heatmap(Table.load(self.library_dir / "table.json"), self.out / "table.png")
        # The adapter's calibration, by the command that makes it, in an interpreter of its own:
        # this one's table and payoff were read before the grown library was in use.
        command = [
            sys.executable,
            "-m",
            "services.commands",
            "calibrate-adapter",
            "--workers",
            str(self.workers),
        ]
        command += ["--out", str(self.library_dir / "calibration.json")]
        env = os.environ | {"TSF_LIBRARY": str(self.library_dir.resolve())}
        subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL)
        (self.library_dir / "calibration.json.journal").unlink(missing_ok=True)  # done: not the library's

    def _partner_groups(
        self, selection: dict, held_out: dict[str, Grid], groups: dict, grouping: dict[str, Grid]
    ) -> None:
        """groups.json: per seat of ours, the partner groups the adaptive agent identifies (their
        training and validation members) and the mean kills/min of each group with each member of
        ours (services/adapter/core.py reads it as a Payoff), then their out-of-library thresholds
        (`tsf calibrate-adapter --partners groups`)."""
        sides, names = self._sides(), json.loads((self.library_dir / "members.json").read_text())
        seats = {}
        for ours, steps in selection.items():
            partner_role = other(ours)
            train = grouping[partner_role]
            label = _labels(train, groups[partner_role]["groups"])
            validation = _rows(
                held_out[partner_role],
                [p for p in held_out[partner_role].partners if sides[p] == "validation"],
            )
            members = [p for p in validation.partners if not p.startswith("human(")]
            teammates = steps[-1]["library"]
            seats[ours] = {
                "teammates": [_key_of(names, t, ours) for t in teammates],
                "names": teammates,
                "groups": choice.partner_groups(train, label, validation, members, teammates),
            }
        _write(self.library_dir / GROUPS, {"version": 1, "population": self.spec.text_hash, "seats": seats})
        command = [sys.executable, "-m", "services.commands", "calibrate-adapter", "--partners", "groups"]
        command += ["--workers", str(self.workers), "--out", str(self.library_dir / GROUPS)]
        env = os.environ | {"TSF_LIBRARY": str(self.library_dir.resolve())}  # its groups, its members
        subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL)
        (self.library_dir / f"{GROUPS}.journal").unlink(missing_ok=True)

    def _group_table(self, chosen: list[str], grid: Grid, assigned: np.ndarray, groups: int) -> list[dict]:
        """Each member's kills/min (± s.e. over the group's partners) with each partner group."""
        out = []
        for name in chosen:
            column = grid.columns([name])[:, 0].mean(axis=1)
            row = {"member": name}
            for j in range(groups):
                values = column[assigned == j]
                row[f"group {j + 1}"] = round(float(values.mean()), 3) if len(values) else None
                row[f"group {j + 1} se"] = (
                    round(float(values.std(ddof=1) / np.sqrt(len(values))), 3) if len(values) > 1 else None
                )
            out.append(row)
        return out

    # --- helpers -------------------------------------------------------------------------------

    def _events_recipe(self, run) -> dict:  # noqa: ANN001 - families.EventsRun
        seat = self.spec.seats[run.role]
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

    def _registry(self, root: Path, recipes: dict[str, dict]) -> None:
        """Add the recipes `root`'s registry lacks (a directory made if need be)."""
        root.mkdir(parents=True, exist_ok=True)
        path = root / "registry.toml"
        have = library.registry(root) if path.exists() else {}
        with open(path, "a") as f:
            for key, recipe in recipes.items():
                if key not in have:
                    f.write(_toml(key, recipe))
        library._registry.cache_clear()

    def _adopt(self, source: Path, target: Path, keys: list[str]) -> None:
        """Copy trained keys' weights and manifest entries from `source` into the library `target`."""
        entries = library.manifest(source)
        manifest_path = target / "manifest.json"
        manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
        for key in keys:
            manifest[key] = _copied(entries[key], source, target, key)
        _write(manifest_path, manifest)

    def _sides(self) -> dict[str, str]:
        """Every partner name's split side: a stand-in is on its member's."""
        record = json.loads((self.out / "population.json").read_text())["members"]
        sides = {row["name"]: row["split"] for rows in record.values() for row in rows}
        for name, side in list(sides.items()):
            for stand_in in self.spec.stand_ins(name):
                sides[stand_in] = side
        return sides

    def _side(self, members: list[tuple[Member, str]], side: str, stand_ins: bool = True) -> list[str]:
        names = [m.name for m, s in members if s == side]
        return names + ([s for n in names for s in self.spec.stand_ins(n)] if stand_ins else [])

    def _jobs(self, stage: str, jobs: list, roots: list[Path]) -> list[list]:
        with self._roots(roots), self.engine(stage) as run:
            return run(jobs)

    def _roots(self, roots: list[Path]) -> AbstractContextManager[None]:
        return _library_roots([r for r in roots if _is_library(r)])


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


def _key_of(names: dict[str, str], name: str, role: str) -> str:
    """The grown library's key of a selected member of `role`'s seat (members.json: key -> name)."""
    return next(k for k, n in names.items() if n == name and k.startswith(PREFIX[role]))


def _labels(grid: Grid, groups: list[list[str]]) -> np.ndarray:
    """Each of `grid`'s partners' group, from the groups' member lists."""
    label = np.zeros(len(grid.partners), np.int64)
    for j, members in enumerate(groups):
        for m in members:
            label[grid.partners.index(m)] = j
    return label


def _copied(entry: dict, source: Path, target: Path, key: str) -> dict:
    """A trained policy's weights copied from the library at `source` into `target` as `key`; its
    manifest entry, naming the new file."""
    path = target / "weights" / f"{key}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source / entry["file"], path)
    return entry | {"file": str(path.relative_to(target))}


def _is_library(root: Path) -> bool:
    return (root / "registry.toml").exists()


def figures_on(grid: Grid, chosen: list[str], study: list[str]) -> dict:
    """A library's held-out oracle headroom on `grid`'s partners, its best single member, and the
    study library's (its policies among the candidates) on the same partners."""
    kills, study_kills = grid.columns(chosen), grid.columns(study)
    single, mean = choice.best_single(kills)
    study_single, study_mean = choice.best_single(study_kills)
    return {
        "partners": len(grid.partners),
        "headroom": round(choice.headroom(kills), 4),
        "oracle": round(choice.oracle(kills), 4),
        "best_single": chosen[single],
        "best_single_mean": round(mean, 4),
        "study_best_single": study[study_single],
        "study_best_single_mean": round(study_mean, 4),
        "study_headroom": round(choice.headroom(study_kills), 4),
    }


def _rows(grid: Grid, partners: list[str]) -> Grid:
    index = [grid.partners.index(p) for p in partners]
    return Grid(tuple(partners), grid.candidates, grid.kills[index])


def _recipe_fields(recipe: library.Recipe) -> dict:
    fields = {}
    for name in (
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
    ):
        value = getattr(recipe, name)
        if value not in (None, "", 0, 0.0, (), {}):
            fields[name] = list(value) if isinstance(value, tuple) else value
    if recipe.view != "role":
        fields["frame"] = recipe.view
    return fields


def _rule_settings(name: str) -> dict[str, float]:
    inside = name[name.index("(") + 1 : -1]
    return {k: float(v) for k, v in (part.split("=") for part in inside.split(","))}


def _toml(key: str, recipe: dict) -> str:
    """One registry entry as TOML (strings, numbers, lists of strings, tables of numbers)."""

    def value(v: object) -> str:
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, bool):
            return str(v).lower()
        if isinstance(v, int | float):
            return repr(v)
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        raise TypeError(f"{key}: cannot write {v!r} to a registry")

    return f"\n[{key}]\n" + "".join(f"{k} = {value(v)}\n" for k, v in recipe.items())


def _write(path: Path, record: object) -> None:
    """Written whole or not at all: a stage's file exists only once the stage is done."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    partial.write_text(json.dumps(record, indent=1) + "\n")
    partial.replace(path)


def markdown(summary: dict) -> str:
    """The run's figures as a page: per seat, the test population's headroom and best single member
    beside the study library's, and the selection's headroom curve."""
    lines = [
        "# The grown library",
        "",
        f"Population spec {summary['population']}; every partner is simulated.",
        "",
    ]
    for ours, seat in summary["seats"].items():
        lines += [
            f"## The {ours} seat",
            "",
            "| test partners | n | headroom | grown: best single | study: best single | study: headroom |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for label, f in seat["test"].items():
            lines.append(
                f"| {label} | {f['partners']} | {f['headroom']:+.1%} | "
                f"{f['best_single']} {f['best_single_mean']:.2f} | "
                f"{f['study_best_single']} {f['study_best_single_mean']:.2f} | {f['study_headroom']:+.1%} |"
            )
        lines += [
            "",
            "Selection on the validation population (headroom against library size):",
            "",
            "| size | added | headroom |",
            "| --- | --- | --- |",
        ]
        for i, step in enumerate(seat["curve"]):
            lines.append(f"| {i + 1} | {step['library'][-1]} | {step['headroom']:+.1%} |")
        lines.append("")
    return "\n".join(lines)
