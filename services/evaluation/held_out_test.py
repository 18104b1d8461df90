"""The test split as the shipped grown library's run records it."""

from __future__ import annotations

import json

from services.evaluation import held_out


def test_the_test_partners_are_the_runs_test_members_and_their_stand_ins_with_their_groups():
    run = json.loads((held_out.RUN / "run-population.json").read_text())["members"]
    groups = json.loads((held_out.RUN / "groups.json").read_text())["seats"]
    for partner_role, ours in (("bait", "shooter"), ("shooter", "bait")):
        test = {m["name"] for m in run[partner_role] if m["split"] == "test"}
        partners = held_out.test_partners(partner_role)
        assert set(held_out.members(partner_role)) == test
        assert len(partners) == 4 * len(test)  # each member and its three stand-ins
        named = {g["name"] for g in groups[ours]["groups"]}
        assert set(partners.values()) <= named  # the groups the adaptive agent in our seat knows
        known = {m for g in groups[ours]["groups"] for m in g["members"]}
        assert not known & test  # none of them is a member the agent scores
    statics = held_out.statics("bait")
    assert statics[:9] == [f"B{i}" for i in range(1, 10)] and "GB1" in statics and "GB2" not in statics  # B6
