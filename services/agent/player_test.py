"""The agent's pure core: one seat's player answering every state, switching policy on request."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from services.agent.player import Player
from services.agent.seats import policy_for
from services.sim.engine import Game
from services.sim.match import state_message
from services.sim.play import policy_seed
from shared.game import N_ACTIONS, GameConfig
from shared.messages import Action, State, decode

M = "m1"


def states(seed: int = 2, frames: int = 30, actions: tuple[int, int] = (2, 9)) -> Iterator[State]:
    """The states a sim publishes for a game with fixed actions (frames 0..frames)."""
    game = Game(GameConfig(frames=frames), seed)
    while True:
        yield state_message(game, M, "sim", actions)
        if game.done:
            return
        game.step(*actions)


def play(player: Player, switches: dict[int, str] | None = None) -> list[Action]:
    """Answer every state, switching before the state of each frame named in `switches`."""
    answers, switches = [], switches or {}
    for state in states():
        if state.frame in switches:
            player.switch(switches[state.frame])
        answers.append(player.act(state, "agent/x"))
    return answers


class Recorder:
    """A fake policy that remembers the seeds it was reset with and plays a fixed action."""

    view = "world"

    def __init__(self, key: str, role: str) -> None:
        self.key, self.role, self.seeds = key, role, []

    def reset(self, seed: int | None = None) -> None:
        self.seeds.append(seed)

    def act(self, obs: np.ndarray) -> int:
        assert obs.dtype == np.float32 and obs.shape == (64,)
        return len(self.key)

    def probs(self, obs: np.ndarray) -> np.ndarray:
        return np.full(N_ACTIONS, 1.0 / N_ACTIONS)


def fake_loader(known: tuple[str, ...] = ("a", "bb", "ccc")):  # noqa: ANN201 - a PolicyLoader
    def load(key: str, role: str) -> Recorder:
        if key not in known:
            raise ValueError(f"unknown policy {key!r}")
        return Recorder(key, role)

    return load


@pytest.mark.parametrize(("role", "key"), [("bait", "circle"), ("shooter", "mirror"), ("bait", "random")])
def test_answers_every_state(role: str, key: str) -> None:
    player = Player(role, key, seed=5)
    answers = play(player)
    assert len(answers) == 31
    for frame, answer in enumerate(answers):
        assert (answer.match, answer.frame, answer.role, answer.policy) == (M, frame, role, key)
        assert answer.sender == "agent/x" and 0 <= answer.action < N_ACTIONS
        assert decode(answer.encode(), Action) == answer


def test_switch_takes_effect_at_next_act() -> None:
    player = Player("bait", "circle", seed=1)
    answers = iter(states())
    assert player.act(next(answers), "a").policy == "circle"
    player.switch("idle")
    assert player.key == "circle"  # not before the next state
    assert player.act(next(answers), "a").policy == "idle"
    assert player.key == "idle" and player.pending is None
    assert player.act(next(answers), "a").policy == "idle"


def test_unknown_key_keeps_current_policy() -> None:
    player = Player("shooter", "mirror", seed=1)
    with pytest.raises(ValueError, match="--policy nope: no policy of the shooter seat"):
        player.switch("nope")
    assert player.key == "mirror" and player.pending is None
    assert player.act(next(states()), "a").policy == "mirror"


def test_unknown_key_after_a_good_switch_keeps_the_pending_one() -> None:
    player = Player("bait", "a", load=fake_loader())
    player.switch("bb")
    with pytest.raises(ValueError):
        player.switch("zz")
    assert player.act(next(states()), "a").policy == "bb"


def test_seeds_of_the_first_and_switched_policies() -> None:
    player = Player("shooter", "a", seed=7, load=fake_loader())
    first = player.policy
    assert first.seeds == [policy_seed(7, "shooter")]
    answers = play(player, {10: "ccc"})
    assert [a.action for a in answers] == [1] * 10 + [3] * 21
    assert player.policy.seeds == [policy_seed(7, "shooter") * 1_000_003 + 10]
    assert first.seeds == [policy_seed(7, "shooter")]  # the old policy was not touched again


def test_same_inputs_same_actions() -> None:
    for key, role in (("circle", "bait"), ("mirror", "shooter"), ("random", "bait")):
        runs = [play(Player(role, key, seed=3), {12: "random", 20: key}) for _ in range(2)]
        assert runs[0] == runs[1]


def test_seed_matters() -> None:
    runs = [[a.action for a in play(Player("bait", "random", seed=seed))] for seed in (1, 2)]
    assert runs[0] != runs[1]


def test_default_loader_is_scripted() -> None:
    assert Player("bait", "circle").load is policy_for


class FailsLate:
    """Answers thrust for 5 frames, then `bad` (an exception is raised, anything else returned)."""

    key, role, view = "fails_late", "bait", "world"

    def __init__(self, bad: object) -> None:
        self.bad, self.t = bad, 0

    def reset(self, seed: int | None = None) -> None:
        self.t = 0

    def act(self, obs: np.ndarray) -> int:
        self.t += 1
        if self.t <= 5:
            return 2
        if isinstance(self.bad, Exception):
            raise self.bad
        return self.bad  # type: ignore[return-value]


@pytest.mark.parametrize("bad", [RuntimeError("boom"), 12, -1, "left", 2.0, None])
def test_a_policy_that_fails_plays_no_op_and_the_actions_count_it(bad):
    player = Player("bait", "fails_late", load=lambda key, role: FailsLate(bad))
    actions = [decode(player.act(state, "agent/bait").encode(), Action) for state in states(frames=9)]
    assert [a.action for a in actions] == [2] * 5 + [0] * 5  # every answer valid on the wire
    assert [a.failures for a in actions] == [0] * 5 + [1, 2, 3, 4, 5]
    assert actions[4].failure == "" and actions[5].failure.startswith("fails_late at frame 5: ")
    assert ("RuntimeError: boom" if isinstance(bad, Exception) else "not an action") in actions[5].failure


def test_a_switch_to_what_plays_next_changes_nothing() -> None:
    """The adapter's ruling and its switch message name the same policy: the second must not reset
    it at a later frame (in a lockstep match that frame would be the arrival's, not the ruling's)."""
    player = Player("shooter", "a", seed=7, load=fake_loader())
    answers = iter(states())
    player.switch("ccc")
    player.switch("ccc")  # the same, still pending
    player.act(next(answers), "a")
    switched = player.policy
    player.switch("ccc")  # the same, now playing
    player.act(next(answers), "a")
    assert player.policy is switched and switched.seeds == [policy_seed(7, "shooter") * 1_000_003 + 0]
    player.switch("a")  # another: loaded and played from the next state
    assert player.act(next(answers), "a").policy == "a"
