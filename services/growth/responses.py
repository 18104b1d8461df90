"""Stage 4, the responses: one best response of the other seat per group, trained as the spec's
`response` recipe says (its algorithm: PPO where it names none) against the group's members and
their stand-ins into `responses/`, a library of its own (trained in `staging/`, then adopted)."""

from __future__ import annotations

from services.agent import library
from services.growth.workspace import Workspace, is_library, train_job
from services.population.families import RESPONSE_PREFIX, Spec
from shared.game import ROLES, other


def responses(ws: Workspace, groups: dict[str, dict]) -> None:
    """A best response of the other seat for every group, trained into `responses/`."""
    recipes = {}
    for role, record in groups.items():
        ours = other(role)
        for j, members in enumerate(record["groups"]):
            recipes[f"{RESPONSE_PREFIX[ours]}{j + 1}"] = response_recipe(ws.spec, role, j, members)
    trained = library.manifest(ws.responses_dir) if is_library(ws.responses_dir) else {}
    todo = [k for k in recipes if k not in trained]
    if not todo:
        return
    library.record(ws.staging, recipes)
    library.record(ws.responses_dir, recipes)
    jobs = [train_job(k, ws.staging, {k: int(recipes[k]["steps"])}, ws.runs) for k in todo]
    ws.say(f"responses: training {len(jobs)} best responses")
    ws.jobs("responses", jobs, roots=[ws.population_dir])
    library.adopt_members(ws.staging, ws.responses_dir, list(recipes))


def response_recipe(spec: Spec, role: str, j: int, members: list[str]) -> dict:
    """The registry fields of the best response to group `j` (its `members`) of `role`'s seat."""
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
    return recipe | ({"frame": "world"} if ours == "shooter" else {})


def response_partners(spec: Spec, members: list[str]) -> list[str]:
    """What a best response to a group trains with: its members, and a stand-in of each of the
    first few (one per skill level, in turn)."""
    skills = spec.skills
    stand_ins = [spec.stand_ins(m)[i % len(skills)] for i, m in enumerate(members[: len(skills)])]
    return [*members, *stand_ins]
