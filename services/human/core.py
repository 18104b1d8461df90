"""The human gateway's pure core: seats and their tokens, what a browser may send, the key state it
holds, and what the page is sent. No web server and no bus here (services/human/gateway.py is the
shell), so every rule about a person's input is tested directly.

The browser protocol is JSON text frames, every message typed and validated in shared/page.py (the
page's contract, docs/contract.md). Up (browser -> gateway): `join` (a seat and its token, first)
or `watch` (playing no seat), then `ready` and `keys` (the held keys, on every change). Down
(gateway -> browser): `welcome` (the seat and the arena's geometry) or `refused` (why), then
`setup` (the match's own numbers), `state` (one frame to draw, with what it means for the person:
Narrator), `event` (a kill, death, shield hit or respawn, as it happens) and `end` (the match's
result). The study runner (services/study/runner.py) uses the same socket with `hello` and
`consent` up and its own messages down.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from services.agent.policy import stalled
from shared.errors import UsageError
from shared.game import ROLES, GameConfig, join_action, other, split_action
from shared.messages import GameEvent, State, Summary
from shared.page import GEOMETRY, End, EventView, Keys, PageError, PageMessage, Ready, StateView, decode
from shared.secret import same_secret

RATE = 60.0  # messages a second a connection may send on average (a person changes keys far less)
BURST = 60  # and at once
STRIKES = 300  # messages dropped (bad or over the rate) before the connection is closed


# A browser message that does not meet the page's contract (or comes too fast); `reason` is a short
# code for counting. The contract's own error: one kind of bad input, whichever check found it.
BadInput = PageError


def parse(text: str | bytes, allowed: tuple[str, ...]) -> PageMessage:
    """A browser's text frame -> the validated message, or BadInput. `allowed`: the types accepted
    now (a join only first, keys only after it)."""
    return decode(text, allowed)


def keys_action(keys: Keys) -> int:
    """Held keys -> the action index. Left and right together cancel, as on a keyboard's joystick."""
    turn = 1 if keys.left and not keys.right else 2 if keys.right and not keys.left else 0
    return join_action(turn, int(keys.thrust), int(keys.fire))


def action_keys(action: int) -> Keys:
    """The key state that plays `action` (what a scripted stand-in presses)."""
    turn, thrust, fire = split_action(action)
    return Keys(left=turn == 1, right=turn == 2, thrust=bool(thrust), fire=bool(fire))


class RateLimit:
    """A token bucket: `rate` messages a second on average, `burst` at once."""

    def __init__(self, rate: float = RATE, burst: int = BURST, clock: Callable[[], float] = time.monotonic):
        self.rate, self.burst, self.clock = rate, burst, clock
        self.tokens, self.last = float(burst), clock()

    def full(self) -> bool:
        """Whether the bucket has refilled: it is then as good as a new one."""
        return self.tokens + (self.clock() - self.last) * self.rate >= self.burst

    def allow(self) -> bool:
        now = self.clock()
        self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
        self.last = now
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True


class PerAddress:
    """A RateLimit per client address (`rate` 0: none). Buckets that have refilled are forgotten
    once there are many, so a crowd of addresses costs no memory for long."""

    def __init__(self, rate: float, burst: int, clock: Callable[[], float] = time.monotonic) -> None:
        self.rate, self.burst, self.clock = rate, burst, clock
        self.buckets: dict[str, RateLimit] = {}

    def allow(self, address: str) -> bool:
        if not self.rate:
            return True
        if len(self.buckets) > 10_000:
            self.buckets = {a: bucket for a, bucket in self.buckets.items() if not bucket.full()}
        bucket = self.buckets.setdefault(address, RateLimit(self.rate, self.burst, self.clock))
        return bucket.allow()


@dataclass
class Controls:
    """One connection's input: what it holds now, whether it is playing, and what it got wrong.

    The bus side reads `action` once per state (from another thread: one int, replaced whole)."""

    action: int = 0
    ready: bool = False
    drops: dict[str, int] = field(default_factory=dict)
    limit: RateLimit = field(default_factory=RateLimit)

    def receive(self, text: str | bytes, allowed: tuple[str, ...] = ("ready", "keys")) -> PageMessage | None:
        """Take one message; returns it if valid and within the rate, else counts the drop and
        returns None. Raises BadInput("strikes") once too many were dropped: close the connection."""
        try:
            if not self.limit.allow():
                raise BadInput("rate", "over the message rate")
            message = parse(text, allowed)
        except BadInput as error:
            self.drops[error.reason] = self.drops.get(error.reason, 0) + 1
            if sum(self.drops.values()) >= STRIKES:
                raise BadInput("strikes", f"{STRIKES} bad or excess messages") from None
            return None
        if isinstance(message, Ready):
            self.ready = True
        elif isinstance(message, Keys):
            self.action = keys_action(message)
        return message


