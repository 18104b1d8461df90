"""What plays a seat, as one value: `SeatSpec`, read from its name once (`parse`) and named back
(`str`), the two inverses; partners.build turns one into what plays.

    B5, S1, circle, random   a key: a library policy or a scripted one (services/agent/seats.py)
    circle(radius=150)       a scripted rule with other settings (any of its constructor's numbers)
    my_bait.zip              an SB3 model (services/agent/outside.py)
    package.module:attr      a plug-in: your own policy object, or a callable that returns one
    proxy:DIR                a proxy cloned from recorded people (services/proxy)
    humans:DIR@NAME          participant NAME's stand-in fitted by `tsf humans fit`
    human                    a person (no agent plays the seat; a gateway does)
    adaptive-T400-bayes-dwell-ood-guard   the adaptive agent, with every setting of its
                             AdapterConfig that is not the default: _initial-random, _warmup150,
                             _dwell20, _hazard0.01, _noise0.1 (AdapterConfig.name and .parse)
    noisy(X), delayed(X), sticky(X), switch(X,Y), human(X), human(X,Y)   wrappers (partners.py);
                             delayed(X,frames=N) and human(X,skill=...,input_ms=...,reaction_ms=...)
                             with settings (human_like.SETTINGS: the model's parameters too)

The adaptive agent's seat and seed come from where it plays (the seat it is given, the match's
seed), so its name carries the other seven settings. Old names read as before: every name a
recording, study config or result table holds parses to the same seat.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace

from services.agent.outside import BY_KEY, PLUGIN, PROXY_KIND, ZIP, policy_kind
from services.agent.scripted import SCRIPTED
from services.agent.seats import check_seat, policy_of
from services.population.adaptive import ADAPTIVE, AdapterConfig, setting_text
from services.population.wrappers import WRAPPERS
from shared.errors import UsageError
from shared.game import HUMAN

KEY = BY_KEY  # how a policy is found (KEY, ZIP, PLUGIN, PROXY_KIND) is outside.policy_kind's
HUMANS = "humans:"  # stand-ins fitted by `tsf humans fit`: humans:DIR@NAME (services/proxy/humans.py)
POLICIES = (KEY, ZIP, PLUGIN, PROXY_KIND)  # a policy by its key: services/agent/seats.policy_of
_CALL = re.compile(r"^(\w+)\((.*)\)$")


@dataclass(frozen=True)
class SeatSpec:
    """One seat's player, read from its name once (`parse`) and named back (`str`). What plays is
    its type: `PolicySeat` (a key, a .zip, a module:attr, a proxy:DIR), `RuleSeat` (a scripted
    rule with other settings), `FittedSeat` (humans:DIR@NAME), `PersonSeat`, `AdaptiveSeat` (the
    adaptive agent's whole config) and `WrapperSeat` (a wrapper's partners and settings)."""

    @classmethod
    def parse(cls, name: str, option: str = "--partner") -> SeatSpec:
        """The seat a name stands for; a UsageError about `option` for a name that is none."""
        name = name.strip()
        if name == HUMAN:
            return PersonSeat()
        if name.startswith(ADAPTIVE):
            return AdaptiveSeat(AdapterConfig.parse(name, option))
        call = _CALL.match(name)
        if call and call[1] in WRAPPERS:
            parts = arguments(call[2])
            settings = [part for part in parts if "=" in part and "(" not in part]
            parts = [part for part in parts if part not in settings]
            if len(parts) not in WRAPPERS[call[1]].partners:
                counts = " or ".join(("one", "two")[n - 1] for n in WRAPPERS[call[1]].partners)
                raise UsageError(option, name, f"{call[1]}(...) needs {counts} partners, not {len(parts)}")
            named = tuple(tuple(part.strip() for part in s.partition("=")[::2]) for s in settings)
            if named and not WRAPPERS[call[1]].settings:
                raise UsageError(option, name, f"{call[1]}(...) takes no settings")
            return WrapperSeat(call[1], tuple(cls.parse(part, option) for part in parts), named)
        if call and call[1] in SCRIPTED:
            return RuleSeat(call[1], rule_settings(name, call[1], call[2], option))
        if name.startswith(HUMANS):
            return FittedSeat(name)
        if not name:
            raise UsageError(option, name, "no seat named")
        return PolicySeat(name, policy_kind(name))

    @staticmethod
    def adaptive_agent(config: AdapterConfig) -> AdaptiveSeat:
        """The seat of the adaptive agent `config`, whole (its role and seed come from where it plays)."""
        return AdaptiveSeat(config)

    def adaptive(self, role: str, seed: int = 0) -> AdapterConfig | None:
        """The adaptive agent it names, in `role`'s seat of a game of `seed`; None for any other."""
        return None

    def walk(self) -> Iterator[SeatSpec]:
        """This spec and every spec inside it."""
        yield self

    @property
    def plugins(self) -> tuple[str, ...]:
        """The `module:attr` plug-ins it names, inside wrappers too: what a worker must import."""
        found = (s.key for s in self.walk() if isinstance(s, PolicySeat) and s.how == PLUGIN)
        return tuple(dict.fromkeys(found))


