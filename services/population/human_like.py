"""Human-like partners: a library or plug-in policy played by a simulated person at the keys.

`human(B5)` plays B5's choices as a person would, `human(B1,B5)` drifts from B1's style to B5's
over a session, and `human(B5,skill=novice)` (or `typical`, the default, `practised`, or a number
in [0, 1]) sets how practised the person is. docs/humans.md cites the numbers and says which are
ours and how they were calibrated:

- **Looks and delay.** The person looks now and then (every LOOK_MS on average) and takes in the
  state of a reaction time ago (ex-Gaussian), plus `input_ms`, the delay of the screen and keys
  they play through: by default the study's page (PAGE_INPUT_MS), `input_ms=0` for none.
- **Anticipation.** Between looks they act on that state moved to now by a forward model (the
  game's own rules, engine.steer and engine.fortress_turn): their own ship by the keys they
  pressed since, the partner, shells and missiles coasting, and over the foreseen part of the lag
  the fortress turning and firing when aimed and due: a person fires into an opening they expect.
- **Held keys.** Every frame the policy chooses on the predicted state, and each key (turn,
  thrust, fire) changes only once held the person's shortest press (intermittent control).
- **Fire habits.** The fire key has its own: once down it stays down a burst (`fire_ms`, a missile
  every cooldown while held), and once up it stays up the person's gap between presses (`fire_gap_ms`).
- **Lapses.** At a look the person may lapse: the keys stay as they are for 0.5 s plus a tail.
- **Slips.** A key change may come out wrong (the turn the third way, a press missed).
- **Skill and learning.** Every trait lies between a first-time player's value (skill 0) and a
  practised player's (skill 1); over a session's SESSION_TRIALS trials the gap to practised
  shrinks as a power law of practice.
- **Drift.** With two policies, each frame follows the second with probability w, which grows
  from 0 to 1 over the session.
- **Parameters.** Each trait is drawn from the person and their practice unless `human(...)` names
  it (PARAMETERS: `reaction_ms`, `look_ms`, `hold_ms`, `fire_ms`, `fire_gap_ms`, `lapses`,
  `slip`, `foresight`): a named one is the person's in every trial, as `tsf humans fit` estimates it.
  `session=N` makes a session N trials (default SESSION_TRIALS).

Every draw is counter-based (sampling.lane_uniforms, keyed by the game's seed, a stream and the
frame), so a game is a function of its seed, and one game (`act`) is one lane of many
(`act_lanes`). A session is SESSION_TRIALS consecutive game seeds: game s is trial
s % SESSION_TRIALS of person s // SESSION_TRIALS, whose traits are drawn from the person's number
only (the partner is reset with play.policy_seed of the game's seed, and reads the game's back).
The hand reads the world view and hands each inner policy the predicted state in its own view.
"""

from __future__ import annotations

import math
import re

import numpy as np

from services.sim import observation as ob
from services.sim.engine import fortress_turn, steer
from services.sim.jit import compiled
from services.sim.play import game_seed, policy_seed
from services.sim.sampling import batch_probs, lane_uniforms, sample
from shared.game import FPS, N_ACTIONS, GameConfig, join_action, split_action