class SeatBook:
    """The seats of one match and their tokens: a seat obeys one connection, the one that showed its
    token first; others are refused until it leaves. Seats without a token are not offered."""

    def __init__(self, tokens: dict[str, str]) -> None:
        unknown = set(tokens) - set(ROLES)
        if unknown:
            raise UsageError("--token", ", ".join(sorted(unknown)), "unknown roles", ROLES)
        self.tokens = dict(tokens)
        self.holders: dict[str, object] = {}

    def claim(self, role: str, token: str, holder: object) -> str:
        """Give `role` to `holder`; returns "" on success, else why not (shown to the person)."""
        expected = self.tokens.get(role)
        if expected is None:
            return f"the {role} seat of this match is not open to people"
        if not same_secret(token, expected):
            return f"wrong seat token for the {role} seat"
        if role in self.holders:
            return f"the {role} seat is already taken by another connection"
        self.holders[role] = holder
        return ""

    def release(self, role: str, holder: object) -> None:
        if self.holders.get(role) is holder:
            del self.holders[role]


def setup(config: GameConfig) -> dict:
    """The numbers the page draws with (services/sim/render.py draws the same picture): the fields
    of the `welcome` and `setup` messages (shared/page.py GEOMETRY)."""
    return {name: getattr(config, name) for name in GEOMETRY}


def view(
    state: State, narration: dict | None = None, obs: bool = False, role: str | None = None
) -> StateView:
    """One frame as the page draws it, rounded to what a screen shows (a tenth of a pixel), with the
    actions that led to it (the page draws a thrusting ship's flame) and the Narrator's fields;
    with `obs`, `role`'s observation values too."""
    return StateView(
        frame=state.frame,
        frames=state.frames,
        ships=[[_r(x), _r(y), _r(heading), alive] for x, y, _, _, heading, alive in state.ships],
        fortress=[_r(state.fortress[0]), *state.fortress[1:4]],  # facing, alive, vulnerable, lock
        missiles=[[_r(m[0]), _r(m[1]), int(m[4])] for m in state.missiles],
        shells=[[_r(s[0]), _r(s[1])] for s in state.shells],
        kills=state.kills,
        points=state.points,
        applied=state.applied,
        **(narration or {"respawn": None, "ending": False}),
        obs=state.obs[role] if obs and role is not None else None,
    )


NARRATED = ("kill", "death", "shield_hit", "respawn", "reset", "fortress_respawn")  # what the page shows
# Agents that do not end stalled rounds (docs/library.md "Stalled rounds"); a person does not either.
NO_ROUND_ENDING = ("idle", "random")


def event_view(event: GameEvent) -> EventView | None:
    """A game event as the page shows it (a death with its cause in `detail`), or None for those it
    does not show (missiles, shells and locks are seen in the frames)."""
    if event.kind not in NARRATED:
        return None
    return EventView(frame=event.frame, kind=event.kind, role=event.role, detail=event.detail)


class Narrator:
    """What a frame means for the person in `role`, which the page says in words: `respawn`, the
    frames until a round whose ships are both dead resets (None while one lives), and `ending`,
    whether the partner is an agent ending a stalled round on purpose (its own rule, policy.stalled
    on its observation: this ship dead, it alive, the fortress up, no missile that can kill), so
    the page can say why it flies into the shield. Fed every state in order: the page may skip
    frames, the gateway does not."""

    def __init__(self, role: str | None, partner_ends_rounds: bool, delay: int) -> None:
        self.role, self.delay = role, delay
        self.partner = None if role is None or not partner_ends_rounds else other(role)
        self.both_dead: int | None = None  # the first frame of the round's both-dead count-down

    def __call__(self, state: State) -> dict:
        if any(ship[5] for ship in state.ships):
            self.both_dead = None
        elif self.both_dead is None:
            self.both_dead = state.frame
        respawn = None if self.both_dead is None else max(0, self.both_dead + self.delay - state.frame)
        partner_obs = state.obs.get(self.partner) if self.partner else None
        ending = partner_obs is not None and bool(stalled(partner_obs))
        return {"respawn": respawn, "ending": ending}


def end(summary: Summary, frames: int) -> End:
    """The match's result as the page shows it; `frame` short of the planned `frames`: it was
    stopped early (the page says so, never "Time is up")."""
    return End(
        kills=summary.kills,
        kills_per_minute=round(summary.kills_per_minute, 2),
        points=summary.points,
        frame=summary.frame,
        frames=frames,
    )


def points(config: GameConfig) -> dict[str, int]:
    """How the team's points are counted, as the page explains them."""
    return {"kill": config.points_kill, "death": config.points_death, "shield_hit": config.points_shield_hit}


def _r(value: float) -> float:
    return round(value, 1) if math.isfinite(value) else 0.0
