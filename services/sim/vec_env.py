"""One role's seat in many games at once: a Gymnasium `VectorEnv` over the batched engine.

The learner plays `role` in every lane; the partner seat is played by one policy, or by a pool
(each game draws its partner from its own seed). A pool may hold stateful partners in their
batched form (`LanePartner`, e.g. a human-like stand-in's, population/partners.py): such a
partner plays every lane every frame, so that its per-lane state runs on, and a lane's game uses
its action when it drew that partner; a restarted lane restarts it there. Policies answer in
batch (`probs_batch`) and their actions are drawn with `lane_uniforms`, so a lane's game depends
on its seed only. Games end
by truncation after `config.frames`. With `end_on_death`, a game also ends when a ship dies: a
dead ship stays dead until its round ends, so the rest of such a game is often time in which the
learner has no control or no partner. The learner's death terminates its game, the partner's
truncates it (the learner is not to blame). Either way the lane restarts at once with a fresh
seed (Gymnasium's same-step autoreset: the finished game's last observation is in
`infos["final_obs"]`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from services.sim.batch import BatchGame
from services.sim.env import observation_space
from services.sim.observation import observe
from services.sim.sampling import batch_act, lane_uniforms
from shared.game import N_ACTIONS, ROLES, GameConfig, Policy

# A batched reward: (batch, the learner's seat, points before the frame) -> (lanes,) rewards.
BatchReward = Callable[[BatchGame, int, np.ndarray], np.ndarray]
PARTNER_DRAW = 2  # lane_uniforms stream that picks a game's partner from a pool


class LanePartner(Protocol):
    """A stateful partner in every lane at once: reset with the lanes' game seeds, restarted lane by
    lane, one action per lane per frame."""

    key: str
    role: str
    view: str

    def reset(self, keys: np.ndarray) -> None: ...

    def restart(self, lanes: np.ndarray, keys: np.ndarray) -> None: ...

    def act(self, obs: np.ndarray, frame: np.ndarray) -> np.ndarray: ...  # frame: each lane's


def team_points(batch: BatchGame, seat: int, before: np.ndarray) -> np.ndarray:
    """The default reward: the team's change in points, as RoleEnv's."""
    return (batch.state.points - before).astype(np.float64)


class RoleVectorEnv(VectorEnv):
    """`num_envs` games of `role` against `partners`; actions are (num_envs,) ints 0..11."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int,
        role: str,
        partners: Policy | list[Policy | LanePartner],
        config: GameConfig | None = None,
        view: str = "world",
        reward: BatchReward = team_points,
        end_on_death: bool = False,
    ) -> None:
        if role not in ROLES:
            raise ValueError(f"unknown role {role!r}; expected one of {ROLES}")
        self.partners = partners if isinstance(partners, list) else [partners]
        for partner in self.partners:
            if partner.role == role:
                raise ValueError(f"the partner policy {partner.key!r} plays {role}, the seat being trained")
        self.num_envs, self.role, self.seat = num_envs, role, ROLES.index(role)
        self.config = config or GameConfig()
        self.view, self.reward, self.end_on_death = view, reward, end_on_death
        self.single_observation_space = observation_space(self.config)
        self.single_action_space = spaces.Discrete(N_ACTIONS)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.batch: BatchGame | None = None
        self.partner_of = np.zeros(num_envs, np.int64)  # each lane's index into partners

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.batch = BatchGame(self.num_envs, self.config, self._seeds(self.num_envs))
        self._draw_partners(np.arange(self.num_envs))
        for partner in self._stateful():
            partner.reset(self.batch.seeds)
        return observe(self.batch, self.role, self.view), {}

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        batch = self.batch
        mine = np.asarray(actions)
        theirs = self.partner_actions()
        before = batch.state.points.copy()
        batch.step(*((mine, theirs) if self.seat == 0 else (theirs, mine)))
        rewards = self.reward(batch, self.seat, before)
        truncated = batch.done.copy()
        terminated = np.zeros(self.num_envs, np.bool_)
        if self.end_on_death:
            terminated = batch.event_counts("death", self.seat) > 0
            truncated = (truncated | (batch.event_counts("death", 1 - self.seat) > 0)) & ~terminated
        obs = observe(batch, self.role, self.view)
        infos: dict = {}
        ended = truncated | terminated
        if ended.any():
            lanes = np.flatnonzero(ended)
            infos = {"final_obs": obs.copy(), "_final_obs": ended}
            batch.reset(lanes, self._seeds(len(lanes)))
            self._draw_partners(lanes)
            for partner in self._stateful():
                partner.restart(lanes, batch.seeds[lanes])
            obs = observe(batch, self.role, self.view)
        return obs, rewards, terminated, truncated, infos

    def partner_actions(self) -> np.ndarray:
        """Every lane's partner action for the current frame."""
        batch, seat = self.batch, 1 - self.seat
        uniforms = lane_uniforms(batch.seeds, seat, batch.state.frame)
        actions = np.empty(self.num_envs, np.int64)
        views: dict[str, np.ndarray] = {}
        for index, partner in enumerate(self.partners):
            lanes = np.flatnonzero(self.partner_of == index)
            stateful = hasattr(partner, "restart")
            if (lanes.size or stateful) and partner.view not in views:
                views[partner.view] = observe(batch, ROLES[seat], partner.view)
            if stateful:  # every lane, every frame: its per-lane state runs on
                actions[lanes] = partner.act(views[partner.view], batch.state.frame)[lanes]
            elif lanes.size:
                actions[lanes] = batch_act(partner, views[partner.view][lanes], uniforms[lanes])
        return actions

    def _stateful(self) -> list[LanePartner]:
        return [p for p in self.partners if hasattr(p, "restart")]

    def _seeds(self, n: int) -> np.ndarray:
        return self.np_random.integers(2**31 - 1, size=n)

    def _draw_partners(self, lanes: np.ndarray) -> None:
        u = lane_uniforms(self.batch.seeds[lanes], PARTNER_DRAW, 0)
        self.partner_of[lanes] = (u * len(self.partners)).astype(np.int64)
