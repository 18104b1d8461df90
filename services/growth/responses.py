"""Stage 4, the responses: one best response of the other seat per group, trained as the spec's
`response` recipe says (its algorithm: PPO where it names none) against the group's members and
their stand-ins into `responses/`, a library of its own (trained in `staging/`, then adopted).

Where the recipe asks for a warm start (`warm_start = true`), a response first imitates its
group's best rule of the family a network can imitate (scripted.DEMONSTRATOR: the circle for a
bait, the mirror for a shooter), chosen on the grouping cross-play, by DAgger
(training.algorithms.warm_start_fit), then learns by its algorithm: it starts from the teammate
the group already has instead of from a random walk."""

from __future__ import annotations

from services.agent import library
from services.agent.scripted import DEMONSTRATOR
from services.growth import choice
from services.growth.choice import Grid
from services.growth.library import rule_settings
from services.growth.workspace import Workspace, is_library, train_job
from services.population.families import RESPONSE_PREFIX, Spec
from shared.game import ROLES, other


def responses(ws: Workspace, groups: dict[str, dict], grouping: dict[str, Grid]) -> None:
    """A best response of the other seat for every group, trained into `responses/`."""
    recipes, warm = {}, {}
    for role, record in groups.items():
        ours = other(role)
        warm[ours] = ws.spec.seats[ours].warm_start
        for j, members in enumerate(record["groups"]):
            shown = demonstrator(grouping[role], members, DEMONSTRATOR[ours]) if warm[ours] else None
            recipes[f"{RESPONSE_PREFIX[ours]}{j + 1}"] = response_recipe(ws.spec, role, j, members, shown)
    trained = library.manifest(ws.responses_dir) if is_library(ws.responses_dir) else {}
    todo = [k for k in recipes if k not in trained]
    if not todo:
        return
    library.record(ws.staging, recipes)
    library.record(ws.responses_dir, recipes)
    steps = {k: int(recipes[k]["steps"]) for k in todo}
    jobs = [train_job(k, ws.staging, {k: steps[k]}, ws.runs, warm[recipes[k]["role"]]) for k in todo]
    ws.say(f"responses: training {len(jobs)} best responses")
    ws.jobs("responses", jobs, roots=[ws.population_dir])
    library.adopt_members(ws.staging, ws.responses_dir, list(recipes))


def demonstrator(grid: Grid, members: list[str], family: str) -> dict[str, float]:
    """The settings of the candidate of rule `family` with the best mean kills/min over `members`
    (the group's rows of the grouping cross-play)."""
    rules = [c for c in grid.candidates if c.startswith(f"{family}(")]
    if not rules:
        raise ValueError(f"no {family} rule among the candidates to warm-start from")
    best, _ = choice.best_single(grid.only(members).columns(rules))
    return rule_settings(rules[best])


def response_recipe(
    spec: Spec, role: str, j: int, members: list[str], demonstrator: dict[str, float] | None = None
) -> dict:
    """The registry fields of the best response to group `j` (its `members`) of `role`'s seat; with
    a `demonstrator`, the settings of the rule it imitates first."""
    ours = other(role)
    recipe = dict(spec.seats[ours].response)
    recipe |= {
        "role": ours,
        "family": "response",
        "description": f"{recipe['algorithm']} best response to {role} group {j + 1} "
        f"({len(members)} members), with their stand-ins",
        "seed": spec.seed + 1000 + 10 * ROLES.index(ours) + j,
        "partners": response_partners(spec, members),
    }
    recipe |= {"demonstrator": demonstrator} if demonstrator else {}
    return recipe | ({"frame": "world"} if ours == "shooter" else {})


def response_partners(spec: Spec, members: list[str]) -> list[str]:
    """What a best response to a group trains with: its members, and a stand-in of each of the
    first few (one per skill level, in turn)."""
    skills = spec.skills
    stand_ins = [spec.stand_ins(m)[i % len(skills)] for i, m in enumerate(members[: len(skills)])]
    return [*members, *stand_ins]
