"""The lockstep gate: the state after a scoring frame waits for that frame's ruling, once armed."""

from __future__ import annotations

from services.agent.gate import Gate
from shared.messages import State


def state(frame: int) -> State:
    return State(match="m", frame=frame, sender="sim")


def armed() -> Gate:
    gate = Gate()
    gate.armed = True
    return gate


def test_unarmed_answers_every_state_at_once() -> None:
    gate = Gate()
    assert all(gate.offer(state(f)) for f in range(20)) and gate.held is None


def test_the_state_after_a_scoring_frame_waits_for_its_ruling() -> None:
    gate = armed()
    assert all(gate.offer(state(f)) for f in range(6))  # frames 0-5: no ruling is due before them
    six = state(6)
    assert not gate.offer(six) and gate.held is six
    assert gate.rule(5) is six and gate.held is None
    assert all(gate.offer(state(f)) for f in range(7, 12))
    assert gate.rule(11) is None  # a ruling ahead of its state: that state goes at once
    assert gate.offer(state(12))


def test_an_earlier_ruling_frees_nothing_and_a_later_one_frees_the_held() -> None:
    gate = armed()
    twelve = state(12)
    assert not gate.offer(twelve)
    assert gate.rule(5) is None and gate.held is twelve
    assert gate.rule(17) is twelve  # a lost ruling's batch ruled on with the next


def test_a_wait_that_runs_out_opens_the_gate_until_the_next_ruling() -> None:
    gate = armed()
    six = state(6)
    assert not gate.offer(six)
    assert gate.expire(state(6)) is None  # another state than the held one: nothing
    assert gate.expire(six) is six and not gate.waiting
    assert gate.offer(state(12)) and gate.offer(state(18))  # a dead adapter costs one wait
    assert gate.rule(5) is None and gate.waiting
    assert not gate.offer(state(24))
    assert gate.expire(six) is None  # a stale timer frees nothing