@dataclass(frozen=True)
class PolicySeat(SeatSpec):
    """A policy by its key; `how` is where the key is found (outside.policy_kind: a library or
    scripted key, a .zip, a module:attr, a proxy:DIR)."""

    key: str
    how: str = KEY

    def __str__(self) -> str:
        return self.key


@dataclass(frozen=True)
class RuleSeat(SeatSpec):
    """A scripted rule with other settings than its own (any of its constructor's numbers)."""

    key: str
    settings: tuple[tuple[str, float], ...] = ()

    def __str__(self) -> str:
        return f"{self.key}({','.join(f'{s}={setting_text(v)}' for s, v in self.settings)})"


@dataclass(frozen=True)
class FittedSeat(SeatSpec):
    """Participant NAME's stand-in fitted by `tsf humans fit`: humans:DIR@NAME."""

    key: str

    def __str__(self) -> str:
        return self.key


@dataclass(frozen=True)
class PersonSeat(SeatSpec):
    """A person: no agent plays the seat, a gateway does."""

    def __str__(self) -> str:
        return HUMAN


@dataclass(frozen=True)
class AdaptiveSeat(SeatSpec):
    """The adaptive agent, with its whole AdapterConfig (its seat and seed come from where it plays)."""

    adapter: AdapterConfig

    def __str__(self) -> str:
        return self.adapter.name

    def adaptive(self, role: str, seed: int = 0) -> AdapterConfig:
        return replace(self.adapter, role=role, seed=seed)


@dataclass(frozen=True)
class WrapperSeat(SeatSpec):
    """A wrapper (WRAPPERS) of one or two partners, with its settings as written."""

    wrapper: str
    inner: tuple[SeatSpec, ...]
    settings: tuple[tuple[str, str], ...] = ()

    def __str__(self) -> str:
        settings = (f"{setting}={value}" for setting, value in self.settings)
        return f"{self.wrapper}({','.join([*map(str, self.inner), *settings])})"

    def walk(self) -> Iterator[SeatSpec]:
        yield self
        for spec in self.inner:
            yield from spec.walk()


def seats_of(names: Iterable[str], option: str = "--partner") -> tuple[SeatSpec, ...]:
    """Each name's seat, in order (a team's, read from a job's or a table's names)."""
    return tuple(SeatSpec.parse(name, option) for name in names)


def plugins_in(names: Iterable[str]) -> tuple[str, ...]:
    """The `module:attr` plug-ins among partner or policy names (inside wrappers too:
    noisy(my_lab.partners:Alice)); a proxy (`proxy:DIR`) or fitted stand-ins (`humans:DIR@NAME`)
    are a directory, not a plug-in."""
    return tuple(dict.fromkeys(plugin for name in names for plugin in SeatSpec.parse(name).plugins))


def check_live(spec: SeatSpec, role: str, option: str) -> SeatSpec:
    """`spec`, refused (UsageError) where nothing can play it live in `role`'s seat: a person, or a
    policy by key (library, scripted, .zip, plug-in, proxy; loaded to see which seat it plays).
    Partners made of policies (wrappers, rules with other settings) play in bulk only, and the
    adaptive agent takes its seat through the adapter (MatchPlan)."""
    if isinstance(spec, PolicySeat) and spec.how == KEY:
        check_seat(spec.key, role, option)
    elif isinstance(spec, PolicySeat):
        policy_of(spec.how, spec.key, role, option)  # loaded to see which seat it plays
    elif not isinstance(spec, PersonSeat):
        raise UsageError(option, str(spec), "plays in bulk evaluations only, not in a live match")
    return spec


def arguments(text: str) -> list[str]:
    """The top-level, comma-separated arguments of a wrapper, which may nest."""
    depth, start, out = 0, 0, []
    for i, char in enumerate(text):
        depth += {"(": 1, ")": -1}.get(char, 0)
        if char == "," and depth == 0:
            out.append(text[start:i].strip())
            start = i + 1
    return [*out, text[start:].strip()]


def rule_settings(name: str, rule: str, text: str, option: str) -> tuple[tuple[str, float], ...]:
    """A scripted rule's `setting=number, ...`, each a number its constructor takes."""
    settings = [s for s in inspect.signature(SCRIPTED[rule]).parameters if s not in ("epsilon", "config")]
    values = []
    for item in filter(None, (a.strip() for a in text.split(","))):
        setting, _, value = (part.strip() for part in item.partition("="))
        try:
            if setting not in settings:
                raise ValueError(setting)
            values.append((setting, float(value)))
        except ValueError:
            problem = f"{item!r} is not SETTING=NUMBER for a setting of {rule}"
            raise UsageError(option, name, problem, settings) from None
    return tuple(values)
