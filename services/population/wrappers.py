"""The partner grammar's wrappers (noisy, delayed, sticky, switch, human) and the batched form of
each that plays in lanes: the one place a new wrapper is written. `WRAPPERS` names each with how
many partners it takes, the settings it takes and its batched form; the grammar
(services/population/seat.py) parses by it, and the partners' lanes (partners.py) build by it.

Every draw a wrapper makes comes from its own stream of `lane_uniforms` (`next(streams)`, taken in
the order its form is built), keyed by the game's seed and the frame, so that a game's partner is
the same alone or among many lanes. A wrapper's form is built after the partners inside it, and a
switch's second partner before its first: the order every earlier version drew in, which keeps a
game's draws, and so its recording, as they were.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from services.sim.sampling import lane_uniforms
from shared.game import N_ACTIONS

NOISE = 0.1
DELAY = 6  # frames
STICKY = 0.5
SWITCH_AT = 900  # frame: the middle of a one-minute game


class Lanes(Protocol):
    """A partner in n lanes: reset with each lane's game seed, then one action per lane per frame."""

    view: str

    def reset(self, keys: np.ndarray) -> None: ...

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray: ...


class LaneWrapper:
    """A partner in lanes around another, `inner` (as SB3's VecEnvWrapper wraps a VecEnv): it reads
    the inner partner's view, resets it with the lanes' keys (kept as `keys`) and acts as it does; a
    wrapper overrides only what it changes."""

    def __init__(self, inner: Lanes) -> None:
        self.inner, self.view = inner, inner.view

    def reset(self, keys: np.ndarray) -> None:
        self.inner.reset(keys)
        self.keys = keys

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        return self.inner.act(obs, frame)


class Noisy(LaneWrapper):
    """noisy(X): a uniformly random action with probability `noise`, lane by lane."""

    def __init__(self, inner: Lanes, noise: float, streams: Iterator[int]) -> None:
        super().__init__(inner)
        self.noise, self.slip, self.pick = noise, next(streams), next(streams)

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        action = self.inner.act(obs, frame)
        slipped = lane_uniforms(self.keys, self.slip, frame) < self.noise
        random = (lane_uniforms(self.keys, self.pick, frame) * N_ACTIONS).astype(np.int64)
        return np.where(slipped, random, action)


class Delayed(LaneWrapper):
    """delayed(X): the inner partner acts on each lane's observation of `delay` frames ago (the
    first one until that many have been seen)."""

    def __init__(self, inner: Lanes, delay: int) -> None:
        super().__init__(inner)
        self.delay = delay

    def reset(self, keys: np.ndarray) -> None:
        super().reset(keys)
        self.seen: np.ndarray | None = None
        self.t = 0

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        kept = self.delay + 1
        if self.seen is None:
            self.seen = np.empty((kept, *obs.shape), obs.dtype)
        self.seen[self.t % kept] = obs
        oldest = max(0, self.t - self.delay)
        self.t += 1
        return self.inner.act(self.seen[oldest % kept], frame)


class Sticky(LaneWrapper):
    """sticky(X): each lane repeats its previous action with probability `sticky` (keys held too
    long)."""

    def __init__(self, inner: Lanes, sticky: float, streams: Iterator[int]) -> None:
        super().__init__(inner)
        self.sticky, self.stream = sticky, next(streams)

    def reset(self, keys: np.ndarray) -> None:
        super().reset(keys)
        self.last = np.zeros(len(keys), np.int64)

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        action = self.inner.act(obs, frame)  # the inner partner keeps its own course either way
        self.last = np.where(lane_uniforms(self.keys, self.stream, frame) >= self.sticky, action, self.last)
        return self.last


class Switching:
    """switch(X,Y): the first partner for `at` frames, then the second."""

    def __init__(self, first: Lanes, second: Lanes, at: int) -> None:
        if first.view != second.view:
            raise ValueError("both partners of switch(...) must read the same observation view")
        self.first, self.second, self.at, self.view = first, second, at, first.view

    def reset(self, keys: np.ndarray) -> None:
        self.first.reset(keys)
        self.second.reset(keys)
        self.t = 0

    def act(self, obs: np.ndarray, frame: int) -> np.ndarray:
        self.t += 1
        return (self.first if self.t <= self.at else self.second).act(obs, frame)


Inner = Callable[..., Lanes]  # inner(i): the i-th wrapped partner's lanes; inner(i, own=True): with
# a stream and a seed offset of its own


@dataclass(frozen=True)
class Wrapper:
    """One wrapper of the grammar: how many partners it takes, the settings it takes (name=value),
    what of them its batched form depends on (`setting`, a ValueError for a wrong one), and that
    form: `lanes(inner, setting, streams)`; None where the wrapper plays as its own kind (the
    simulated hand, human_like.HumanLike)."""

    partners: tuple[int, ...] = (1,)
    settings: tuple[str, ...] = ()
    lanes: Callable[[Inner, object, Iterator[int]], Lanes] | None = None
    setting: Callable[[tuple[tuple[str, str], ...]], object] = lambda settings: None


def frames(settings: tuple[tuple[str, str], ...]) -> int:
    """delayed(...)'s frames: DELAY, or frames=N (0 to 60)."""
    if not settings:
        return DELAY
    (name, value), *more = settings
    if more or name != "frames" or not str(value).isdigit() or int(value) > 60:
        raise ValueError("delayed(...) takes one setting, frames=N (0 to 60)")
    return int(value)


def _switching(inner: Inner, setting: object, streams: Iterator[int]) -> Switching:
    second = inner(1, own=True)  # built first, as it always was (the module's docstring)
    return Switching(inner(0), second, SWITCH_AT)


WRAPPERS = {
    "noisy": Wrapper(lanes=lambda inner, setting, streams: Noisy(inner(0), NOISE, streams)),
    "delayed": Wrapper(
        settings=("frames",), lanes=lambda inner, delay, streams: Delayed(inner(0), delay), setting=frames
    ),
    "sticky": Wrapper(lanes=lambda inner, setting, streams: Sticky(inner(0), STICKY, streams)),
    "switch": Wrapper((2,), lanes=_switching),
    # its settings: human_like.SETTINGS (skill, input_ms, the model's parameters)
    "human": Wrapper((1, 2), ("skill", "input_ms", "reaction_ms", "...")),
}
