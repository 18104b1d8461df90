"""The one immutable config that holds every number of the game.

Defaults follow docs/rules.md; numbers the original team game never published are marked
*(assumption)* there. Any re-tuning is written in the rules page with its measurement.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass

ROLES: tuple[str, str] = ("bait", "shooter")
N_ACTIONS = 12


@dataclass(frozen=True)
class GameConfig:
    """Every rule number of a TSF game (pixels, frames, degrees)."""

    fps: int = 30
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
        if self.frames <= 0 or self.fps <= 0:
            raise ValueError(f"frames and fps must be positive, got {self.frames}, {self.fps}")
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


def split_action(action: int) -> tuple[int, int, int]:
    """Action index -> (turn, thrust, fire); turn 0 none, 1 left (ccw), 2 right."""
    return action // 4, (action >> 1) & 1, action & 1


def join_action(turn: int, thrust: int, fire: int) -> int:
    return turn * 4 + thrust * 2 + fire
