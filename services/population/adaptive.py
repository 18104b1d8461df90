"""The adaptive agent as a value: `AdapterConfig`, its settings, its name and the name read back.

Every launcher, study variant, command line, seat and report names the adaptive agent through this
value, so it sits below them all and reads no file; what it builds (the adapter core, from the
table, the out-of-library calibration and the skill model) is the adapter's
(services/adapter/core.py: `build`, `build_lanes`, `initial_policy`, `threshold`, `skill_model`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, fields
from typing import Any

from shared.errors import UsageError
from shared.game import FRAMES, ROLES, SEEDS, Range, other
from shared.messages import STRATEGY_NAME


@dataclass(frozen=True)
class Strategy:
    """What an adaptive strategy does, explicitly (its name lists the parts, in this order): how it
    estimates the partner (`cem`: the best window mean; `bayes`: a filter over partner types) and
    which parts it adds: `dwell` (a new choice must hold), `ood` (out of library: fall back to the
    best average), `guard` (fall back when the choice does worse than expected), `memory` (carry on
    across a session's trials) and `skill` (a skill model of the partner's keys)."""

    name: str
    rule: str  # "cem" or "bayes"
    dwell: bool = False
    ood: bool = False
    guard: bool = False
    memory: bool = False
    skill: bool = False

    def __post_init__(self) -> None:
        parts = [self.rule, *(p for p in ("dwell", "ood", "guard", "memory", "skill") if getattr(self, p))]
        if self.name != "-".join(parts) or not STRATEGY_NAME.fullmatch(self.name):
            raise ValueError(f"strategy {self.name!r}: its name must be its parts, {STRATEGY_NAME.pattern}")

    @property
    def bayes(self) -> bool:
        return self.rule == "bayes"


_GUARDED = {"dwell": True, "ood": True, "guard": True}
STRATEGY = {
    s.name: s
    for s in (
        Strategy("cem", "cem"),
        Strategy("cem-dwell", "cem", dwell=True),
        Strategy("cem-ood", "cem", ood=True),
        Strategy("bayes", "bayes"),
        Strategy("bayes-dwell-ood", "bayes", dwell=True, ood=True),
        Strategy("bayes-dwell-ood-guard", "bayes", **_GUARDED),
        Strategy("bayes-dwell-ood-guard-memory", "bayes", **_GUARDED, memory=True),
        Strategy("bayes-dwell-ood-guard-skill", "bayes", **_GUARDED, skill=True),
    )
}
STRATEGIES = tuple(STRATEGY)
INITIAL = ("best-average", "random")
# What the partner is identified as: `library`, one of the study's library policies, choosing by
# the table P; `groups`, one of the grown library's partner groups, choosing among the grown
# library's members (services/adapter/core.py, Payoff.from_groups). A name without the setting
# reads as `library` (every name recorded before groups existed); the command line's default is
# `groups` (SHIPPED), the agent the project ships.
PARTNERS = ("library", "groups")
WINDOWS = Range(1, FRAMES.high)  # T: a window longer than a game never fills
ADAPTIVE = "adaptive-"  # how every adaptive agent's name begins
_NAME = re.compile(rf"^{ADAPTIVE}T(\d+)-([a-z-]+)$")
NAMED = {
    "initial": str,
    "warmup": int,
    "dwell": int,
    "hazard": float,
    "noise": float,
    "partners": str,
}  # in a name after T, strategy


def setting_text(value: object) -> str:
    """A setting as a name writes it: 150, not 150.0 (floats otherwise as Python writes them back,
    so that reading the name gives the same number); a word after a hyphen."""
    if isinstance(value, str):
        return f"-{value}"
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(value)


def _option(default: object, help: str, command_line: object = None) -> Any:
    """A config field with its command-line help and, where it differs, its command-line default
    (services/commands/options.py builds the options from these)."""
    return field(
        default=default, metadata={"help": help, "default": default if command_line is None else command_line}
    )


@dataclass(frozen=True)
class AdapterConfig:
    """The adaptive agent, whole: every launcher, study variant, command line and report reads or
    names it through this value. Zero means "the default derived from the window"."""

    role: str = _option("shooter", "The adaptive agent's seat; the partner plays the other.")
    window: int = _option(400, "T: frames of partner play the similarity averages over.")
    strategy: str = _option("bayes-dwell-ood-guard", f"One of {', '.join(STRATEGIES)}.")
    initial: str = _option("best-average", f"Policy before the first estimate: {' or '.join(INITIAL)}.")
    warmup: int = _option(0, "Frames before the first estimate (0: min(T, 150), 5 s).")
    dwell: int = _option(0, "-dwell strategies: frames a new choice must hold (0: max(15, T/10)).")
    hazard: float = _option(0.0, "bayes: per-frame switching probability (0: 1/T).")
    noise: float = _option(0.05, "bayes: probability that the partner's action is a uniform slip.")
    seed: int = _option(0, "Draws the random initial policy.")
    partners: str = _option(
        "library",
        "What the partner is identified as: groups (the grown library's partner groups, playing its "
        "members) or library (the study's policies, playing by its table P).",
        command_line="groups",
    )

    def __post_init__(self) -> None:
        choices = (("--role", self.role, ROLES), ("--strategy", self.strategy, STRATEGIES))
        for option, value, valid in (
            *choices,
            ("--initial", self.initial, INITIAL),
            ("--partners", self.partners, PARTNERS),
        ):
            if value not in valid:
                raise UsageError(option, value, "unknown", valid)
        for option, value, limits in (
            ("--window", self.window, WINDOWS),
            ("--warmup", self.warmup, Range(0, FRAMES.high)),
            ("--dwell", self.dwell, Range(0, FRAMES.high)),
            ("--seed", self.seed, SEEDS),
        ):
            if value not in limits:
                raise UsageError(option, value, f"outside the range {limits}")
        for option, value in (("--hazard", self.hazard), ("--noise", self.noise)):
            if not 0.0 <= value < 1.0:
                raise UsageError(option, value, "a probability in [0, 1)")
        if self.partners == "groups" and self.strategy_kind.skill:
            raise UsageError(
                "--strategy", self.strategy, "its skill model knows the library's policies, not groups"
            )

    @property
    def partner_role(self) -> str:
        return other(self.role)

    @property
    def strategy_kind(self) -> Strategy:
        """What the strategy does (`Strategy`), not its name read as substrings."""
        return STRATEGY[self.strategy]

    @property
    def warmup_frames(self) -> int:
        return self.warmup or min(self.window, 150)

    @property
    def dwell_frames(self) -> int:
        return (self.dwell or max(15, self.window // 10)) if self.strategy_kind.dwell else 0

    @property
    def hazard_rate(self) -> float:
        return self.hazard or 1.0 / self.window

    @property
    def name(self) -> str:
        """The name a recording, a result table, a study or an offer gives this agent, whole:
        adaptive-T<window>-<strategy>, then _<setting><value> for each of NAMED that is not the
        default (_initial-random, _warmup150, _dwell20, _hazard0.01, _noise0.1). The seat and the
        seed are where it plays, not what it is, so the name leaves them out."""
        default = {f.name: f.default for f in fields(self)}
        extra = "".join(
            f"_{s}{setting_text(getattr(self, s))}" for s in NAMED if getattr(self, s) != default[s]
        )
        return f"{ADAPTIVE}T{self.window}-{self.strategy}{extra}"

    @classmethod
    def parse(cls, name: str, option: str = "--policy", **context: object) -> AdapterConfig:
        """The config a name stands for (`name`'s inverse); `context` gives the seat and seed (role,
        seed). A UsageError about `option` for a name that is not an adaptive agent's."""
        head, *items = name.split("_")
        found = _NAME.match(head)
        if not found:
            raise UsageError(
                option, name, f"not an adaptive agent ({ADAPTIVE}T<window>-<strategy>[_<setting>...])"
            )
        named: dict[str, object] = {}
        for item in items:
            setting = next((s for s in NAMED if item.startswith(s)), None)
            if setting is None or setting in named:
                raise UsageError(
                    option, name, f"{item!r} is not one setting of the adaptive agent", list(NAMED)
                )
            text = item.removeprefix(setting)
            try:
                named[setting] = text.removeprefix("-") if NAMED[setting] is str else NAMED[setting](text)
            except ValueError:
                raise UsageError(option, name, f"{item!r}: {setting} takes a number") from None
        return cls(window=int(found[1]), strategy=found[2], **named, **context)

    @classmethod
    def shipped(cls, role: str = "shooter", window: int = 400) -> AdapterConfig:
        """The agent the project ships (`tsf adapter`'s defaults: each field's command-line default)
        in seat `role` at `window`."""
        defaults = {f.name: f.metadata["default"] for f in fields(cls)}
        return cls(**defaults | {"role": role, "window": window})

    def to_args(self) -> list[str]:
        """The same config as `tsf adapter` options: one per field, so that none is dropped."""
        return [arg for f in fields(self) for arg in (f"--{f.name}", str(getattr(self, f.name)))]


# The agent the project ships, the command line's default: every field at its command-line default
# (partners `groups`, the grown library's agent). A page, figure or help text that calls an agent
# "the default" means this one (tests/test_docs.py); AdapterConfig() itself is the study library's
# agent, which a name without settings has always meant.
SHIPPED = AdapterConfig.shipped()
