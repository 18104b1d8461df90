"""The agent service's pure core: one seat's player, turning states into actions."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from services.agent.networks import LearnedPolicy
from services.agent.policy import rule_stack_key
from services.agent.seats import policy_for
from services.sim.observation import as_observation
from services.sim.play import policy_seed, switch_seed
from shared.game import NOOP, Policy, checked_action
from shared.messages import Action, State, printable

PolicyLoader = Callable[[str, str], Policy]


class Player:
    """Plays one role with a policy chosen by key. A switch takes effect at the next state, so no
    frame goes unanswered; the new policy is reset with a seed derived from the game's seed and the
    frame, so a match stays a function of its inputs. A policy that raises or answers no action
    plays no-op for that frame, and the action says so (`failures`, `failure`)."""

    def __init__(self, role: str, key: str, seed: int = 0, load: PolicyLoader = policy_for) -> None:
        self.role, self.seed, self.load = role, seed, load
        self.policy = load(key, role)
        self.policy.reset(policy_seed(seed, role))
        self.pending: str | None = None
        self.failures = 0  # frames on which the policy raised or answered no action (played no-op)
        self._lock = threading.Lock()

    @property
    def key(self) -> str:
        return self.policy.key

    @property
    def next_key(self) -> str:
        """The policy the next state is answered with: the one asked for, else the one playing."""
        with self._lock:
            return self._next_key()

    def _next_key(self) -> str:
        return self.pending if self.pending is not None else self.policy.key

    def switch(self, key: str) -> None:
        """Ask for another policy; it is loaded now (a bad key raises here) and played from the next
        state. A switch to the policy that plays next anyway changes nothing: the adapter's ruling
        and its switch message name the same policy, and whichever comes second must not reset it
        at a later frame (asked again once loaded: the other may have come, and played, meanwhile)."""
        if key == self.next_key:
            return
        policy = self.load(key, self.role)
        with self._lock:
            if key != self._next_key():
                self.pending, self._next = key, policy

    def ready(self, frame: int) -> Policy:
        """The policy that answers the state of `frame`: a pending switch takes effect here."""
        with self._lock:
            if self.pending is not None:
                self.policy, self.pending = self._next, None
                self.policy.reset(switch_seed(self.seed, self.role, frame))
            return self.policy

    def act(self, state: State | Frame, sender: str) -> Action:
        policy = self.ready(state.frame)
        obs = as_observation(state.obs[self.role], policy.view)
        return self.answer(state, sender, policy, lambda: policy.act(obs))

    def answer(self, state: State | Frame, sender: str, policy: Policy, play: Callable[[], int]) -> Action:
        """The action `play` gives (a policy's act, or its row of a batch's), or no-op where it
        raises or answers no action, counted and said."""
        try:
            action, failure = checked_action(play()), ""
        except Exception as error:  # noqa: BLE001 - a policy from outside may raise anything; the match goes on
            self.failures += 1
            action, failure = NOOP, f"{policy.key} at frame {state.frame}: {type(error).__name__}: {error}"
        return Action(
            match=state.match,
            frame=state.frame,
            sender=sender,
            role=self.role,
            action=action,
            policy=policy.key,
            failures=self.failures,
            failure=printable(failure, 200),
        )


class Frame(NamedTuple):
    """One match's frame as a pool's Tick gives it to the agent (shared.messages.Tick): what a
    player reads of a State, each seat's world-view values a float64 row."""

    match: str
    frame: int
    obs: dict[str, np.ndarray]


def play_together(policies: list[Policy], observations: np.ndarray) -> list[int] | None:
    """The actions of seats that play one library policy (each its own copy and random stream),
    for their (seats, 64) observations, the policy evaluated once for all rows: a rule's choices
    (its compiled form), a network's heads; then each seat draws with its own stream, as `act`
    does. None for any other kind of policy (each seat then acts alone)."""
    first = policies[0]
    if type(first) is LearnedPolicy:
        heads = first.head_probs_batch(observations)
        return [p.sample({name: h[i] for name, h in heads.items()}) for i, p in enumerate(policies)]
    if rule_stack_key(first) is not None:
        choices = first.rule_batch(observations).tolist()
        return [p.explore(tuple(c)) for p, c in zip(policies, choices, strict=True)]
    return None
