"""The cross-entropy metric (CEM): how likely a library policy finds another player's actions.

The similarity of a player to a policy is the mean log-probability the policy gives the player's
actions in the states the player saw. States are kept as world-frame values (what the sim
publishes), so that each policy reads them in its own observation frame.
"""

from __future__ import annotations

import numpy as np

from services.sim.engine import Game
from services.sim.observation import as_observation, world_values
from services.sim.play import play
from shared.game import ROLES, GameConfig, Policy, bait_first


def log_probs(policy: Policy, states: list[list[float]], actions: list[int]) -> np.ndarray:
    """log pi(a_t | s_t) for every frame t of a player's (world-frame state, action) stream."""
    frame = policy.frame
    return np.log([policy.probs(as_observation(s, frame))[a] for s, a in zip(states, actions, strict=True)])


def rollout(
    policy: Policy, partner: Policy, seed: int, config: GameConfig | None = None
) -> tuple[list[list[float]], list[int]]:
    """The (world-frame state, action) stream of `policy`'s seat over one game with `partner`."""
    role = policy.role
    states: list[list[float]] = []
    actions: list[int] = []

    def trace(game: Game, bait_action: int, shooter_action: int) -> None:
        states.append(world_values(game, role))
        actions.append((bait_action, shooter_action)[ROLES.index(role)])

    pair = bait_first(role, policy, partner)
    play(*pair, seed, config, trace)
    return states, actions


def cem_matrix(
    policies: list[Policy], partner: Policy, seeds: list[int], config: GameConfig | None = None
) -> np.ndarray:
    """M[i, j]: mean log-probability under policy j of policy i's own actions, over games of i with
    `partner` (one per seed). A diverse library has each diagonal entry clearly above its row."""
    m = np.zeros((len(policies), len(policies)))
    for i, player in enumerate(policies):
        streams = [rollout(player, partner, seed, config) for seed in seeds]
        states = [s for stream in streams for s in stream[0]]
        actions = [a for stream in streams for a in stream[1]]
        for j, judge in enumerate(policies):
            m[i, j] = log_probs(judge, states, actions).mean()
    return m
