"""The conditioned teammate (TALENTS, PECAN): one network of our seat told its partner's group,
tried against switching among members, on a grown run's held-out partners.

It trains as a best response does (the spec's `response` recipe, PPO), against every training
member of the other seat and their stand-ins at once, with each game's partner group appended to
the observation as a one-hot (`Told`); by default for as many steps as all the groups' best
responses together, so that neither side had more experience. Told the group, the network is a plain
network of the recipe: the one-hot's first-layer weights add to the bias (`told`). So each group's
conditioned teammate is an ordinary library policy (CB1.., CS1..), and the adapter's switch to the
identified group's teammate is exactly the conditioned teammate told the adapter's estimate.

The comparison gives both sides the partner's true group (oracle identification), on the validation
partners (where the library was selected) and on the test partners, members and stand-ins, over the
held-out cross-play's seeds: the conditioned teammate told the group; the grown library's teammate
that groups.json names best for the group (what the adaptive agent switches to); and the group's own
best response (`responses/`). The winner on validation is what the adaptive agent should play.
With `separate`, the new teammates are instead the groups' own best responses trained on to more
steps (from the run's checkpoints), compared alike: would responses at the study's scale do?
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from services.agent import library
from services.growth import choice
from services.growth.choice import Grid
from services.growth.crossplay import kills_of, pair_jobs
from services.growth.groups import grouped
from services.growth.library import GROUPS, recipe_fields
from services.growth.responses import response_partners
from services.growth.training import train_levels
from services.growth.workspace import Workspace
from services.population.families import CONDITIONED_PREFIX, RESPONSE_PREFIX
from services.training.algorithms import export, make_model
from services.training.loop import whole_rollouts
from shared.files import write_json
from shared.game import ROLES, other


class Told(VecEnvWrapper):
    """A recipe's env (training/env.py) whose observation ends with the one-hot of each game's
    partner group: `group_of[i]` is the group of the env's partner `i`."""

    def __init__(self, venv: VecEnv, group_of: np.ndarray) -> None:
        self.group_of = np.asarray(group_of, np.int64)
        self.groups = int(self.group_of.max()) + 1
        inner = venv.observation_space
        low = np.concatenate([inner.low, np.zeros(self.groups, np.float32)])
        high = np.concatenate([inner.high, np.ones(self.groups, np.float32)])
        super().__init__(venv, observation_space=spaces.Box(low, high, dtype=np.float32))

    def current(self) -> np.ndarray:
        """Each lane's partner group now."""
        return self.group_of[self.venv.env.partner_of]

    def with_group(self, obs: np.ndarray, group: np.ndarray) -> np.ndarray:
        return np.concatenate([obs, np.eye(self.groups, dtype=np.float32)[group]], axis=-1)

    def reset(self) -> np.ndarray:
        return self.with_group(self.venv.reset(), self.current())

    def step_wait(self) -> tuple:
        before = self.current()  # a finished game's last observation belongs to its partner
        obs, rewards, done, infos = self.venv.step_wait()
        for lane in np.flatnonzero(done):
            last = infos[lane]["terminal_observation"]
            infos[lane]["terminal_observation"] = self.with_group(last, before[lane])
        return self.with_group(obs, self.current()), rewards, done, infos


def told(arrays: dict[str, np.ndarray], belief: np.ndarray) -> dict[str, np.ndarray]:
    """A conditioned network's arrays told `belief` (a one-hot, or probabilities over the groups):
    a plain network over the recipe's features, the belief's part of the first layer in its bias."""
    groups = len(belief)
    w0 = arrays["w0"]
    out = dict(arrays)
    out["w0"] = np.ascontiguousarray(w0[:, :-groups])
    out["b0"] = (arrays["b0"] + w0[:, -groups:] @ np.asarray(belief, w0.dtype)).astype(arrays["b0"].dtype)
    return out


def train_conditioned(
    recipe: library.Recipe, root: Path, group_of: np.ndarray, steps: int, seed: int
) -> dict[str, np.ndarray]:
    """The conditioned network's arrays (training/algorithms.export), trained for `steps`: the
    recipe of the library at `root` with the group of each of its partners appended."""
    model = make_model(recipe, seed, root=root, wrap=lambda env: Told(env, group_of))
    model.learn(whole_rollouts(model, steps), progress_bar=False)
    return export(model, recipe)


