"""Policies from outside the library, playing any seat a library key can.

    my_bait.zip            a model trained with Stable-Baselines3 on the 64-value observation and
                           the 12 actions (gymnasium.make("tsf/Role-v0"), services/agent/envs.py)
    package.module:attr    an object with the policy protocol's key, role, view, reset(seed) and
                           act(obs) (and probs(obs) where the adapter scores it), or a callable
                           that returns a new one
    proxy:DIR              a proxy cloned from recorded people by `tsf proxy train` (services/proxy)

`policy_kind` is the one place a policy key is classified: seats.policy_for reads a key with it,
and SeatSpec.parse (services/population/seat.py) the policies inside a seat's name, keeping the kind,
so a spec is loaded (`load`) without being classified again.

A `.zip` is read with SB3 (the `train` extra) and played as numpy arrays (networks.JointPolicy): the
network's distribution over the 12 actions with networks.FLOOR mixed in is what `probs` reports and
what `act` draws from, so the adapter's likelihoods are exact. It reads the observation view it
was trained on ("world", RoleEnv's default, unless told). `services/agent/add.py` writes one into
a library directory of your own (weights, registry and manifest entries); TSF_LIBRARY then makes
its key a library key.
"""

from __future__ import annotations

import importlib
import json
import re
import zipfile
from pathlib import Path

import numpy as np

from services.agent import proxy
from services.agent.library import PROXY_FAMILY
from services.agent.networks import JointPolicy, Network, read_arrays
from services.agent.proxy import PROXY
from services.sim.observation import VIEWS
from shared.errors import UsageError, missing_extra
from shared.game import N_ACTIONS, OBS_SIZE, ROLES, Policy
from shared.messages import POLICY_NAME

ACTIVATIONS = {"Tanh": "tanh", "ReLU": "relu"}  # torch module name: networks.Network's name
KEY = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")
NAME = re.compile(POLICY_NAME)
BY_KEY, ZIP, PLUGIN, PROXY_KIND = "key", "zip", "plugin", "proxy"  # what a policy key names (policy_kind)


def policy_kind(key: str) -> str:
    """What a policy key names: an SB3 `.zip` (ZIP), a `proxy:DIR` (PROXY_KIND), a `module:attr`
    (PLUGIN), else a library or scripted key (BY_KEY)."""
    if key.endswith(".zip"):
        return ZIP
    if key.startswith(PROXY):
        return PROXY_KIND
    return PLUGIN if ":" in key else BY_KEY


def record_name(key: str) -> str:
    """How a policy key is named in messages and recordings, which take 1-64 of [A-Za-z0-9_.:-]: a
    library or scripted key as it is, a `.zip` by its file name, a `proxy:DIR` by its directory's
    name, a `module:attr` as it is where it fits, else by its attr."""
    kind = policy_kind(key)
    if kind == BY_KEY or NAME.fullmatch(key):
        return key
    if kind == PROXY_KIND:
        name = PROXY + Path(key.removeprefix(PROXY)).name
    else:
        name = Path(key).name if kind == ZIP else key.rpartition(":")[2]
    return re.sub(r"[^A-Za-z0-9_.:-]", "_", name)[-32:] or "outside"


def load(kind: str, key: str, role: str, option: str = "--policy", view: str = "world") -> Policy:
    """The policy from outside that `key` names, of its `kind` (policy_kind: ZIP, PROXY_KIND or
    PLUGIN), checked to play `role` (UsageError if not); a `.zip` plays whichever seat it is given."""
    if kind == ZIP:
        return zip_policy(Path(key), role, view, option)
    if kind == PROXY_KIND:
        return proxy.load(Path(key.removeprefix(PROXY)), role, record_name(key), option)
    policy = _object(key, option)
    if policy.role != role:
        raise UsageError(option, key, f"plays {policy.role}, not {role}", [role])
    return policy


def _object(path: str, option: str) -> Policy:
    module, _, attr = path.partition(":")
    try:
        found = getattr(importlib.import_module(module), attr)
    except Exception as error:  # noqa: BLE001 - a module of the user's may fail as it likes on import
        raise UsageError(option, path, f"cannot be imported ({type(error).__name__}: {error})") from None
    policy = found() if isinstance(found, type) or not _is_policy(found) else found
    if not _is_policy(policy):
        raise UsageError(option, path, "is not a policy (key, role, view, reset, act)")
    if not NAME.fullmatch(str(policy.key)):
        raise UsageError(option, path, f"its key {policy.key!r} is not 1-64 of letters, digits, _ . : -")
    return policy


