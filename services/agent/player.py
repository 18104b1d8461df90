"""The agent service's pure core: one seat's player, turning states into actions."""

from __future__ import annotations

import threading
from collections.abc import Callable

from services.agent.library import policy_for
from services.sim.observation import as_observation
from services.sim.play import policy_seed, switch_seed
from shared.game import Policy
from shared.messages import Action, State

PolicyLoader = Callable[[str, str], Policy]


class Player:
    """Plays one role with a policy chosen by key. A switch takes effect at the next state, so no
    frame goes unanswered; the new policy is reset with a seed derived from the game's seed and the
    frame, so a match stays a function of its inputs."""

    def __init__(self, role: str, key: str, seed: int = 0, load: PolicyLoader = policy_for) -> None:
        self.role, self.seed, self.load = role, seed, load
        self.policy = load(key, role)
        self.policy.reset(policy_seed(seed, role))
        self.pending: str | None = None
        self._lock = threading.Lock()

    @property
    def key(self) -> str:
        return self.policy.key

    def switch(self, key: str) -> None:
        """Ask for another policy; it is loaded now (a bad key raises here) and played from the next state."""
        policy = self.load(key, self.role)
        with self._lock:
            self.pending = key
            self._next = policy

    def act(self, state: State, sender: str) -> Action:
        with self._lock:
            if self.pending is not None:
                self.policy, self.pending = self._next, None
                self.policy.reset(switch_seed(self.seed, self.role, state.frame))
            policy = self.policy
        action = policy.act(as_observation(state.obs[self.role], policy.view))
        return Action(
            match=state.match,
            frame=state.frame,
            sender=sender,
            role=self.role,
            action=action,
            policy=policy.key,
        )
