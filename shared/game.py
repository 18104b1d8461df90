"""The game's vocabulary and its rule numbers: the one module every layer stands on.

Roles, the other seat, the bait-first seat order, the action encoding, event kinds, death causes,
the observation's size, the frame rate, the `Policy` protocol and `GameConfig` live here and
nowhere else. It imports nothing of the project (docs/architecture.md; tests/test_layers.py).
GameConfig is here rather than beside the engine because the wire contract validates it: the
Start message carries the config a match is replayed with.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import numbers
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, TypeVar, runtime_checkable

if TYPE_CHECKING:
    import numpy as np

ROLES: tuple[str, str] = ("bait", "shooter")  # also the seat order: the bait first, everywhere
HUMAN = "human"  # a seat's policy key for a person: no agent plays it, a gateway does
PERSON = ("", HUMAN)  # what a recording's start record names a person's seat
FPS = 30  # frames per second of game time
N_TURN, N_THRUST, N_FIRE = 3, 2, 2  # choices of each action head; turn 0 none, 1 left (ccw), 2 right
N_ACTIONS = N_TURN * N_THRUST * N_FIRE
NOOP = 0  # the action of no turn, no thrust, no fire: what an empty or failed seat plays
DEATH_CAUSES = ("shell", "border", "shield")
# What the engine reports in a frame (services/sim/engine.py Event), then the sim's match markers.
EVENT_KINDS = (
    "kill",
    "death",
    "shield_hit",
    "missile",
    "shell",
    "lock",
    "fortress_respawn",
    "reset",
    "respawn",
    "match_start",
    "match_end",
    "policy_failure",  # a seat's policy raised or answered no action; it played no-op (the sim's)
)
OBS_SIZE = 64  # float values per observation; the layout is services/sim/observation.py
# The adapter scores the partner's frames in batches of SCORE_FRAMES frames of the match (never by
# the clock: a lockstep match plays as fast as it is answered) and rules on the last frame of each
# batch; a switch it makes plays from the frame after that one, live and in the in-process
# evaluation alike (docs/adapter.md, "When a switch plays").
SCORE_FRAMES = 6


@dataclass(frozen=True)
class Range:
    """The values a number may take, both ends included. The wire contract and the command line
    check a value against the same Range, so a value a command accepts is one every service accepts.
    Ends of type float make a range of numbers, ends of type int one of whole numbers."""

    low: int | float
    high: int | float

    def __contains__(self, value: object) -> bool:
        """NaN is in no range (it compares false), nor is a bool."""
        return (
            isinstance(value, int | float) and not isinstance(value, bool) and self.low <= value <= self.high
        )

    def __str__(self) -> str:
        return f"{self.low} to {self.high}"


SEEDS = Range(0, 2**32 - 1)  # a game's seed; random.Random(-s) would play the game of seed s
FRAMES = Range(1, 60 * 60 * FPS)  # a game's length: at most an hour
DURATION = Range(0.1, FRAMES.high / FPS)  # the same in seconds, where people give it (--duration)

T = TypeVar("T")


def scoring(frame: int) -> bool:
    """Whether the adapter rules on `frame`: the last of a batch of SCORE_FRAMES (5, 11, 17, ...)."""
    return (frame + 1) % SCORE_FRAMES == 0


def ruled_at(frame: int) -> int:
    """The scoring frame whose ruling covers `frame`: a choice the adapter makes on `frame` is
    played from the frame after this one."""
    return frame + (-(frame + 1)) % SCORE_FRAMES


def check_role(role: str) -> str:
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r}; expected one of {ROLES}")
    return role


def other(role: str) -> str:
    """The other seat."""
    return ROLES[1 - ROLES.index(check_role(role))]


def bait_first(role: str, mine: T, partners: T) -> tuple[T, T]:
    """A pair of one seat's value and its partner's, in seat order (the bait's first)."""
    return (mine, partners) if check_role(role) == ROLES[0] else (partners, mine)


def split_action(action: int) -> tuple[int, int, int]:
    """Action index -> (turn, thrust, fire)."""
    return action // 4, (action >> 1) & 1, action & 1


def join_action(turn: int, thrust: int, fire: int) -> int:
    return turn * 4 + thrust * 2 + fire


def checked_action(action: object) -> int:
    """A policy's answer as an action index; ValueError naming it unless it is an integer
    0..N_ACTIONS-1 (a bool or a float is not), wherever a policy from outside is asked."""
    if isinstance(action, bool) or not isinstance(action, numbers.Integral) or not 0 <= action < N_ACTIONS:
        raise ValueError(f"returned {action!r:.40}, not an action (an integer 0..{N_ACTIONS - 1})")
    return int(action)


@runtime_checkable
class Policy(Protocol):
    """What every player of TSF implements: library, scripted, random or human proxy.

    A policy is reset with a seed, reads the observation vector of its role (in the view it names),
    returns an action, and returns the full distribution over the N_ACTIONS actions it samples
    from. The distribution is what the adapter's similarity score reads, so it must be the real
    sampling distribution and never zero anywhere."""

    key: str
    role: str
    view: str  # the observation view it reads: "world" or "role"

    def reset(self, seed: int | None = None) -> None: ...

    def act(self, obs: np.ndarray) -> int: ...

    def probs(self, obs: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class GameConfig:
    """Every rule number of a TSF game (pixels, frames, degrees)."""

    fps: int = FPS
    frames: int = 1800
    # Arena: nothing wraps; leaving it is a border death.
    arena_x: float = 355.0
    arena_y: float = 313.0
    # Fortress and its two hexagons (circumradii), rotating with the facing.
    fortress_radius: float = 18.0
    shield_radius: float = 40.0
    region_radius: float = 200.0
    fortress_turn: float = 4.0  # deg/frame (assumption)
    fortress_aim_tolerance: float = 10.0  # deg
    fortress_fire_interval: int = 30  # frames since last shell or lock
    vulnerable_frames: int = 20  # from each shell's launch (assumption)
    rear_arc: float = 120.0  # deg, open shield arc centred opposite the facing
    kill_distance: float = 23.0  # missile centre to fortress centre
    # Ships.
    ship_radius: float = 10.0
    ship_turn: float = 6.0  # deg/frame
    ship_thrust: float = 0.3  # px/frame^2
    ship_drag: float = 0.995  # velocity factor per frame (assumption)
    ship_max_speed: float = 8.0  # px/frame (assumption)
    # Missiles (the ships') and shells (the fortress's).
    missile_speed: float = 20.0
    missile_radius: float = 5.0
    missiles_in_flight: int = 5
    missile_cooldown: int = 6  # frames between a ship's launches (assumption)
    shell_speed: float = 6.0
    shell_radius: float = 3.0
    shell_hit_distance: float = 13.0  # shell centre to ship centre
    # Rounds.
    respawn_delay: int = 30  # frames: both-dead reset, and minimum fortress downtime
    bait_spawn: tuple[float, float, float] = (-280.0, 0.0, 0.0)  # x, y, heading
    shooter_spawn: tuple[float, float, float] = (280.0, 0.0, 180.0)
    spawn_jitter_px: float = 20.0  # (assumption)
    spawn_jitter_deg: float = 30.0  # (assumption)
    # Points (display and reward shaping).
    points_kill: int = 100
    points_death: int = -100
    points_shield_hit: int = -20  # (assumption)

    def __post_init__(self) -> None:
        if self.frames not in FRAMES or self.fps <= 0:
            raise ValueError(f"frames must be {FRAMES} and fps positive, got {self.frames}, {self.fps}")
        if not self.fortress_radius < self.shield_radius < self.region_radius:
            raise ValueError("need fortress_radius < shield_radius < region_radius")

    def replace(self, **changes: object) -> GameConfig:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> GameConfig:
        """The inverse of to_dict (lists from msgpack or JSON become the spawn tuples again)."""
        if not isinstance(values, dict) or set(values) != {f.name for f in dataclasses.fields(cls)}:
            raise ValueError("a game config needs exactly the GameConfig fields")
        defaults = cls()
        converted = {}
        for name, value in values.items():
            default = getattr(defaults, name)
            value = tuple(value) if isinstance(value, list) else value
            if not _same_kind(value, default):
                raise ValueError(f"config field {name}: {value!r} does not match {default!r}")
            converted[name] = value
        return cls(**converted)

    def hash(self) -> str:
        """Stable short hash, so artifacts (tables, recordings) can name the rules they used."""
        text = json.dumps(self.to_dict(), sort_keys=True)
        return hashlib.blake2b(text.encode(), digest_size=8).hexdigest()


def _same_kind(value: object, default: object) -> bool:
    """Whether a loaded value can stand for a default: an int for an int, a finite number for a
    float, a tuple of such numbers as long as the default's."""
    if isinstance(default, tuple):
        return (
            isinstance(value, tuple)
            and len(value) == len(default)
            and all(_same_kind(v, d) for v, d in zip(value, default, strict=True))
        )
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    if isinstance(default, int):
        return isinstance(value, int)
    return math.isfinite(value)
