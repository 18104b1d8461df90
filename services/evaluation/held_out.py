"""The partner population's test split, as the shipped grown library's run left it: the partners
that training, grouping and selection never saw (members and their human-like stand-ins), each
with the partner group its results place it in. `tsf eval --population held-out`
measures the adaptive teammate on them (populations.py).

The grown library keeps its run's records (services/agent/grown/run-*.json, written by `tsf library
grow`): the members' split sides (run-population.json) and, per seat of ours, every held-out
partner's group (run-summary.json: the group whose training members' rows, what works with them,
its own row is nearest).
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

from services.agent import library
from services.population import families
from shared.game import other

RUN = library.NAMED["grown"]  # the shipped grown library, with its run's records
STAND_IN = "human("  # how a member played through a stand-in is named (families.Spec.stand_ins)
PARTS = {  # the parts of the test population each result is also given for
    "members": lambda partner: not partner.startswith(STAND_IN),
    "stand-ins": lambda partner: partner.startswith(STAND_IN),
}


def _read(name: str, run: Path) -> dict:
    return json.loads((run / f"run-{name}.json").read_text())


@cache
def test_partners(partner_role: str, run: Path = RUN) -> dict[str, str]:
    """Each test partner of `partner_role` (the members of the test split, then their stand-ins)
    with its partner group's name (G1..), as the groups of the adaptive teammate in the other seat
    name them."""
    members = [m["name"] for m in _read("population", run)["members"][partner_role] if m["split"] == "test"]
    spec = families.read()
    groups = _read("summary", run)["seats"][other(partner_role)]["partners"]
    return {n: groups[n] for n in members + [s for m in members for s in spec.stand_ins(m)]}


def members(partner_role: str, run: Path = RUN) -> dict[str, str]:
    """The test partners that are members (no stand-ins), with their groups."""
    return {p: g for p, g in test_partners(partner_role, run).items() if PARTS["members"](p)}


def statics(role: str, run: Path = RUN) -> list[str]:
    """Every static policy of our seat `role` the comparison chooses its best from: the study's
    library policies and the grown library's members (GB1.., GS1..; not those that are a study
    policy under another key)."""
    study = library.keys(role)
    grown = json.loads((run / "members.json").read_text())
    seat = library.registry(run)
    return study + [key for key, name in grown.items() if seat[key].role == role and name not in study]
