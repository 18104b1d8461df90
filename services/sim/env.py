"""The game behind the standard RL interfaces: PettingZoo for both seats, Gymnasium for one seat.

`TSFParallelEnv` lets a learner (or two) drive both ships; `RoleEnv` trains one role against a
fixed partner policy. TSF is cooperative, so every reward is the team's change in points by
default. A game has no terminal state, only a time limit: episodes end by truncation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from services.sim.engine import Event, Game
from services.sim.observation import POSITION_SCALE, VELOCITY_SCALE, VIEWS, observe
from services.sim.play import policy_seed
from services.sim.render import render
from shared.game import FPS, N_ACTIONS, OBS_SIZE, ROLES, GameConfig, Policy, bait_first, check_role

Reward = Callable[[Game, str, list[Event]], float]
RENDER_MODES = ("rgb_array",)


def observation_space(config: GameConfig) -> spaces.Box:
    """A box that provably holds every observation of games under `config`: the farthest position
    is a ship that died one frame of travel past an arena corner (or a missile just launched from
    a ship's nose), the fastest velocity that of a missile, shell or ship; flags and angles are
    within [-1, 1]."""
    margin = config.ship_max_speed + config.ship_radius
    reach = math.hypot(config.arena_x + margin, config.arena_y + margin) / POSITION_SCALE
    speed = max(config.ship_max_speed, config.missile_speed, config.shell_speed) / VELOCITY_SCALE
    bound = math.ceil(max(reach, speed, 1.0))
    return spaces.Box(-bound, bound, (OBS_SIZE,), np.float32)


def _game_seed(rng: np.random.Generator, seed: int | None) -> int:
    """The seed of the next game: the one asked for, else a draw from the env's generator, which a
    seeded reset seeds, so that the unseeded resets after it replay exactly."""
    return int(seed) if seed is not None else int(rng.integers(2**31 - 1))


def _info(game: Game, events: list[Event]) -> dict[str, Any]:
    return {"events": [event._asdict() for event in events], "state_hash": game.state_hash()}


def _check_modes(view: str, render_mode: str | None) -> None:
    if view not in VIEWS:
        raise ValueError(f"unknown observation view {view!r}; expected one of {VIEWS}")
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"unknown render mode {render_mode!r}; expected one of {RENDER_MODES}")


class TSFParallelEnv(ParallelEnv):
    """Both ships, stepped together; each agent observes in the env's frame and gets the team reward."""

    metadata = {
        "name": "tsf_v0",
        "render_modes": list(RENDER_MODES),
        "render_fps": FPS,
        "is_parallelizable": True,
    }

    def __init__(
        self, config: GameConfig | None = None, view: str = "world", render_mode: str | None = None
    ) -> None:
        _check_modes(view, render_mode)
        self.config = config or GameConfig()
        self.view = view
        self.render_mode = render_mode
        self.possible_agents = list(ROLES)
        self.agents: list[str] = []
        self.observation_spaces = {role: observation_space(self.config) for role in ROLES}
        self.action_spaces = {role: spaces.Discrete(N_ACTIONS) for role in ROLES}
        self.np_random, _ = seeding.np_random()
        self.game: Game | None = None

    def observation_space(self, agent: str) -> spaces.Box:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Discrete:
        return self.action_spaces[agent]

    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        if seed is not None:
            self.np_random, _ = seeding.np_random(seed)
        self.game = Game(self.config, _game_seed(self.np_random, seed))
        self.agents = list(ROLES)
        return self._observations(), {role: _info(self.game, []) for role in ROLES}

    def step(self, actions: dict[str, int]) -> tuple[dict, dict, dict, dict, dict]:
        game = self.game
        before = game.points
        events = game.step(actions["bait"], actions["shooter"])
        reward = float(game.points - before)
        observations = self._observations()
        rewards = dict.fromkeys(ROLES, reward)
        terminations = dict.fromkeys(ROLES, False)
        truncations = dict.fromkeys(ROLES, game.done)
        infos = {role: _info(game, events) for role in ROLES}
        if game.done:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def render(self) -> np.ndarray | None:
        return render(self.game) if self.render_mode == "rgb_array" else None

    def _observations(self) -> dict[str, np.ndarray]:
        return {role: observe(self.game, role, self.view) for role in ROLES}


class RoleEnv(gymnasium.Env):
    """One role's seat; the partner policy plays the other seat, reading its own observation view,
    and is reset at each reset with the seed play() would give it."""

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": FPS}

    def __init__(
        self,
        role: str,
        partner: Policy,
        config: GameConfig | None = None,
        view: str = "world",
        reward: Reward | None = None,
        render_mode: str | None = None,
    ) -> None:
        check_role(role)
        if partner.role == role:
            raise ValueError(f"the partner policy {partner.key!r} plays {role}, the seat being trained")
        _check_modes(view, render_mode)
        self.role, self.partner = role, partner
        self.config = config or GameConfig()
        self.view = view
        self.reward = reward
        self.render_mode = render_mode
        self.observation_space = observation_space(self.config)
        self.action_space = spaces.Discrete(N_ACTIONS)
        self.game: Game | None = None

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.game = Game(self.config, _game_seed(self.np_random, seed))
        self.partner.reset(policy_seed(self.game.seed, self.partner.role))
        return observe(self.game, self.role, self.view), _info(self.game, [])

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        if isinstance(action, np.ndarray) and action.shape == () and action.dtype.kind in "iu":
            action = action.item()  # what SB3's `model.predict` returns for one Discrete action
        game = self.game
        before = game.points
        partner_action = self.partner.act(observe(game, self.partner.role, self.partner.view))
        actions = bait_first(self.role, action, partner_action)
        events = game.step(*actions)
        if self.reward is None:
            reward = float(game.points - before)
        else:
            reward = float(self.reward(game, self.role, events))
        return observe(game, self.role, self.view), reward, False, game.done, _info(game, events)

    def render(self) -> np.ndarray | None:
        return render(self.game) if self.render_mode == "rgb_array" else None
