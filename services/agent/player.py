"""The agent service's pure core: one seat's player, turning states into actions."""

from __future__ import annotations

import threading
from collections.abc import Callable

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

    def act(self, state: State, sender: str) -> Action:
        with self._lock:
            if self.pending is not None:
                self.policy, self.pending = self._next, None
                self.policy.reset(switch_seed(self.seed, self.role, state.frame))
            policy = self.policy
        obs = as_observation(state.obs[self.role], policy.view)
        try:
            action, failure = checked_action(policy.act(obs)), ""
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