def compare(
    kills: Callable[[str], np.ndarray],
    placed: np.ndarray,
    parts: dict[str, np.ndarray],
    sides: dict[str, list],
) -> dict:
    """Per part of the partners (validation/test, members/stand-ins, each group): the mean kills/min of each
    side, given each partner's group, and the paired difference of the new teammates (`new`) with
    switching. `kills(name)` is a teammate's (partners, seeds) kills/min; `sides[side]` each group's
    teammate of that side."""
    per_side = {
        side: np.array([kills(names[g])[i].mean() for i, g in enumerate(placed)])
        for side, names in sides.items()
    }
    out = {}
    for part, rows in parts.items():
        if not rows.any():
            continue
        diff = per_side["new"][rows] - per_side["switching"][rows]
        out[part] = {"partners": int(rows.sum())}
        out[part] |= {side: round(float(v[rows].mean()), 4) for side, v in per_side.items()}
        out[part]["difference"] = round(float(diff.mean()), 4)
        out[part]["difference se"] = (
            round(float(diff.std(ddof=1) / np.sqrt(rows.sum())), 4) if rows.sum() > 1 else None
        )
    return out


def run_conditioned(grow: Workspace, ours: str, steps: int | None = None, separate: bool = False) -> dict:
    """The experiment for seat `ours` on the finished run `grow`: the teammates trained (once, into
    a library of their own: `conditioned-OURS-STEPS/`, the conditioned network told each group;
    with `separate`, `responses-OURS-STEPS/`, each group's best response trained on to `steps`), their
    games with every held-out partner and the comparison (once: that directory's name + `.json`)."""

    grow.bind()  # a run of another spec is refused
    out, partner_role = grow.out, other(ours)
    groups = json.loads((out / "groups.json").read_text())[partner_role]["groups"]
    responses = [f"{RESPONSE_PREFIX[ours]}{j + 1}" for j in range(len(groups))]
    steps = steps or int(grow.spec.seats[ours].response["steps"]) * (1 if separate else len(groups))
    if separate:
        root = out / f"responses-{ours}-{steps}"
        teammates = [f"{r}-{steps}" for r in responses]
        make = _separate_library
    else:
        root = out / f"conditioned-{ours}-{steps}"
        teammates = [f"{CONDITIONED_PREFIX[ours]}{j + 1}" for j in range(len(groups))]
        make = _conditioned_library
    if not (root / "manifest.json").exists():
        make(grow, ours, groups, steps, root, teammates)
    held = Grid.of(json.loads((out / "held-out.json").read_text())[partner_role])
    done = out / f"{root.name}.json"
    record = json.loads(done.read_text()) if done.exists() else {}
    if "kills" not in record:
        seeds = list(range(grow.spec.games))
        teams = [(p, c) if partner_role == "bait" else (c, p) for p in held.partners for c in teammates]
        jobs = pair_jobs(root.name, teams, seeds)
        values = grow.jobs(root.name, jobs, roots=[grow.population_dir, root])
        record["kills"] = kills_of(values, len(held.partners), len(teammates), len(seeds))
    played = Grid(held.partners, tuple(teammates), np.array(record["kills"]))
    grouping = Grid.of(json.loads((out / "grouping.json").read_text())[partner_role])
    placed = choice.place(held, *grouped(grouping, groups))
    grown = json.loads((grow.library_dir / GROUPS).read_text())["seats"][ours]
    switching = [grown["names"][int(np.argmax(g["values"]))] for g in grown["groups"]]
    sides = grow.sides()
    side = np.array([sides[p] for p in held.partners])
    person = np.array([p.startswith("human(") for p in held.partners])
    parts = {}
    for split in ("validation", "test"):
        parts |= {split: side == split, f"{split}, members": (side == split) & ~person}
        parts[f"{split}, stand-ins"] = (side == split) & person
    parts |= {f"both, group G{j + 1}": placed == j for j in range(len(groups))}

    def kills(name: str) -> np.ndarray:
        return (played if name in teammates else held).columns([name])[:, 0]

    trained = all(r in held.candidates for r in responses)  # the run's own, as the selection saw them
    record |= {
        "seat": ours,
        "teammates": "separate" if separate else "conditioned",
        "steps": steps,
        "switching": switching,
        "figures": compare(
            kills,
            placed,
            parts,
            {"new": teammates, "switching": switching} | ({"responses": responses} if trained else {}),
        ),
    }
    validation = record["figures"]["validation"]  # the newcomer must win, one-sided at 5 %
    wins = validation["difference"] > 1.645 * (validation["difference se"] or np.inf)
    record["kept"] = record["teammates"] if wins else "switching"
    write_json(done, record)
    return record


