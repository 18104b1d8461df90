"""The cross-entropy metric (CEM): how likely a library policy finds another player's actions.

The similarity of a player to a policy is the mean log-probability the policy gives the player's
actions in the states the player saw. States are kept as world-view values (what the sim
publishes), so that each policy reads them in its own observation view.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from services.agent import networks
from services.agent.policy import Ending, RuleStack, end_round_batch, rule_stack_key
from services.sim.engine import Game
from services.sim.observation import as_observation, world_values
from services.sim.play import play
from services.sim.sampling import batch_probs
from shared.game import ROLES, GameConfig, Policy, bait_first

Evaluation = list[tuple[np.ndarray, str, Callable[[np.ndarray, Ending], np.ndarray]]]  # `evaluation`'s plan


def log_probs(
    policies: Sequence[Policy],
    states: Sequence[Sequence[float]],
    actions: Sequence[int],
    plan: Evaluation | None = None,
) -> np.ndarray:
    """The similarity score, (n, K): log pi_k(a_t | s_t) of a player's n (world-view state values,
    action) pairs under each of K policies. Every policy reads the states in its own view, and its
    probabilities come from one batched evaluation (sampling.batch_probs) over all n states; `plan`
    is the policies' `evaluation`, where the caller keeps one (a scorer's)."""
    views = {p.view for p in policies}
    observed = {v: np.stack([as_observation(s, v) for s in states]) for v in sorted(views)}
    return observed_log_probs(policies, observed, actions, plan)


def observed_log_probs(
    policies: Sequence[Policy],
    observed: Mapping[str, np.ndarray],
    actions: Sequence[int] | np.ndarray,
    plan: Evaluation | None = None,
) -> np.ndarray:
    """`log_probs` of n states already observed in each policy's view (`observed[view]`: (n, 64),
    as the batched engine observes them, bit-identical to as_observation of the world values),
    by the policies' `evaluation` (`plan`, or made here for this call)."""
    rows = np.arange(len(actions))
    out = np.empty((len(policies), len(actions)))
    endings: dict[str, Ending] = {}  # the stalled rounds of each view's rows, found once for every stack
    for columns, view, probs in plan or evaluation(policies):
        if view not in endings:
            endings[view] = end_round_batch(observed[view], view)
        out[columns] = probs(observed[view], endings[view])[:, rows, actions]
    return np.log(out).T


def evaluation(policies: Sequence[Policy]) -> Evaluation:
    """How the policies are evaluated: each stack of learned policies (networks.stack_key: a
    population's members of one family) and of rules (policy.rule_stack_key: a rule grid) as one,
    every other policy alone; (columns, view, (observations, their end_round_batch) ->
    (len(columns), n, 12)). A stack copies its networks' layers, so a caller that scores the same
    policies often (a scorer) keeps it."""
    stacks = {"network": networks.Stack, "rule": RuleStack}
    groups: dict[tuple, list[int]] = {}
    for i, policy in enumerate(policies):
        learned, rule = networks.stack_key(policy), rule_stack_key(policy)
        kind = ("network", learned) if learned else ("rule", rule) if rule else ("alone", i)
        groups.setdefault(kind, []).append(i)
    plan = []
    for (kind, _), columns in groups.items():
        members, at = [policies[i] for i in columns], np.array(columns)
        if kind in stacks:
            plan.append((at, members[0].view, stacks[kind](members)))
        else:
            plan.append((at, members[0].view, lambda obs, _, p=members[0]: batch_probs(p, obs)[None]))
    return plan


def rollout(
    policy: Policy, partner: Policy, seed: int, config: GameConfig | None = None
) -> tuple[list[list[float]], list[int]]:
    """The (world-view state, action) stream of `policy`'s seat over one game with `partner`."""
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
        m[i] = log_probs(policies, states, actions).mean(axis=0)
    return m
