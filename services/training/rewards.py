"""Rewards of the library's recipes (the `train` extra's training, services/training): one value per
lane of a batched game, for the learner's seat. A recipe names its reward (`REWARDS`) and weights."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from services.sim.batch import BatchGame


def opening(batch: BatchGame, seat: int) -> np.ndarray:
    """Whether the fortress, up and locked on this bait, is firing with its open back to the
    shooter: the frames in which the bait's work can become a kill."""
    s, shooter = batch.state, 1 - seat
    rear = np.radians(s.facing + 180.0)
    bearing = np.arctan2(s.y[:, shooter], s.x[:, shooter])
    behind = np.abs((bearing - rear + np.pi) % (2 * np.pi) - np.pi) <= np.radians(batch.config.rear_arc / 2)
    both = s.alive[:, seat] & s.alive[:, shooter]
    return both & s.fortress_alive & (s.lock == seat) & (s.vulnerable > 0) & behind


def facing(batch: BatchGame, seat: int) -> np.ndarray:
    """The cosine of the angle between this ship's heading and its bearing to the fortress."""
    s = batch.state
    x, y = s.x[:, seat], s.y[:, seat]
    r = np.hypot(x, y)
    h = np.radians(s.heading[:, seat])
    return -(x * np.cos(h) + y * np.sin(h)) / np.where(r == 0.0, 1.0, r)


def drawing_fire_reward(
    batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]
) -> np.ndarray:
    """1 per frame of `opening`, plus `kill` per team kill. The study paid 1 per frame in the
    region. From scratch that taught baits to stay in after a kill (which keeps the fortress from
    respawning) and to circle faster than the fortress turns or the shooter follows: region time
    without kills."""
    return opening(batch, seat) + weights.get("kill", 0.0) * batch.event_counts("kill")


def border_bearing_death_reward(
    batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]
) -> np.ndarray:
    """The shaped family: border * distance / region radius + bearing * cos(heading to the
    fortress) per frame of `opening`, - death per death of this ship, + kill per team kill. The
    study paid the shaped terms on every frame in the region; from scratch its baits then sat at the
    border facing the fortress and drew no useful fire."""
    s = batch.state
    r = np.hypot(s.x[:, seat], s.y[:, seat])
    shaped = weights["border"] * r / batch.config.region_radius + weights["bearing"] * facing(batch, seat)
    deaths = batch.event_counts("death", seat)
    kills = weights.get("kill", 0.0) * batch.event_counts("kill")
    return kills - weights["death"] * deaths + np.where(opening(batch, seat), shaped, 0.0)


def shooter_position_reward(
    batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]
) -> np.ndarray:
    """The study's: 1 per frame just outside the region while the bait is out, 1 per frame at the
    fortress's rear while it is in, `kill` per kill; plus `aim` * cos(aim error)^16 per frame the
    fortress is up. Without the aim term the DQN shooters learned neither to aim nor to move (the
    kills that pay for aiming come too rarely to a shooter that turns at random; docs/library.md)."""
    s, region = batch.state, batch.config.region_radius
    x, y = s.x[:, seat], s.y[:, seat]
    r = np.hypot(x, y)
    rear = np.radians(s.facing + 180.0)
    off = np.abs((np.arctan2(y, x) - rear + np.pi) % (2 * np.pi) - np.pi)
    waiting = (region < r) & (r < region + 60.0)  # just outside the region while the bait is out
    at_rear = (off < np.radians(40.0)) & (region < r) & (r < region + 100.0)
    placed = np.where(s.in_region[:, 0], at_rear, waiting) & s.alive[:, seat]
    aimed = np.clip(facing(batch, seat), 0.0, 1.0) ** 16 * (s.fortress_alive & s.alive[:, seat])
    return weights["kill"] * batch.event_counts("kill") + placed + weights.get("aim", 0.0) * aimed


# The terms of the "events" reward, each per lane and frame for the learner's seat: a partner of the
# population is trained on a random weighting of them (services/population/families.py), as HSP
# trains its biased partners on random event weights, so that its style is its own, not the
# library's.
EVENT_TERMS: dict[str, Callable[[BatchGame, int], np.ndarray]] = {
    "kill": lambda b, seat: b.event_counts("kill"),  # team kills
    "death": lambda b, seat: b.event_counts("death", seat),  # this ship's deaths
    "region": lambda b, seat: b.state.in_region[:, seat],  # frames inside the activation region
    "distance": lambda b, seat: np.hypot(b.state.x[:, seat], b.state.y[:, seat]) / b.config.region_radius,
    "facing": facing,  # heading toward the fortress: aggression
    "speed": lambda b, seat: np.hypot(b.state.vx[:, seat], b.state.vy[:, seat]) / b.config.ship_max_speed,
    "shots": lambda b, seat: b.event_counts("missile", seat),  # missiles fired
    "shells": lambda b, seat: b.event_counts("shell", seat),  # shells the fortress fired at this ship
    "partner": lambda b, seat: (
        np.hypot(b.state.x[:, 0] - b.state.x[:, 1], b.state.y[:, 0] - b.state.y[:, 1])
        / b.config.region_radius
    ),  # distance kept from the partner
}


def events_reward(batch: BatchGame, seat: int, before: np.ndarray, weights: dict[str, float]) -> np.ndarray:
    """The weighted sum of EVENT_TERMS (a term without a weight counts 0; a negative weight is a
    cost), while this ship lives."""
    total = np.zeros(batch.n)
    for name, weight in weights.items():
        total += weight * EVENT_TERMS[name](batch, seat)
    return total


REWARDS: dict[str, Callable[[BatchGame, int, np.ndarray, dict[str, float]], np.ndarray]] = {
    "drawing-fire": drawing_fire_reward,
    "border-bearing-death": border_bearing_death_reward,
    "shooter-position": shooter_position_reward,
    "events": events_reward,
}
