"""Human-like partners: a library or plug-in policy played by a simulated hand.

`human(B5)` plays B5's choices as a person at a keyboard would, and `human(B1,B5)` drifts from
B1's style to B5's over a session. The numbers come from published reaction-time and keypress
data (docs/adapter.md, "Human-like partners", cites them):

- **Reaction delay.** Each decision reads the state of `lag` frames ago, with lag drawn from an
  ex-Gaussian (mu, sigma, tau): the person's mu is drawn once per person, shifted once per game,
  and sigma and tau spread each decision.
- **Held keys.** A decision is held for at least HOLD_MIN frames (a key press lasts about 0.1 s)
  plus a geometric run, then the person decides again.
- **Lapses.** At a decision the person may lapse: the keys stay as they are for 0.5 s plus an
  exponential tail (the vigilance literature's lapse, a response slower than 0.5 s).
- **Motor noise.** A decision may slip: one of the three keys (turn, thrust, fire) comes out wrong.
- **Drift.** With two policies, each decision follows the second with probability w, which grows
  from 0 to 1 over a session of SESSION_TRIALS one-minute trials.

Every draw is counter-based (sampling.lane_uniforms, keyed by the game's seed, a stream and the
frame), so a game is a function of its seed, and `act` (one game) and `act_lanes` (n games at
once, the batched form) give every lane the same actions. A session is SESSION_TRIALS consecutive
game seeds: game s is trial s % SESSION_TRIALS of person s // SESSION_TRIALS, whose traits are
drawn from the person's number only (the partner is reset with play.policy_seed of the game's
seed, and reads the game's back).
"""

from __future__ import annotations

import math

import numpy as np

from services.sim import observation as ob
from services.sim.play import game_seed, policy_seed
from services.sim.sampling import batch_probs, lane_uniforms, sample
from shared.game import N_ACTIONS, N_FIRE, N_THRUST, N_TURN, join_action, split_action

FRAME_MS = 1000.0 / 30.0
SESSION_TRIALS = 3  # the study plays three one-minute trials with the same partner
RT_MU, RT_MU_PERSON_SD, RT_MU_GAME_SD = 200.0, 25.0, 15.0  # ms: the ex-Gaussian's mu
RT_SIGMA, RT_TAU = 25.0, 50.0  # ms: its Gaussian spread and exponential tail
HISTORY = 36  # frames of states kept (1.2 s): the longest lag
HOLD_MIN, HOLD_EXTRA = 3, 2.0  # frames: the shortest key press, the mean extra run
LAPSES_PER_MINUTE = (0.3, 3.0)  # a person's lapse rate is drawn log-uniformly in this range
LAPSE_MS, LAPSE_TAIL_MS = 500.0, 400.0
SLIP = (0.02, 0.05)  # a person's chance that a decision's key comes out wrong
_STREAMS = dict(
    zip(
        ("lapse", "lapse_len", "n1", "n2", "tail", "style", "action", "slip", "key", "hold"),
        range(40, 50),
        strict=True,
    )
)