def _is_policy(thing: object) -> bool:
    return all(hasattr(thing, name) for name in ("key", "role", "view", "reset", "act"))


def network_arrays(path: Path, meta: dict, option: str = "MODEL") -> dict[str, np.ndarray]:
    """An SB3 actor-critic model's policy network as networks.Network arrays, with `meta` plus its
    activation and policy class. Refused (UsageError) unless it maps the 64-value observation to the
    12 actions through a feed-forward network."""
    try:
        from stable_baselines3.common.policies import ActorCriticPolicy
        from stable_baselines3.common.save_util import load_from_zip_file
    except ModuleNotFoundError as error:
        raise UsageError(option, path, f"reading a model {missing_extra(error) or error}") from None
    if not path.is_file():
        raise UsageError(option, path, "no such file")
    try:
        data, params, _ = load_from_zip_file(path, device="cpu", print_system_info=False)
    except (zipfile.BadZipFile, ValueError, KeyError, OSError, RuntimeError) as error:
        raise UsageError(option, path, f"not a Stable-Baselines3 model ({error})") from None
    if not data or "policy_class" not in data or "policy" not in (params or {}):
        raise UsageError(option, path, "not a Stable-Baselines3 model")
    obs, actions, cls = data["observation_space"], data["action_space"], data["policy_class"]
    if getattr(obs, "shape", None) != (OBS_SIZE,) or getattr(actions, "n", None) != N_ACTIONS:
        raise UsageError(
            option, path, f"maps {obs} to {actions}, not {OBS_SIZE} values to {N_ACTIONS} actions"
        )
    if not (isinstance(cls, type) and issubclass(cls, ActorCriticPolicy)) or "lstm" in cls.__name__.lower():
        raise UsageError(option, path, f"{getattr(cls, '__name__', cls)}: not a feed-forward actor-critic")
    policy = cls(obs, actions, lambda _: 0.0, **data.get("policy_kwargs", {}))
    policy.load_state_dict(params["policy"])
    activation = ACTIVATIONS.get(policy.activation_fn.__name__)
    if activation is None:
        raise UsageError(option, path, f"activation {policy.activation_fn.__name__}", ACTIVATIONS)
    meta = meta | {"activation": activation, "policy_class": cls.__name__}
    return linear_arrays([*policy.mlp_extractor.policy_net, policy.action_net], meta)


def proxy_arrays(directory: Path, key: str, role: str) -> tuple[dict[str, np.ndarray], str, str]:
    """A proxy's arrays for a library (with `key` and its policy class in the metadata), its family
    and view; refused (UsageError) unless it is a proxy of `role`."""
    proxy.manifest(directory, "MODEL")
    arrays = read_arrays(directory / proxy.WEIGHTS)
    meta = json.loads(bytes(arrays["meta"]).decode())
    if meta["role"] != role:
        raise UsageError("MODEL", directory, f"is a proxy of the {meta['role']} seat, not the {role}", [role])
    if meta.get("history"):
        raise UsageError(
            "MODEL",
            directory,
            "reads its own last actions (--history), which the adapter cannot score; "
            "train one without --history for a library",
        )
    meta |= {"key": key, "policy_class": "proxy"}
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    return arrays, PROXY_FAMILY, meta["view"]


def zip_policy(path: Path, role: str, view: str = "world", option: str = "--policy") -> JointPolicy:
    """An SB3 `.zip` as a numpy policy of `role` reading the `view` observation."""
    check_view(role, view)
    arrays = network_arrays(path, {}, option)
    meta = json.loads(bytes(arrays.pop("meta")).decode())
    return JointPolicy(record_name(str(path)), role, view, Network(arrays, meta["activation"]))


def check_view(role: str, view: str) -> None:
    """Refuse (UsageError) a seat or an observation view that is not one."""
    if role not in ROLES:
        raise UsageError("--role", role, "not a seat", ROLES)
    if view not in VIEWS:
        raise UsageError("--view", view, "not an observation view", VIEWS)


def linear_arrays(layers: list, meta: dict) -> dict[str, np.ndarray]:
    """The linear layers among `layers` as arrays w0, b0, ... plus `meta` as JSON (networks.Network);
    torch modules: the `train` extra, loaded by the caller."""
    import torch as th  # the `train` extra

    linear = [m for m in layers if isinstance(m, th.nn.Linear)]
    arrays = {}
    for i, m in enumerate(linear):
        arrays[f"w{i}"] = m.weight.detach().cpu().numpy().astype(np.float32)
        arrays[f"b{i}"] = m.bias.detach().cpu().numpy().astype(np.float32)
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    return arrays