FRAME_MS = 1000.0 / FPS
SESSION_TRIALS = 3  # the study plays three one-minute trials with the same partner
STAND_INS = "stand_ins.json"  # what `tsf humans fit` writes into DIR
SKILLS = {"novice": 0.0, "typical": 0.65, "practised": 1.0}  # typical: calibrated (docs/humans.md)
# What the study's page adds to a person's delay: a key is seen 2 frames later there (median 53-62
# ms, docs/human.md), 1 frame in process (an action chosen on frame t shows in t + 1); so 1 frame.
PAGE_INPUT_MS = 33.0
# A trait as (first-time player, practised player); skill s in [0, 1] lies between, linearly.
RT_MU = (260.0, 190.0)  # ms: the ex-Gaussian's mu, the person's mean
RT_MU_PERSON_SD, RT_MU_GAME_SD = 25.0, 15.0  # ms: between people, between one person's games
RT_SIGMA, RT_TAU = 25.0, 50.0  # ms: its Gaussian spread and exponential tail
FORESIGHT = (0.0, 1.0)  # the fraction of the lag over which the fortress is foreseen (ours)
FORESIGHT_SD = 0.15  # between people (ours)
LAPSES_PER_MINUTE = ((1.0, 6.0), (0.2, 1.0))  # a person's rate, log-uniform in this range
LAPSE_MS, LAPSE_TAIL_MS = 500.0, 400.0
SLIP = ((0.04, 0.08), (0.01, 0.03))  # a person's chance that a decision's key comes out wrong
LEARNING = 0.5  # power-law exponent: trial i keeps (i + 1) ** -LEARNING of the gap to practised
HOLD_MS = (100.0, 67.0)  # the shortest key press or release
LOOK_MIN = 2  # frames between looks at the least
LOOK_MS = (270.0, 67.0)  # ms between looks on average (ours: calibrated)
LONGEST_LAG = 30  # frames (1 s)
HISTORY = 64  # frames of states kept: the longest lag plus the longest run between looks
_STREAMS = dict(
    zip(
        ("lapse", "lapse_len", "n1", "n2", "tail", "style", "action", "slip", "look"),
        range(40, 49),
        strict=True,
    )
)
_HEADS = np.array([split_action(a)[:2] for a in range(N_ACTIONS)], np.int64)  # turn, thrust
# The model's own parameters, which human(...) may name (then fixed for the person): their bounds.
PARAMETERS = {
    "reaction_ms": (120.0, 450.0),  # the person's mean reaction time (the ex-Gaussian's mu)
    "look_ms": (67.0, 600.0),  # the mean time between looks
    "hold_ms": (33.0, 300.0),  # the shortest press or release of the turn and thrust keys
    "fire_ms": (33.0, 1000.0),  # the shortest press of the fire key: a burst
    "fire_gap_ms": (33.0, 1000.0),  # the shortest release of the fire key: the gap between presses
    "lapses": (0.0, 20.0),  # lapses per minute
    "slip": (0.0, 0.5),  # the chance that a key change comes out wrong
    "foresight": (0.0, 1.0),  # the share of the lag over which the fortress is foreseen
}
SETTINGS = ("skill", "input_ms", *PARAMETERS, "session")  # human(...)'s settings, in its name's order
_SETTING = re.compile(r"^(\w+)\s*=\s*(.+)$")


def between(trait: tuple, skill: np.ndarray) -> np.ndarray:
    """A trait's value at each skill: the novice's at 0, the practised player's at 1."""
    low, high = (np.asarray(v, np.float64) for v in trait)
    s = np.asarray(skill, np.float64).reshape(-1, *([1] * low.ndim))
    return low + (high - low) * s


def parse_skill(text: str) -> float:
    """A skill by name (SKILLS) or as a number in [0, 1]; ValueError naming what is accepted."""
    if text in SKILLS:
        return SKILLS[text]
    try:
        skill = float(text)
    except ValueError:
        skill = -1.0
    if not 0.0 <= skill <= 1.0:
        raise ValueError(f"skill={text} is not one of {', '.join(SKILLS)} or a number in [0, 1]")
    return skill


