"""Building blocks of policies: factored distributions, rule-based and uniform play.

The `Policy` protocol itself is part of the game's vocabulary (shared/game.py).
"""

from __future__ import annotations

import math
import random

import numpy as np

from services.sim import observation as ob
from services.sim.jit import compiled, jitable
from shared.game import N_ACTIONS, N_FIRE, N_THRUST, N_TURN, GameConfig, join_action

HEAD_SIZES = (N_TURN, N_THRUST, N_FIRE)


def factored_probs(turn: np.ndarray, thrust: np.ndarray, fire: np.ndarray) -> np.ndarray:
    """Joint distribution over the actions (shared.game.join_action) from three independent heads."""
    return (turn[:, None, None] * thrust[None, :, None] * fire[None, None, :]).reshape(N_ACTIONS)


def factored_probs_batch(turn: np.ndarray, thrust: np.ndarray, fire: np.ndarray) -> np.ndarray:
    """factored_probs() of every row of the three heads' (..., n) distributions, the same products:
    (..., 12), the leading dimensions broadcast (a stack's learned heads are (policies, rows, n), its
    rule heads (1, rows, n), the same for every policy)."""
    joint = turn[..., :, None, None] * thrust[..., None, :, None] * fire[..., None, None, :]
    return joint.reshape(*joint.shape[:-3], N_ACTIONS)


def rule_head_probs(choices: np.ndarray, n: int, epsilon: float) -> np.ndarray:
    """(rows, n) distributions of a rule head: each row's choice with 1 - epsilon, the rest spread."""
    out = np.full((len(choices), n), epsilon / (n - 1))
    out[np.arange(len(choices)), choices] = 1.0 - epsilon
    return out


def rule_probs(choices: np.ndarray, epsilon: float) -> np.ndarray:
    """(rows, 12) distributions of rules' (rows, 3) choices, each head a rule head."""
    return factored_probs_batch(
        *(rule_head_probs(choices[:, k], n, epsilon) for k, n in enumerate(HEAD_SIZES))
    )