def _conditioned_library(
    grow: Workspace, ours: str, groups: list[list[str]], steps: int, root: Path, teammates: list[str]
) -> None:
    """The conditioned network, trained with every group's partners at once, told each group."""

    partners = [response_partners(grow.spec, members) for members in groups]
    recipe = dict(grow.spec.seats[ours].response) | {
        "role": ours,
        "family": "conditioned",
        "description": f"PPO told its partner's group ({len(groups)} {other(ours)} groups)",
        "algorithm": "PPO",
        "seed": grow.spec.seed + 2000 + ROLES.index(ours),
        "steps": steps,
        "partners": [p for names in partners for p in names],
    }
    recipe |= {"frame": "world"} if ours == "shooter" else {}
    staging = grow.out / f"{root.name}-recipe"  # in no library in use, as grow's staging
    library.write_registry(staging, {CONDITIONED_PREFIX[ours]: recipe})
    group_of = np.array([j for j, names in enumerate(partners) for _ in names])
    with grow.playing([grow.population_dir]):
        trained = library.registry(staging)[CONDITIONED_PREFIX[ours]]
        arrays = train_conditioned(trained, staging, group_of, steps, recipe["seed"])
    recipes, manifest = {}, {}
    for j, name in enumerate(teammates):
        path = root / "weights" / f"{name}.npz"
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **told(arrays, np.eye(len(groups))[j]))
        recipes[name] = recipe | {"description": f"PPO told its partner's group: {other(ours)} group {j + 1}"}
        manifest[name] = {
            "file": str(path.relative_to(root)),
            "sha256": library.file_hash(path),
            "algorithm": "PPO",
            "steps": steps,
            "seed": recipe["seed"],
            "command": f"tsf library condition {grow.out} --seat {ours} --steps {steps}",
        }
    library.write_registry(root, recipes)
    library.write_manifest(root, manifest)


def _separate_library(
    grow: Workspace, ours: str, groups: list[list[str]], steps: int, root: Path, teammates: list[str]
) -> None:
    """Each group's best response (the run's own recipe, in its staging) trained on to `steps`
    from its checkpoint, under the key `teammates` gives it."""

    recipes, manifest = {}, {}
    for j, name in enumerate(teammates):
        key = f"{RESPONSE_PREFIX[ours]}{j + 1}"
        with grow.playing([grow.population_dir]):
            train_levels(key, grow.staging, {key: steps}, grow.runs)
        manifest[name] = library.copy_member(grow.staging, library.manifest(grow.staging)[key], root, name)
        recipe = library.registry(grow.staging)[key]
        recipes[name] = recipe_fields(recipe) | {"steps": steps, "description": recipe.description}
    library.write_registry(root, recipes)
    library.write_manifest(root, manifest)


def markdown(record: dict) -> str:
    """The comparison as a table: each side's mean kills/min given the partner's group, and the
    new teammates' paired difference with switching."""
    sides = [s for s in ("new", "switching", "responses") if s in next(iter(record["figures"].values()))]
    separate = record["teammates"] == "separate"
    what = "each group's best response, trained apart" if separate else "the conditioned teammate"
    lines = [
        f"# New teammates of the {record['seat']} seat: {what} ({record['steps']:,} PPO steps)",
        "",
        f"Every partner is simulated; both sides are told the partner's group. New: {what}. "
        "Switching plays, per group: "
        + ", ".join(f"G{j + 1} {name}" for j, name in enumerate(record["switching"]))
        + ".",
        "",
        "| partners | n | " + " | ".join(sides) + " | new - switching |",
        "| --- | --- | " + " | ".join("---" for _ in sides) + " | --- |",
    ]
    for part, f in record["figures"].items():
        se = f" ± {f['difference se']:.2f}" if f["difference se"] is not None else ""
        cells = " | ".join(f"{f[s]:.2f}" for s in sides)
        lines.append(f"| {part} | {f['partners']} | {cells} | {f['difference']:+.2f}{se} |")
    lines += ["", f"Kept on validation: **{record['kept']}**.", ""]
    return "\n".join(lines)
