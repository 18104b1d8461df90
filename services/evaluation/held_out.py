"""The partner population's test split, as the default agent's library's run left it (the tuned
library's; the grown library's run split the same members alike): the partners that training,
grouping and selection never saw (members and their human-like stand-ins), each with the partner
group its results place it in. `tsf eval --population held-out` measures the adaptive teammate on
them (populations.py).

A grown library keeps its run's records (services/agent/tuned/run-*.json, written by `tsf library
grow`): the members' split sides (run-population.json) and, per seat of ours, every held-out
partner's group (run-summary.json: the group whose training members' rows, what works with them,
its own row is nearest; as the library's groups.json names them).
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

from services.agent import library
from services.population import families
from shared.game import other

RUN = library.NAMED["tuned"]  # the default agent's library, with its run's records (grown's: the same split)
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


def statics(role: str) -> list[str]:
    """Every static policy of our seat `role` the comparison chooses its best from: the study's
    library policies and the members of every shipped grown library (GB1.., GS1..; TB1.., TS1..),
    each once (not one that is a study policy, or an earlier library's member, under another key)."""
    keys = library.keys(role)
    names = set(keys)
    for root in library.NAMED.values():
        if not (root / "members.json").is_file():
            continue
        seat = library.registry(root)
        for key, name in json.loads((root / "members.json").read_text()).items():
            if seat[key].role == role and name not in names:
                keys.append(key)
                names.add(name)
    return keys