class HumanLike:
    """A policy (or two, drifting) played by a simulated hand; see the module docstring."""

    def __init__(self, first, second=None) -> None:
        if second is not None and (first.role != second.role or first.view != second.view):
            raise ValueError(f"human({first.key},{second.key}): both must share role and observation view")
        self.first, self.second = first, second
        self.key = f"human({first.key})" if second is None else f"human({first.key},{second.key})"
        self.role, self.view = first.role, first.view
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        self.reset_lanes([policy_seed(0, self.role) if seed is None else seed])

    def reset_lanes(self, seeds: list[int]) -> None:
        """Start one game per seed, the seed its seat resets its partner with (play.policy_seed of
        the game's seed): the person's traits, drawn from the person of the game's seed, and this
        game's reaction delay."""
        n = len(seeds)
        self.seeds = np.asarray(seeds, np.int64)
        for inner in (self.first, self.second):
            if inner is not None:
                inner.reset(int(seeds[0]))
        played = np.array([max(0, game_seed(int(s), self.role)) for s in seeds], np.int64)
        people = [np.random.default_rng([int(g) // SESSION_TRIALS, 17]) for g in played]
        games = [np.random.default_rng([int(s), 29]) for s in seeds]
        low, high = np.log(LAPSES_PER_MINUTE)
        traits = np.array(
            [[r.normal(RT_MU, RT_MU_PERSON_SD), r.uniform(low, high), r.uniform(*SLIP)] for r in people]
        )
        self.mu = np.clip(traits[:, 0] + [g.normal(0.0, RT_MU_GAME_SD) for g in games], 120.0, 400.0)
        # a lapse can start at any decision; decisions come every HOLD_MIN + HOLD_EXTRA frames
        per_decision = np.exp(traits[:, 1]) / (60.0 * 30.0) * (HOLD_MIN + HOLD_EXTRA)
        self.lapse, self.slip = per_decision, traits[:, 2]
        self.trial = played % SESSION_TRIALS
        self.ring = np.zeros((n, HISTORY, ob.TIME + 1), np.float32)
        self.held = np.zeros(n, np.int64)
        self.hold_left = np.zeros(n, np.int64)
        self.t = 0

    def act(self, obs: np.ndarray) -> int:
        """The action of a single game (after reset): act_lanes with one lane."""
        return int(self.act_lanes(obs[None])[0])

    def act_lanes(self, observations: np.ndarray) -> np.ndarray:
        """One action per lane for this frame's (n, 64) observations (the batched form)."""
        t = self.t
        self.ring[:, t % HISTORY] = observations
        self.t += 1
        busy = self.hold_left > 0
        self.hold_left[busy] -= 1
        u = {name: lane_uniforms(self.seeds, stream, t) for name, stream in _STREAMS.items()}
        lapse = ~busy & (u["lapse"] < self.lapse)
        lapse_frames = (LAPSE_MS - LAPSE_TAIL_MS * np.log1p(-u["lapse_len"])) / FRAME_MS
        self.hold_left[lapse] = np.rint(lapse_frames[lapse]).astype(np.int64)
        decide = np.flatnonzero(~busy & ~lapse)
        if len(decide):
            self._decide(decide, u, t)
        return self.held.copy()

    def _decide(self, lanes: np.ndarray, u: dict[str, np.ndarray], t: int) -> None:
        normal = np.sqrt(-2.0 * np.log1p(-u["n1"])) * np.cos(2.0 * math.pi * u["n2"])
        lag_ms = self.mu + RT_SIGMA * normal - RT_TAU * np.log1p(-u["tail"])
        lag = np.clip(np.rint(lag_ms / FRAME_MS).astype(np.int64), 0, min(t, HISTORY - 1))
        seen = self.ring[np.arange(len(self.seeds)), (t - lag) % HISTORY][lanes]
        probs = self._probs(seen, lanes, u["style"][lanes])
        actions = sample(probs, u["action"][lanes])
        slipped = u["slip"][lanes] < self.slip[lanes]
        actions[slipped] = [
            _slip(a, k) for a, k in zip(actions[slipped], u["key"][lanes][slipped], strict=True)
        ]
        self.held[lanes] = actions
        extra = np.floor(np.log1p(-u["hold"][lanes]) / math.log(HOLD_EXTRA / (1.0 + HOLD_EXTRA)))
        self.hold_left[lanes] = HOLD_MIN - 1 + extra.astype(np.int64)

    def _probs(self, seen: np.ndarray, lanes: np.ndarray, style: np.ndarray) -> np.ndarray:
        """The (rows, 12) distributions the person decides from: the first policy's, or, drifting,
        the second's with probability w (the session's progress)."""
        probs = self._inner_probs(self.first, seen)
        if self.second is not None:
            progress = (self.trial[lanes] + 1.0 - seen[:, ob.TIME]) / SESSION_TRIALS
            second = style < progress
            if second.any():
                probs[second] = self._inner_probs(self.second, seen[second])
        return probs

    @staticmethod
    def _inner_probs(inner, seen: np.ndarray) -> np.ndarray:
        if hasattr(inner, "probs") or hasattr(inner, "probs_batch"):
            return batch_probs(inner, seen)
        return np.eye(N_ACTIONS)[[inner.act(o) for o in seen]]  # a plug-in that only acts


def _slip(action: int, draw: float) -> int:
    """The action with one key (chosen by `draw`) pressed wrong."""
    turn, thrust, fire = split_action(int(action))
    key = min(int(draw * 4), 3)
    if key <= 1:  # turn: the other two choices, equally likely
        turn = (turn + 1 + key) % N_TURN
    elif key == 2:
        thrust = (thrust + 1) % N_THRUST
    else:
        fire = (fire + 1) % N_FIRE
    return join_action(turn, thrust, fire)