class RulePolicy:
    """A rule picks one choice per head; the policy plays it with probability 1 - epsilon per head
    and spreads epsilon evenly over that head's other choices (EPSILON, documented in the library
    docs), so every action keeps a small, known probability."""

    EPSILON = 0.01
    key = "rule"
    role = "bait"
    view = "world"
    ends_stalled_rounds = True  # plays end_round_choice while the round is stalled (stalled())

    def __init__(self, epsilon: float = EPSILON) -> None:
        if not 0.0 < epsilon < 1.0:
            raise ValueError(f"epsilon must be in (0, 1), got {epsilon}")
        self.epsilon = epsilon
        self.rng = random.Random(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = random.Random(seed)

    def choose(self, obs: np.ndarray) -> tuple[int, int, int]:
        """The rule: (turn, thrust, fire) intended for this observation."""
        raise NotImplementedError

    def rule(self, obs: np.ndarray) -> tuple[int, int, int]:
        """What the policy intends: its own rule, or ending the round when it is stalled."""
        if self.ends_stalled_rounds and stalled(obs):
            return end_round_choice(obs, self.view == "world")
        return self.choose(obs)

    def rule_batch(self, observations: np.ndarray) -> np.ndarray:
        """rule() of every row, (rows, 3)."""
        return RuleStack([self]).rules(observations)[0]

    def act(self, obs: np.ndarray) -> int:
        turn, thrust, fire = self.rule(obs)
        rng, eps = self.rng, self.epsilon
        if rng.random() < eps:
            turn = (turn + rng.randrange(1, N_TURN)) % N_TURN
        if rng.random() < eps:
            thrust = 1 - thrust
        if rng.random() < eps:
            fire = 1 - fire
        return join_action(turn, thrust, fire)

    def probs(self, obs: np.ndarray) -> np.ndarray:
        return rule_probs(np.array([self.rule(obs)]), self.epsilon)[0]

    def choose_batch(self, observations: np.ndarray) -> np.ndarray:
        """choose() of every row, (rows, 3); the project's rules run their compiled form."""
        return np.array([self.choose(obs) for obs in observations], np.int64).reshape(-1, 3)

    def probs_batch(self, observations: np.ndarray) -> np.ndarray:
        """probs() of every row of an (n, 64) array: a stack of one (`RuleStack`)."""
        return RuleStack([self])(observations)[0]


class RuleStack:
    """Rules of one kind that differ only in their settings (`rule_stack_key`), evaluated as one:
    each rule's choices, then the stalled rounds and the heads' distributions once for all. A rule
    alone is a stack of one; a scorer of a rule grid's members (the partner population's) stacks
    them."""

    def __init__(self, policies: list[RulePolicy]) -> None:
        if len({rule_stack_key(p) for p in policies}) != 1 or rule_stack_key(policies[0]) is None:
            raise ValueError(f"policies {[p.key for p in policies]} do not stack")
        self.policies = policies

    def rules(self, observations: np.ndarray, ending: Ending | None = None) -> np.ndarray:
        """(policies, rows, 3): each rule() of every row (`ending`: end_round_batch of these rows, where
        the caller has it)."""
        first = self.policies[0]
        choices = np.stack([p.choose_batch(observations) for p in self.policies])
        if first.ends_stalled_rounds:
            mask, end = ending or end_round_batch(observations, first.view)
            choices[:, mask] = end[mask]
        return choices

    def __call__(self, observations: np.ndarray, ending: Ending | None = None) -> np.ndarray:
        """(policies, rows, 12): each probs() of every row."""
        choices = self.rules(observations, ending)
        return rule_probs(choices.reshape(-1, 3), self.policies[0].epsilon).reshape(*choices.shape[:2], -1)


def rule_stack_key(policy: object) -> tuple | None:
    """What rules must share to be evaluated as one `RuleStack`; None for any other policy."""
    if not isinstance(policy, RulePolicy):
        return None
    return (type(policy), policy.role, policy.view, policy.epsilon, policy.ends_stalled_rounds)


class UniformPolicy:
    """Every action equally likely: the random baseline."""

    view = "world"

    def __init__(self, role: str, key: str = "random") -> None:
        self.role, self.key = role, key
        self.rng = random.Random(0)

    def reset(self, seed: int | None = None) -> None:
        self.rng = random.Random(seed)

    def act(self, obs: np.ndarray) -> int:
        return self.rng.randrange(N_ACTIONS)

    def probs(self, obs: np.ndarray) -> np.ndarray:
        return np.full(N_ACTIONS, 1.0 / N_ACTIONS)

    def probs_batch(self, observations: np.ndarray) -> np.ndarray:
        return np.full((len(observations), N_ACTIONS), 1.0 / N_ACTIONS)


@jitable
def turn_toward(heading_cos: float, heading_sin: float, angle: float, deadband: float = 3.0) -> int:
    """Turn choice (0 none, 1 left, 2 right) that brings the heading toward `angle` (radians)."""
    heading = math.atan2(heading_sin, heading_cos)
    error = math.degrees((angle - heading + math.pi) % (2 * math.pi) - math.pi)
    if error > deadband:
        return 1
    if error < -deadband:
        return 2
    return 0


@jitable
def ship(obs: np.ndarray, block: int) -> tuple[float, float, float, float]:
    """Position (px) and velocity (px/frame) of the ship block starting at `block`."""
    p, v = ob.POSITION_SCALE, ob.VELOCITY_SCALE
    return (
        float(obs[block + ob.X]) * p,
        float(obs[block + ob.Y]) * p,
        float(obs[block + ob.VX]) * v,
        float(obs[block + ob.VY]) * v,
    )


@jitable
def seek(obs: np.ndarray, dvx: float, dvy: float, tolerance: float = 0.3) -> tuple[bool, int, int]:
    """(needed, turn, thrust): the turn and thrust that bring the own velocity toward (dvx, dvy);
    not needed when it is already there."""
    _, _, vx, vy = ship(obs, ob.SELF)
    ex, ey = dvx - vx, dvy - vy
    if math.hypot(ex, ey) < tolerance:
        return False, 0, 0
    cos_h, sin_h = float(obs[ob.SELF + ob.COS]), float(obs[ob.SELF + ob.SIN])
    want = math.atan2(ey, ex)
    turn = turn_toward(cos_h, sin_h, want)
    aligned = cos_h * math.cos(want) + sin_h * math.sin(want) > math.cos(math.radians(40))
    return True, turn, int(aligned)


# --- stalled rounds --------------------------------------------------------------------------------
# A dead ship stays dead until the fortress is destroyed or both ships are dead (docs/rules.md), and a
# lone ship can hardly kill: the fortress faces the only ship it can lock, so its rear opens away from
# it. With the partner dead the round in practice ends only by this ship's death, so every agent seat
# ends it at once (docs/library.md, "Stalled rounds").

DIVE_SPEED = 8.0  # px/frame: the speed cap
FEW_ROWS = 16  # end_round_batch: rows checked in Python rather than by the compiled loop
# The default rules' border and shield (px), as plain numbers for the compiled loops.
ARENA_X, ARENA_Y, SHIELD_RADIUS = GameConfig().arena_x, GameConfig().arena_y, GameConfig().shield_radius


@jitable
def stalled(obs: np.ndarray) -> bool:
    """Whether the round is stalled for this ship: it lives, its partner is dead and the fortress is
    up, and no missile in flight can still kill (none, or the shield is shut). Either view."""
    if (
        obs[ob.SELF + ob.ALIVE] < 0.5
        or obs[ob.PARTNER + ob.ALIVE] > 0.5
        or obs[ob.FORTRESS + ob.F_ALIVE] < 0.5
    ):
        return False
    if obs[ob.FORTRESS + ob.F_VULNERABLE] > 0.0:
        for i in range(ob.N_MISSILES):
            if obs[ob.MISSILES + i * ob.PROJECTILE_SIZE + ob.PROJECTILE_SIZE - 1] > 0.5:
                return False
    return True


@jitable
def end_round_choice(obs: np.ndarray, world: bool) -> tuple[int, int, int]:
    """The quickest end of a stalled round, never firing: at full speed into the shield, or, in the
    world view (where the border's direction is known), into the border when it is nearer than the
    shield (measured in docs/library.md)."""
    x, y, _, _ = ship(obs, ob.SELF)
    r = math.hypot(x, y)
    r = r if r != 0.0 else 1.0
    dx, dy, gap = -x / r, -y / r, r - SHIELD_RADIUS
    if world:
        for wall, wx, wy in (
            (ARENA_X - x, 1.0, 0.0),
            (ARENA_X + x, -1.0, 0.0),
            (ARENA_Y - y, 0.0, 1.0),
            (ARENA_Y + y, 0.0, -1.0),
        ):
            if wall < gap:
                dx, dy, gap = wx, wy, wall
    needed, turn, thrust = seek(obs, DIVE_SPEED * dx, DIVE_SPEED * dy)
    return (turn, thrust, 0) if needed else (0, 1, 0)


Ending = tuple[np.ndarray, np.ndarray]  # end_round_batch's (rows,) mask and (rows, 3) choices


def end_round_batch(observations: np.ndarray, view: str) -> Ending:
    """stalled() and end_round_choice() of every row of one view: a (rows,) mask and (rows, 3)
    choices (rows that are not stalled hold zeros)."""
    mask = np.zeros(len(observations), np.bool_)
    choices = np.zeros((len(observations), 3), np.int64)
    alone = (
        (observations[:, ob.SELF + ob.ALIVE] >= 0.5)
        & (observations[:, ob.PARTNER + ob.ALIVE] <= 0.5)
        & (observations[:, ob.FORTRESS + ob.F_ALIVE] >= 0.5)
    )  # stalled()'s first test, for every row at once: most frames end here
    rows = np.flatnonzero(alone)
    if len(rows) > FEW_ROWS:  # bulk play: the compiled loop
        some, chosen = mask[rows], choices[rows]
        _end_round_rows(observations[rows], view == "world", some, chosen)
        mask[rows], choices[rows] = some, chosen
    else:  # a live service's few rows: plain Python, which loads no numba (a second's stall at start)
        for i in rows:
            if stalled(observations[i]):
                mask[i] = True
                choices[i] = end_round_choice(observations[i], view == "world")
    return mask, choices


def end_stalled_rounds(
    observations: np.ndarray, view: str, probs: np.ndarray, epsilon: float, ending: Ending | None = None
) -> np.ndarray:
    """`probs` (rows, 12), or (policies, rows, 12) of policies that read the same rows, with every
    stalled row replaced by the end-round rule's distribution (`ending`: end_round_batch of these
    rows in this view, where the caller has it: a scorer's stacks read the same rows)."""
    mask, choices = ending or end_round_batch(observations, view)
    if mask.any():
        probs = probs.copy()
        probs[..., mask, :] = rule_probs(choices[mask], epsilon)
    return probs


@compiled
def _end_round_rows(observations, world, mask, choices):
    for i in range(observations.shape[0]):
        if stalled(observations[i]):
            mask[i] = True
            choices[i] = end_round_choice(observations[i], world)
