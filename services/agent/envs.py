"""The envs under the names researchers look for: a Gymnasium id and PettingZoo's factories.

    gymnasium.make("tsf/Role-v0", role="bait", partner="S5")       one seat against a partner
    gymnasium.make_vec("tsf/Role-v0", num_envs=256, role="bait")   that seat in 256 games at once
    env(), raw_env(), parallel_env()                               both seats (PettingZoo)

A partner is anything a seat can play (a library or scripted key, an SB3 `.zip`, a `module:attr`;
services/agent/seats.py `policy_for`) or a policy object; the batched form also takes a list
(each game draws one). Importing this module registers the id (`from services.agent import envs`,
or `gymnasium.make("services.agent.envs:tsf/Role-v0")`), and pyproject.toml names `register`
under the `gymnasium.envs` entry point for tools that load plugins. Entry points are strings, so
registering imports nothing but gymnasium; the rest of `services` never imports this module, so
no live service loads gymnasium.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from shared.game import ROLES, check_role

if TYPE_CHECKING:
    from pettingzoo import AECEnv

    from services.sim.env import RoleEnv, TSFParallelEnv
    from services.sim.vec_env import RoleVectorEnv
    from shared.game import Policy

ENV_ID = "tsf/Role-v0"


def register() -> None:
    """Register `tsf/Role-v0` with Gymnasium (once; registering again changes nothing)."""
    from gymnasium.envs.registration import register as add
    from gymnasium.envs.registration import registry

    if ENV_ID not in registry:
        here = "services.agent.envs"
        add(ENV_ID, entry_point=f"{here}:role_env", vector_entry_point=f"{here}:role_vector_env")


def _partner(partner: Any, role: str) -> Policy:
    from services.agent.library import DEFAULT_PARTNER
    from services.agent.seats import policy_for

    check_role(role)
    other = ROLES[1 - ROLES.index(role)]
    if partner is None:
        partner = DEFAULT_PARTNER[role]
    return policy_for(partner, other, "partner") if isinstance(partner, str) else partner


def role_env(role: str = "bait", partner: Any = None, **options: Any) -> RoleEnv:
    """One seat against a partner (`options`: RoleEnv's config, view, reward, render_mode)."""
    from services.sim.env import RoleEnv

    return RoleEnv(role, _partner(partner, role), **options)


def role_vector_env(
    num_envs: int = 1, role: str = "bait", partner: Any = None, **options: Any
) -> RoleVectorEnv:
    """`num_envs` games of one seat on the batched engine (RoleVectorEnv; `options`: its config, view,
    reward); `partner` may be a list, a pool each game draws its partner from."""
    from services.sim.vec_env import RoleVectorEnv

    pool = partner if isinstance(partner, list | tuple) else [partner]
    return RoleVectorEnv(num_envs, role, [_partner(p, role) for p in pool], **options)


def parallel_env(**options: Any) -> TSFParallelEnv:
    """Both seats, stepped together (`options`: TSFParallelEnv's config, view, render_mode)."""
    from services.sim.env import TSFParallelEnv

    return TSFParallelEnv(**options)


def raw_env(**options: Any) -> AECEnv:
    """Both seats taking turns: the parallel env through PettingZoo's conversion."""
    from pettingzoo.utils.conversions import parallel_to_aec_wrapper

    return parallel_to_aec_wrapper(parallel_env(**options))


def env(**options: Any) -> AECEnv:
    """raw_env() with PettingZoo's usual guards: actions in bounds, calls in order."""
    from pettingzoo.utils.wrappers import AssertOutOfBoundsWrapper, OrderEnforcingWrapper

    return OrderEnforcingWrapper(AssertOutOfBoundsWrapper(raw_env(**options)))


register()