class HumanLike:
    """A policy (or two, drifting) played by a simulated person; see the module docstring."""

    view = "world"

    def __init__(
        self,
        first,
        second=None,
        skill: float = SKILLS["typical"],
        input_ms: float = PAGE_INPUT_MS,
        config=None,
        session: int = SESSION_TRIALS,
        **parameters: float,
    ) -> None:
        if second is not None and first.role != second.role:
            raise ValueError(f"human({first.key},{second.key}): both must share a role")
        if unknown := set(parameters) - set(PARAMETERS):
            raise ValueError(f"{', '.join(sorted(unknown))}: not among {', '.join(PARAMETERS)}")
        self.first, self.second, self.skill, self.input_ms = first, second, float(skill), float(input_ms)
        self.session = int(session)
        self.parameters = {name: float(parameters[name]) for name in PARAMETERS if name in parameters}
        settings = [] if skill == SKILLS["typical"] else [f"skill={_skill_name(skill)}"]
        settings += [f"input_ms={input_ms:g}"] if input_ms != PAGE_INPUT_MS else []
        settings += [f"{name}={value:g}" for name, value in self.parameters.items()]
        settings += [f"session={self.session}"] if self.session != SESSION_TRIALS else []
        inner = [p.key for p in (first, second) if p is not None]
        self.key = f"human({','.join(inner + settings)})"
        self.role = first.role
        self.rules = rules_of(config or GameConfig())  # the rules the person's forward model knows
        self.reset()

    @classmethod
    def from_arguments(cls, inner: list, settings: list[str]) -> HumanLike:
        """human(...)'s partners and its settings: `skill=LEVEL`, `input_ms=`, a parameter's value
        (PARAMETERS) and `session=TRIALS`, each a number within its bounds."""
        values: dict[str, float] = {}
        bounds = {"input_ms": (0.0, 300.0), **PARAMETERS, "session": (1, 100)}
        for item in settings:
            match = _SETTING.match(item)
            if not match or match[1] not in SETTINGS:
                raise ValueError(
                    f"{item!r} is not skill=LEVEL or NAME=NUMBER for NAME in {', '.join(SETTINGS[1:])}"
                )
            name, text = match[1], match[2].strip()
            if name == "skill":
                values[name] = parse_skill(text)
                continue
            try:
                values[name] = int(text) if name == "session" else float(text)
            except ValueError:
                raise ValueError(f"{name}={text} is no {'whole ' * (name == 'session')}number") from None
            low, high = bounds[name]
            if not low <= values[name] <= high:
                raise ValueError(f"{name}={text} is outside [{low:g}, {high:g}]")
        return cls(*inner, **values)

    def reset(self, seed: int | None = None) -> None:
        self.reset_lanes([policy_seed(0, self.role) if seed is None else seed])

    def reset_lanes(self, seeds: list[int]) -> None:
        """Start one game per seed, the seed its seat resets its partner with (play.policy_seed of
        the game's seed)."""
        n = len(seeds)
        for inner in (self.first, self.second):
            if inner is not None:
                inner.reset(int(seeds[0]))
        self.seeds, self.start, self.trial = (np.zeros(n, np.int64) for _ in range(3))
        self.mu, self.look, self.lapse, self.slip, self.foresight = (np.zeros(n) for _ in range(5))
        self.ring = np.zeros((n, HISTORY, ob.TIME + 1), np.float32)
        self.keys = np.zeros((n, HISTORY), np.int64)  # the actions pressed, for the forward model
        self.held, self.hold = np.zeros(n, np.int64), np.zeros((n, 3, 2), np.int64)
        self.since_change = np.zeros((n, 3), np.int64)  # frames each key is as it is
        self.seen_at = np.zeros(n, np.int64)  # the frame whose state the person last took in
        self.look_left = np.zeros(n, np.int64)  # frames to the next look
        self.lapse_left = np.zeros(n, np.int64)
        self.t = 0
        self.restart_lanes(np.arange(n), seeds)

    def restart_lanes(self, lanes: np.ndarray, seeds: list[int]) -> None:
        """Start a new game in each of `lanes` (seeded as reset_lanes's) while the others play on,
        as a training env's lanes restart one by one: the person's traits, drawn from the person
        of the game's seed, this trial's skill (practice) and this game's reaction delay. A lane's
        draws count frames from its own start, so its game is the scalar game of its seed."""
        played = np.array([max(0, game_seed(int(s), self.role)) for s in seeds], np.int64)
        n = len(seeds)
        trial = played % self.session
        skill = 1.0 - (1.0 - self.skill) * (trial + 1.0) ** -LEARNING
        people = [np.random.default_rng([int(g) // self.session, 17]) for g in played]
        games = [np.random.default_rng([int(s), 29]) for s in seeds]
        # the person's draws: reaction mu, lapse rate, slip rate, foresight
        draws = np.array([[r.normal(), r.uniform(), r.uniform(), r.normal()] for r in people])

        def trait(name: str, drawn: np.ndarray) -> np.ndarray:  # a named parameter, else as drawn
            return np.full(n, self.parameters[name]) if name in self.parameters else drawn

        mu = trait("reaction_ms", between(RT_MU, skill) + RT_MU_PERSON_SD * draws[:, 0])
        mu = np.clip(mu + [g.normal(0.0, RT_MU_GAME_SD) for g in games], *PARAMETERS["reaction_ms"])
        lapses = trait("lapses", np.exp(_pick(np.log(between(LAPSES_PER_MINUTE, skill)), draws[:, 1])))
        look = trait("look_ms", between(LOOK_MS, skill)) / FRAME_MS  # frames between looks, on average
        self.mu[lanes], self.look[lanes] = mu, look
        self.lapse[lanes] = lapses / (60.0 * FPS) * look  # a lapse can start at any look
        self.slip[lanes] = trait("slip", _pick(between(SLIP, skill), draws[:, 2]))
        foresight = trait("foresight", between(FORESIGHT, skill) + FORESIGHT_SD * draws[:, 3])
        self.foresight[lanes] = np.clip(foresight, 0.0, 1.0)
        # frames each key must stay as it is, (lanes, turn/thrust/fire, released/pressed): by
        # default the skill's shortest press, every key both ways
        hold = between(HOLD_MS, skill)
        turn, fire = trait("hold_ms", hold), [trait("fire_gap_ms", hold), trait("fire_ms", hold)]
        ms = np.stack([np.stack([turn, turn], 1), np.stack([turn, turn], 1), np.stack(fire, 1)], 1)
        self.hold[lanes] = np.rint(ms / FRAME_MS).astype(np.int64)
        self.since_change[lanes] = self.hold[lanes].max(axis=(1, 2))[:, None]
        self.seeds[lanes], self.trial[lanes], self.start[lanes] = seeds, trial, self.t
        self.held[lanes], self.seen_at[lanes] = 0, self.t
        self.look_left[lanes], self.lapse_left[lanes] = 0, 0

    def act(self, obs: np.ndarray) -> int:
        """The action of a single game (after reset): act_lanes with one lane."""
        return int(self.act_lanes(obs[None])[0])

    def act_lanes(self, observations: np.ndarray) -> np.ndarray:
        """One action per lane for this frame's (n, 64) world-view observations: a new look at a
        sampling moment (or a lapse), then every key the policy wants on the predicted state
        changed if it has been held long enough."""
        t, lanes = self.t, np.arange(len(self.seeds))
        self.ring[:, t % HISTORY] = observations
        self.t += 1
        frames = t - self.start  # each lane's frame of its own game
        u = {name: lane_uniforms(self.seeds, stream, frames) for name, stream in _STREAMS.items()}
        self.since_change += 1
        lapsing = self.lapse_left > 0
        self.lapse_left[lapsing] -= 1
        look = ~lapsing & (self.look_left <= 0)
        self.look_left[~lapsing] -= 1
        lapse = look & (u["lapse"] < self.lapse)
        lapse_frames = (LAPSE_MS - LAPSE_TAIL_MS * np.log1p(-u["lapse_len"])) / FRAME_MS
        self.lapse_left[lapse] = np.rint(lapse_frames[lapse]).astype(np.int64)
        look &= ~lapse
        normal = np.sqrt(-2.0 * np.log1p(-u["n1"])) * np.cos(2.0 * math.pi * u["n2"])
        lag_ms = self.mu + self.input_ms + RT_SIGMA * normal - RT_TAU * np.log1p(-u["tail"])
        lag = np.clip(np.rint(lag_ms / FRAME_MS).astype(np.int64), 0, LONGEST_LAG)
        self.seen_at[look] = np.maximum(t - lag[look], self.start[look])
        extra = np.maximum(self.look - LOOK_MIN, 1e-9)
        runs = np.floor(np.log1p(-u["look"]) / np.log(extra / (1.0 + extra))).astype(np.int64)
        self.look_left[look] = np.minimum(LOOK_MIN + runs[look], HISTORY - LONGEST_LAG - 1)
        active = lanes[~(lapsing | lapse)]
        if len(active):
            self._press(active, u, t)
        self.keys[:, t % HISTORY] = self.held
        return self.held.copy()

    def _press(self, lanes: np.ndarray, u: dict[str, np.ndarray], t: int) -> None:
        """The keys of `lanes` this frame: the policy's choice on the state the person expects now
        (the last look, moved on by their forward model), each key changed only once it has been
        held the person's shortest press, and a change pressed wrong with the person's slip rate."""
        age = t - self.seen_at[lanes]
        seen = self.ring[lanes, self.seen_at[lanes] % HISTORY]
        foreseen = np.rint(self.foresight[lanes] * age).astype(np.int64)
        expected = predict(seen, age, foreseen, self.keys[lanes], t, self.rules)
        chosen = sample(self._probs(expected, lanes, u["style"][lanes]), u["action"][lanes])
        wanted, now = np.array(split_action(chosen)), np.array(split_action(self.held[lanes]))
        needed = np.take_along_axis(self.hold[lanes], (now.T != 0)[:, :, None].astype(np.int64), 2)[..., 0]
        change = (wanted != now) & (needed.T <= self.since_change[lanes].T)
        # a slip: the turn goes the third way, a thrust or fire press is missed
        wrong = np.array([3 - now[0] - wanted[0], now[1], now[2]])
        pressed = np.where(
            change & (u["slip"][lanes] < self.slip[lanes]), wrong, np.where(change, wanted, now)
        )
        self.since_change[lanes] = np.where(pressed != now, 0, self.since_change[lanes].T).T
        self.held[lanes] = join_action(*pressed)

    def _probs(self, expected: np.ndarray, lanes: np.ndarray, style: np.ndarray) -> np.ndarray:
        """The (rows, 12) distributions the person decides from: the first policy's, or, drifting,
        the second's with probability w (the session's progress)."""
        probs = _inner_probs(self.first, expected)
        if self.second is not None:
            progress = (self.trial[lanes] + 1.0 - expected[:, ob.TIME]) / SESSION_TRIALS
            second = style < progress
            if second.any():
                probs[second] = _inner_probs(self.second, expected[second])
        return probs


def rules_of(c: GameConfig) -> np.ndarray:
    """The numbers of a game's rules that the forward model (predict) reads."""
    return np.array(
        [c.ship_turn, c.ship_thrust, c.ship_drag, c.ship_max_speed, c.fortress_turn]
        + [c.fortress_aim_tolerance, c.fortress_fire_interval, c.vulnerable_frames, c.frames],
        np.float64,
    )


def in_view(world: np.ndarray, view: str) -> np.ndarray:
    """World-view rows as a policy of `view` reads them."""
    if view != "role":
        return world
    rows = world.astype(np.float64)
    ob.to_role_view(rows)
    return rows.astype(np.float32)


def _inner_probs(inner, world: np.ndarray) -> np.ndarray:
    """An inner policy's distributions over world-view rows, handed to it in its own view."""
    seen = in_view(world, inner.view)
    if hasattr(inner, "probs") or hasattr(inner, "probs_batch"):
        return batch_probs(inner, seen)
    return np.eye(N_ACTIONS)[[inner.act(o) for o in seen]]  # a plug-in that only acts


def predict(
    seen: np.ndarray, lag: np.ndarray, foreseen: np.ndarray, keys: np.ndarray, t: int, rules: np.ndarray
) -> np.ndarray:
    """World-view rows seen `lag` frames before frame t, moved on to frame t by the game's rules
    (`rules`: HumanLike.rules): the person's own ship by the keys pressed since (`keys`, each
    lane's ring of pressed actions), the partner, shells and missiles coasting; and over the first
    `foreseen` of those frames the fortress turning toward its target and firing (opening its rear)
    when aimed and due (beyond them it is left as last seen)."""
    out = seen.astype(np.float64)
    _predict(out, np.asarray(lag, np.int64), np.asarray(foreseen, np.int64), keys, t, _HEADS, rules)
    return out.astype(np.float32)


@compiled
def _predict(out, lag, foreseen, keys, t, heads, rules):
    ship_turn, thrust, drag, cap, f_turn = rules[0], rules[1], rules[2], rules[3], rules[4]
    tolerance, interval, window, frames = rules[5], rules[6], rules[7], rules[8]
    p, v = ob.POSITION_SCALE, ob.VELOCITY_SCALE
    history = keys.shape[1]
    for i in range(out.shape[0]):
        row, n = out[i], lag[i]
        if n <= 0:
            continue
        heading = math.degrees(math.atan2(row[ob.SELF + ob.SIN], row[ob.SELF + ob.COS])) % 360.0
        vx, vy = row[ob.SELF + ob.VX] * v, row[ob.SELF + ob.VY] * v
        vulnerable = row[ob.FORTRESS + ob.F_VULNERABLE] * window
        since = row[ob.FORTRESS + ob.F_SINCE_SHELL] * interval
        facing = math.degrees(math.atan2(row[ob.FORTRESS + ob.F_SIN], row[ob.FORTRESS + ob.F_COS]))
        target = ob.SELF if row[ob.FORTRESS + ob.F_LOCK_SELF] > 0.5 else -1
        target = ob.PARTNER if row[ob.FORTRESS + ob.F_LOCK_PARTNER] > 0.5 else target
        for k in range(n):
            if row[ob.SELF + ob.ALIVE] > 0.5:
                turn, push = heads[keys[i, (t - lag[i] + k) % history]]
                heading, vx, vy, cos_h, sin_h = steer(
                    heading, vx, vy, turn, push, ship_turn, thrust, drag, cap
                )
                row[ob.SELF + ob.X] += vx / p
                row[ob.SELF + ob.Y] += vy / p
                row[ob.SELF + ob.COS], row[ob.SELF + ob.SIN] = cos_h, sin_h
            row[ob.PARTNER + ob.X] += row[ob.PARTNER + ob.VX] * v / p
            row[ob.PARTNER + ob.Y] += row[ob.PARTNER + ob.VY] * v / p
            for j in range(ob.N_SHELLS + ob.N_MISSILES):
                at = ob.SHELLS + j * ob.PROJECTILE_SIZE
                if row[at + 4] > 0.5:
                    row[at + ob.X] += row[at + ob.VX] * v / p
                    row[at + ob.Y] += row[at + ob.VY] * v / p
            if row[ob.FORTRESS + ob.F_ALIVE] < 0.5 or target < 0 or k >= foreseen[i]:
                continue
            since += 1.0
            vulnerable = max(vulnerable - 1.0, 0.0)
            bearing = math.degrees(math.atan2(row[target + ob.Y], row[target + ob.X]))
            step, error = fortress_turn(facing, bearing, f_turn)
            facing = (facing + step) % 360.0
            if abs(error - step) <= tolerance and since >= interval:
                since, vulnerable = 0.0, window
        rad = math.radians(facing)
        row[ob.FORTRESS + ob.F_COS], row[ob.FORTRESS + ob.F_SIN] = math.cos(rad), math.sin(rad)
        row[ob.FORTRESS + ob.F_VULNERABLE] = vulnerable / window
        row[ob.FORTRESS + ob.F_SINCE_SHELL] = min(since / interval, 1.0)
        row[ob.SELF + ob.VX], row[ob.SELF + ob.VY] = vx / v, vy / v
        row[ob.TIME] = max(row[ob.TIME] - n / frames, 0.0)


def _pick(bounds: np.ndarray, draw: np.ndarray) -> np.ndarray:
    """Per lane, the point `draw` (in [0, 1]) of the way from bounds[:, 0] to bounds[:, 1]."""
    return bounds[:, 0] + (bounds[:, 1] - bounds[:, 0]) * draw


def _skill_name(skill: float) -> str:
    return next((name for name, value in SKILLS.items() if value == skill), f"{skill:g}")
