"""Scenario and property tests of the engine against the rules (docs/rules.md).

Scenarios drive a real Game and place entities directly: ships through `place`, missiles and shells
by appending to `game.missiles` ([x, y, vx, vy, owner]) and `game.shells` ([x, y, vx, vy]).
Frame order matters for the exact frame numbers below: ships steer and move, then projectiles move,
then ship deaths, missiles, shells, and last the fortress acts.
"""

from __future__ import annotations

import math
import random
import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.sim.engine import Event, Game, Ship
from shared.game import GameConfig, join_action, split_action

EXACT = GameConfig().replace(spawn_jitter_px=0.0, spawn_jitter_deg=0.0)
NOOP, FIRE, THRUST, LEFT, RIGHT = 0, 1, 2, 4, 8
BAIT, SHOOTER = 0, 1
BAIT_SPAWN, SHOOTER_SPAWN = (-280.0, 0.0, 0.0), (280.0, 0.0, 180.0)
INSIDE = {BAIT: (-150.0, 0.0), SHOOTER: (150.0, 0.0)}  # inside the activation region at any facing


def new_game() -> Game:
    return Game(EXACT, seed=0)


def place(
    ship: Ship, x: float, y: float, heading: float | None = None, vx: float = 0.0, vy: float = 0.0
) -> None:
    ship.body.position = (x, y)
    ship.vx, ship.vy = vx, vy
    ship.body.velocity = (vx, vy)
    if heading is not None:
        ship.heading = heading


def run(game: Game, frames: int, bait: int = NOOP, shooter: int = NOOP) -> list[Event]:
    events: list[Event] = []
    for _ in range(frames):
        events += game.step(bait, shooter)
    return events


def of_kind(events: list[Event], kind: str) -> list[tuple[int, str, str]]:
    return [(e.frame, e.role, e.detail) for e in events if e.kind == kind]


def missile_at_centre(game: Game, bearing: float, dist: float, owner: int = BAIT) -> list:
    """Append a missile `dist` from the fortress on `bearing`, flying straight at the centre."""
    rad, speed = math.radians(bearing), game.config.missile_speed
    cos, sin = math.cos(rad), math.sin(rad)
    missile = [dist * cos, dist * sin, -speed * cos, -speed * sin, owner]
    game.missiles.append(missile)
    return missile


def step_until(game: Game, kind: str, limit: int = 100, clear_shells: bool = False) -> int:
    """Step with no-op actions until an event of `kind`; returns its frame."""
    for _ in range(limit):
        events = game.step(NOOP, NOOP)
        if clear_shells:
            game.shells.clear()
        if of_kind(events, kind):
            return game.frame
    raise AssertionError(f"no {kind} event in {limit} frames")


def kill_fortress(game: Game, owner: int) -> list[Event]:
    """Open the fortress (facing 0, vulnerable) and fly `owner`'s missile into its rear: 3 frames."""
    game._set_facing(0.0)
    game.vulnerable = game.config.vulnerable_frames
    missile_at_centre(game, 180.0, 70.0, owner)  # 50, 30 (in the opening), 10 (kill)
    events = run(game, 3)
    assert of_kind(events, "kill") == [(game.frame, game.ships[owner].role, "")]
    return events


def border_kill(ship: Ship) -> None:
    """Place `ship` so that it crosses the arena edge on the next step."""
    place(ship, 352.0 if ship.role == "bait" else -352.0, 200.0, vx=8.0 if ship.role == "bait" else -8.0)


def total_deaths(game: Game) -> int:
    return sum(sum(ship.counters.deaths.values()) for ship in game.ships)


# ------------------------------------------------------------------ actions and ship physics


@pytest.mark.parametrize("role", ["bait", "shooter"])
@pytest.mark.parametrize("action", range(12))
def test_action_index_is_turn_times_4_plus_thrust_times_2_plus_fire(action: int, role: str) -> None:
    turn, thrust, fire = action // 4, action // 2 % 2, action % 2
    assert split_action(action) == (turn, thrust, fire)
    assert join_action(turn, thrust, fire) == action
    game = new_game()
    ship = game.bait if role == "bait" else game.shooter
    start = ship.heading
    game.step(*((action, NOOP) if role == "bait" else (NOOP, action)))
    assert ship.heading == pytest.approx((start + (0.0, 6.0, -6.0)[turn]) % 360.0)
    assert (math.hypot(ship.vx, ship.vy) > 0.0) == bool(thrust)
    assert len(game.missiles) == fire


@pytest.mark.parametrize(("action", "heading"), [(LEFT, 90.0), (RIGHT, 270.0)])
def test_turning_is_6_degrees_per_frame_left_counter_clockwise(action: int, heading: float) -> None:
    game = new_game()
    run(game, 15, bait=action)
    assert game.bait.heading == pytest.approx(heading)
    assert (game.bait.x, game.bait.y) == BAIT_SPAWN[:2]  # turning alone does not move the ship


def test_thrust_accelerates_along_the_heading_with_drag() -> None:
    game = new_game()
    place(game.bait, -280.0, 0.0, heading=30.0)
    dx, dy = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    vx = vy = 0.0
    x, y = -280.0, 0.0
    for _ in range(3):
        game.step(THRUST, NOOP)
        vx, vy = (vx + 0.3 * dx) * 0.995, (vy + 0.3 * dy) * 0.995
        x, y = x + vx, y + vy
        assert (game.bait.vx, game.bait.vy) == pytest.approx((vx, vy), abs=1e-12)
        assert (game.bait.x, game.bait.y) == pytest.approx((x, y), abs=1e-9)


def test_turn_applies_before_thrust_in_the_same_frame() -> None:
    game = new_game()
    game.step(LEFT + THRUST, NOOP)
    assert math.degrees(math.atan2(game.bait.vy, game.bait.vx)) == pytest.approx(6.0)


def test_drag_multiplies_velocity_by_0_995_each_frame() -> None:
    game = new_game()
    place(game.bait, -280.0, 0.0, vx=4.0, vy=-2.0)
    run(game, 10)
    factor = 0.995**10
    assert (game.bait.vx, game.bait.vy) == pytest.approx((4.0 * factor, -2.0 * factor), abs=1e-12)
    travelled = sum(0.995**k for k in range(1, 11))
    assert (game.bait.x, game.bait.y) == pytest.approx((-280.0 + 4.0 * travelled, -2.0 * travelled))


def test_speed_is_capped_at_8_keeping_the_direction() -> None:
    game = new_game()
    place(game.bait, -280.0, 0.0, vx=6.0, vy=6.0)
    game.step(NOOP, NOOP)
    assert (game.bait.vx, game.bait.vy) == pytest.approx((8.0 / math.sqrt(2.0),) * 2)
    place(game.shooter, 300.0, 280.0, heading=180.0)  # long straight run above the region
    speeds = []
    for _ in range(60):
        game.step(NOOP, THRUST)
        speeds.append(math.hypot(game.shooter.vx, game.shooter.vy))
    assert max(speeds) <= 8.0 + 1e-12
    assert speeds[-1] == pytest.approx(8.0)
    assert game.shooter.alive


# ------------------------------------------------------------------ missiles


def test_missile_leaves_the_nose_along_the_heading_at_20_px_per_frame() -> None:
    game = new_game()
    place(game.bait, -280.0, 100.0, heading=30.0)
    game.step(FIRE, NOOP)
    [missile] = game.missiles
    dx, dy = math.cos(math.radians(30.0)), math.sin(math.radians(30.0))
    nose = (-280.0 + 10.0 * dx, 100.0 + 10.0 * dy)
    assert missile[2:] == pytest.approx([20.0 * dx, 20.0 * dy, BAIT])
    # From the nose, having flown zero or one frame in its launch frame.
    assert any(
        missile[:2] == pytest.approx([nose[0] + k * missile[2], nose[1] + k * missile[3]]) for k in (0, 1)
    )
    before = missile[:2]
    game.step(NOOP, NOOP)
    assert game.missiles[0][:2] == pytest.approx([before[0] + 20.0 * dx, before[1] + 20.0 * dy])
    assert game.bait.counters.missiles_fired == 1


def test_a_ship_fires_at_most_once_every_6_frames() -> None:
    game = new_game()
    place(game.bait, -280.0, 250.0)
    launches = [game.frame for _ in range(20) if of_kind(game.step(FIRE, NOOP), "missile")]
    assert launches == [1, 7, 13, 19]
    assert game.bait.counters.missiles_fired == 4


def test_at_most_5_missiles_in_flight_per_ship() -> None:
    game = new_game()
    parked = [[0.0, 280.0, 0.0, 0.0, BAIT] for _ in range(5)]  # still, far from everything
    game.missiles.extend(parked)
    events = run(game, 10, bait=FIRE, shooter=FIRE)
    assert of_kind(events, "missile") == [(1, "shooter", ""), (7, "shooter", "")]  # the limit is per ship
    assert game.bait.counters.missiles_fired == 0
    game.missiles.remove(parked[0])
    assert of_kind(game.step(FIRE, NOOP), "missile") == [(11, "bait", "")]


def test_held_fire_never_exceeds_5_in_flight_and_resumes_when_one_leaves() -> None:
    game = new_game()
    place(game.bait, -345.0, 300.0)  # missiles cross the whole arena: 35 frames each
    most = 0
    for _ in range(60):
        game.step(FIRE, NOOP)
        most = max(most, sum(1 for m in game.missiles if m[4] == BAIT))
    assert most == 5
    assert game.bait.counters.missiles_fired > 5


@pytest.mark.parametrize(
    ("x", "y", "vx", "vy"), [(340.0, 0.0, 20.0, 0.0), (-340.0, 0.0, -20.0, 0.0), (0.0, 300.0, 0.0, 20.0)]
)
def test_missiles_and_shells_are_removed_at_the_arena_edge(x: float, y: float, vx: float, vy: float) -> None:
    game = new_game()
    game.missiles.append([x, y, vx, vy, BAIT])
    game.shells.append([x, -y, vx * 0.3, -vy * 0.3])  # 6 px/frame from 15 px inside the edge
    game.missiles.append([x - vx, y - vy, vx, vy, SHOOTER])  # one frame behind: stays in
    game.step(NOOP, NOOP)
    assert [m[4] for m in game.missiles] == [SHOOTER]
    assert len(game.shells) == 1
    run(game, 2)
    assert game.missiles == [] and game.shells == []


@pytest.mark.parametrize("owner", [BAIT, SHOOTER])
def test_friendly_missiles_pass_through_ships(owner: int) -> None:
    game = new_game()
    target = game.ships[1 - owner]
    side = 1.0 if owner == BAIT else -1.0
    place(target, side * 100.0, 250.0)
    game.missiles.append([side * 40.0, 250.0, side * 20.0, 0.0, owner])  # over the target's centre at frame 3
    events = run(game, 5)
    assert target.alive and not of_kind(events, "death")
    assert game.missiles[0][0] == pytest.approx(side * 140.0)


# ------------------------------------------------------------------ the fortress: lock, turning, firing


def test_lock_goes_to_the_first_ship_in_the_region_and_passes_on() -> None:
    game = new_game()
    run(game, 3)
    assert game.lock == -1  # nobody inside
    place(game.shooter, *INSIDE[SHOOTER])
    assert of_kind(game.step(NOOP, NOOP), "lock") == [(4, "shooter", "")]
    place(game.bait, *INSIDE[BAIT])
    events = run(game, 5)
    assert game.lock == SHOOTER and not of_kind(events, "lock")  # the first ship keeps it
    place(game.shooter, *SHOOTER_SPAWN[:2])  # the locked ship leaves
    assert of_kind(game.step(NOOP, NOOP), "lock") == [(10, "bait", "")]
    place(game.shooter, *INSIDE[SHOOTER])
    run(game, 2)
    assert game.lock == BAIT
    place(game.bait, -20.0, 0.0)  # the locked ship dies (inside the shield)
    events = game.step(NOOP, NOOP)
    assert of_kind(events, "death") == [(13, "bait", "shield")]
    assert game.lock == SHOOTER
    place(game.shooter, *SHOOTER_SPAWN[:2])
    game.step(NOOP, NOOP)
    assert game.lock == -1
    assert game.bait.counters.frames_locked == 3 and game.shooter.counters.frames_locked == 7


def test_lock_tie_goes_to_the_bait() -> None:
    game = new_game()
    place(game.bait, *INSIDE[BAIT])
    place(game.shooter, *INSIDE[SHOOTER])
    assert of_kind(game.step(NOOP, NOOP), "lock") == [(1, "bait", "")]


def test_region_and_shield_hexagons_rotate_with_the_facing() -> None:
    # Facing 0 puts a vertex on +x, so the top of each hexagon is a flat edge at the apothem.
    game = new_game()
    place(game.bait, 0.0, 185.0)
    game.step(NOOP, NOOP)
    assert game.lock == -1
    game._set_facing(30.0)  # now a vertex points up
    game.step(NOOP, NOOP)
    assert game.lock == BAIT
    game = new_game()
    place(game.bait, 0.0, 37.0)
    game.step(NOOP, NOOP)
    assert game.bait.alive
    game._set_facing(30.0)
    game.step(NOOP, NOOP)
    assert not game.bait.alive and game.bait.counters.deaths["shield"] == 1


def test_fortress_holds_its_facing_without_a_target() -> None:
    game = new_game()
    game._set_facing(77.0)
    run(game, 10)
    assert game.facing == pytest.approx(77.0)


@pytest.mark.parametrize(("x", "y"), [(-120.0, 77.0), (0.0, -150.0), (60.0, 140.0)])
def test_fortress_turns_toward_the_target_and_fires_only_when_aimed(x: float, y: float) -> None:
    game = new_game()
    place(game.bait, x, y)
    bearing = math.degrees(math.atan2(y, x)) % 360.0
    error = (bearing - game.facing + 180.0) % 360.0 - 180.0
    for _ in range(80):
        before = game.facing
        events = game.step(NOOP, NOOP)
        turned = (game.facing - before + 180.0) % 360.0 - 180.0
        assert abs(turned) <= 4.0 + 1e-9 and turned * error >= 0.0  # the short way, at most 4 deg
        error = (bearing - game.facing + 180.0) % 360.0 - 180.0
        if of_kind(events, "shell"):
            break
        assert abs(error) > 10.0 or game.frame < 31  # aimed and the interval passed: it must fire
    else:
        raise AssertionError("the fortress never fired")
    assert abs(error) <= 10.0 and game.frame >= 31  # 30 frames after taking the lock at frame 1
    [shell] = game.shells
    rad = math.radians(bearing)
    assert shell == pytest.approx([0.0, 0.0, 6.0 * math.cos(rad), 6.0 * math.sin(rad)], abs=1e-12)
    game.step(NOOP, NOOP)
    assert game.shells[0][:2] == pytest.approx([6.0 * math.cos(rad), 6.0 * math.sin(rad)], abs=1e-12)
    assert game.vulnerable == 19


def test_fire_interval_counts_only_with_a_target_but_vulnerability_always_counts_down() -> None:
    game = new_game()
    game.since_shell, game.vulnerable = 12, 20
    run(game, 5)
    assert (game.since_shell, game.vulnerable) == (12, 15)


def test_fortress_fires_every_30_frames_after_taking_the_lock() -> None:
    game = new_game()
    place(game.bait, *INSIDE[SHOOTER])  # dead ahead of facing 0: aimed from the first frame
    game.since_shell = 100  # taking the lock restarts the interval
    shells = [step_until(game, "shell", clear_shells=True) for _ in range(3)]
    assert shells == [31, 61, 91]
    game.since_shell = 28
    assert step_until(game, "shell", clear_shells=True) == 93


# ------------------------------------------------------------------ vulnerability, kills, shield hits


@pytest.mark.parametrize(("arrival", "killed"), [(20, True), (21, False)])
def test_vulnerable_for_20_frames_from_each_shell(arrival: int, killed: bool) -> None:
    game = new_game()
    place(game.bait, *INSIDE[SHOOTER])  # facing stays 0: the opening is at 180 deg
    launch = step_until(game, "shell")
    assert game.vulnerable == 20
    game.shells.clear()
    run(game, arrival - 4)
    missile_at_centre(game, 180.0, 90.0, SHOOTER)  # at distance 10 on frame launch + arrival
    events = run(game, 4)
    assert game.frame == launch + arrival
    assert len(of_kind(events, "kill")) == game.kills == int(killed)
    assert game.shooter.counters.shield_hits == int(not killed)


@pytest.mark.parametrize("owner", [BAIT, SHOOTER])
@pytest.mark.parametrize("bearing", [180.0, 125.0, 235.0])
def test_missile_through_the_open_rear_arc_kills(owner: int, bearing: float) -> None:
    game = new_game()
    game._set_facing(0.0)
    game.vulnerable = 20
    missile_at_centre(game, bearing, 70.0, owner)
    events = run(game, 3)
    role = game.ships[owner].role
    assert of_kind(events, "kill") == [(3, role, "")]
    assert not game.fortress_alive and game.kills == 1 and game.points == 100
    assert game.ships[owner].counters.kills == 1 and game.ships[1 - owner].counters.kills == 0
    assert game.ships[owner].counters.shield_hits == 0
    assert game.missiles == []


@pytest.mark.parametrize(
    ("vulnerable", "bearing"),
    [(0, 180.0), (20, 0.0), (20, 115.0), (20, 245.0), (20, 90.0)],
    ids=["rear-closed", "front-open", "beside-arc-ccw", "beside-arc-cw", "side-open"],
)
@pytest.mark.parametrize("owner", [BAIT, SHOOTER])
def test_missile_elsewhere_is_absorbed_as_a_shield_hit(owner: int, vulnerable: int, bearing: float) -> None:
    game = new_game()
    game._set_facing(0.0)
    game.vulnerable = vulnerable
    missile_at_centre(game, bearing, 70.0, owner)
    events = run(game, 3)
    assert of_kind(events, "shield_hit") == [(2, game.ships[owner].role, "")]  # touches it at distance 30
    assert game.ships[owner].counters.shield_hits == 1 and game.ships[1 - owner].counters.shield_hits == 0
    assert game.points == -20 and game.kills == 0 and game.fortress_alive
    assert game.missiles == []
    run(game, 5)
    assert game.kills == 0 and game.points == -20


@pytest.mark.parametrize("first", [BAIT, SHOOTER])
def test_simultaneous_kill_is_credited_to_the_earliest_launched_missile(first: int) -> None:
    game = new_game()
    game.vulnerable = 20
    missile_at_centre(game, 170.0, 70.0, first)
    missile_at_centre(game, 190.0, 70.0, 1 - first)
    events = run(game, 3)
    assert of_kind(events, "kill") == [(3, game.ships[first].role, "")]
    assert game.kills == 1 and game.points == 100 and not of_kind(events, "shield_hit")
    assert game.ships[1 - first].counters.kills == 0


def test_shooter_kills_through_the_opening_the_bait_draws() -> None:
    """The team strategy end to end, by actions only."""
    game = new_game()
    place(game.bait, *INSIDE[BAIT])  # draws the lock; the fortress turns its back to the shooter
    for _ in range(80):
        events = game.step(NOOP, FIRE if game.vulnerable else NOOP)
        if game.kills:
            break
    assert of_kind(events, "kill") == [(game.frame, "shooter", "")]
    assert game.bait.alive and game.shooter.counters.shield_hits == 0 and game.points == 100


# ------------------------------------------------------------------ deaths


def _shell_at(distance: float):
    """A shell that is `distance` from the bait's centre after one frame."""
    return lambda game: game.shells.append([-280.0 + distance + 6.0, 0.0, -6.0, 0.0])


@pytest.mark.parametrize(
    ("setup", "cause"),
    [
        (lambda game: place(game.bait, 352.0, 100.0, vx=8.0), "border"),
        (lambda game: place(game.bait, -100.0, -310.0, vy=-8.0), "border"),
        (lambda game: place(game.bait, 45.0, 0.0, vx=-8.0), "shield"),
        (_shell_at(13.0), "shell"),
        (_shell_at(14.0), None),
    ],
    ids=["border-x", "border-y", "shield", "shell-13", "shell-14"],
)
def test_each_death_cause(setup, cause: str | None) -> None:
    game = new_game()
    setup(game)
    events = game.step(NOOP, NOOP)
    if cause is None:
        assert game.bait.alive and game.points == 0 and len(game.shells) == 1
        return
    assert of_kind(events, "death") == [(1, "bait", cause)]
    assert not game.bait.alive and game.shooter.alive
    assert game.points == -100
    assert game.bait.counters.deaths == {c: int(c == cause) for c in ("shell", "border", "shield")}
    assert game.shells == []  # a shell that hits is removed
    run(game, 40)
    assert not game.bait.alive  # dead until the round ends


@pytest.mark.parametrize("bait_alive", [True, False])
def test_a_shell_hits_the_first_living_ship_only(bait_alive: bool) -> None:
    game = new_game()
    place(game.bait, -5.0, 250.0)
    place(game.shooter, 5.0, 250.0)
    game.bait.alive = bait_alive
    game.shells.append([0.0, 256.0, 0.0, -6.0])  # 5 px from both ships after one frame
    events = game.step(NOOP, NOOP)
    assert of_kind(events, "death") == [(1, "bait" if bait_alive else "shooter", "shell")]
    assert game.shooter.alive == bait_alive and game.shells == []


def test_both_dead_reset_after_30_frames_resets_ships_and_fortress() -> None:
    game = new_game()
    place(game.bait, *INSIDE[BAIT])
    step_until(game, "shell")
    assert game.facing != 0.0 and game.lock == BAIT and game.vulnerable
    for ship in game.ships:
        border_kill(ship)
    death = game.frame + 1
    run(game, 29)
    assert not game.bait.alive and not game.shooter.alive and game.frame == death + 28
    game._set_facing(123.0)
    game.vulnerable, game.since_shell = 9, 12
    game.shells.append([0.0, 250.0, 0.0, 0.0])
    game.missiles.append([0.0, -250.0, 0.0, 0.0, BAIT])
    events = game.step(NOOP, NOOP)
    assert not game.bait.alive and [e.kind for e in events] == []
    events = game.step(NOOP, NOOP)
    assert game.frame == death + 30 and [e.kind for e in events] == ["reset"]
    for ship, (x, y, heading) in zip(game.ships, (BAIT_SPAWN, SHOOTER_SPAWN), strict=True):
        assert ship.alive and (ship.x, ship.y, ship.heading, ship.vx, ship.vy) == (x, y, heading, 0.0, 0.0)
    assert (game.facing, game.lock, game.since_shell, game.vulnerable) == (0.0, -1, 0, 0)
    assert game.fortress_alive and game.shells == [] and game.missiles == []
    assert game.points == -200 and game.kills == 0


# ------------------------------------------------------------------ after a kill


def test_after_a_kill_dead_ships_respawn_and_the_fortress_waits_for_the_region_to_clear() -> None:
    game = new_game()
    border_kill(game.bait)
    game.step(NOOP, NOOP)
    assert not game.bait.alive
    place(game.shooter, *INSIDE[SHOOTER])
    events = kill_fortress(game, SHOOTER)
    assert of_kind(events, "respawn") == [(game.frame, "bait", "")]
    assert game.bait.alive and (game.bait.x, game.bait.y, game.bait.heading) == BAIT_SPAWN
    assert (game.shooter.x, game.shooter.y) == INSIDE[SHOOTER]  # a living ship stays where it is
    assert game.points == 0 and game.lock == -1
    for _ in range(60):
        game.step(NOOP, NOOP)
        assert not game.fortress_alive and game.shells == []
    place(game.shooter, *SHOOTER_SPAWN[:2])
    events = game.step(NOOP, NOOP)
    assert [e.kind for e in events] == ["fortress_respawn"] and game.fortress_alive
    assert (game.lock, game.since_shell, game.vulnerable) == (-1, 0, 0)


def test_fortress_stays_down_at_least_30_frames() -> None:
    game = new_game()
    kill_fortress(game, BAIT)
    kill = game.frame
    run(game, 29)
    assert not game.fortress_alive
    assert of_kind(game.step(NOOP, NOOP), "fortress_respawn") == [(kill + 30, "", "")]
    assert game.fortress_alive and game.vulnerable == 0


def test_no_shield_while_the_fortress_is_down() -> None:
    game = new_game()
    kill_fortress(game, BAIT)
    place(game.bait, -60.0, 0.0, vx=8.0)  # flies straight across the fortress's place
    missile = missile_at_centre(game, 90.0, 100.0, SHOOTER)  # and so does this missile
    events = run(game, 15)
    assert game.bait.alive and game.bait.x > 40.0 and not of_kind(events, "death")
    assert game.missiles == [missile] and missile[1] == pytest.approx(-200.0)
    assert not of_kind(events, "shield_hit") and game.points == 100


def test_ship_dying_while_the_fortress_is_down_returns_with_it() -> None:
    game = new_game()
    kill_fortress(game, BAIT)
    border_kill(game.bait)
    run(game, 10)
    assert not game.bait.alive
    events = run(game, 30)
    assert game.fortress_alive and game.bait.alive and of_kind(events, "respawn")
    assert (game.bait.x, game.bait.y) == BAIT_SPAWN[:2]


# ------------------------------------------------------------------ game length, determinism, input


def test_game_lasts_1800_frames_and_refuses_more() -> None:
    game = Game(GameConfig(), seed=3)
    run(game, 1799)
    assert not game.done
    game.step(NOOP, NOOP)
    assert game.done and game.frame == 1800
    with pytest.raises(ValueError):
        game.step(NOOP, NOOP)
    assert game.frame == 1800


def _hashes(seed: int, actions: list[tuple[int, int]]) -> list[str]:
    game = Game(GameConfig(), seed=seed)
    hashes = [game.state_hash()]
    for bait, shooter in actions:
        game.step(bait, shooter)
        hashes.append(game.state_hash())
    assert game.spawns > 2  # respawns drew on the seeded generator too
    return hashes


def test_same_config_seed_and_actions_give_identical_states() -> None:
    rng = random.Random(11)
    actions = [(rng.randrange(12), rng.randrange(12)) for _ in range(600)]
    first = _hashes(5, actions)
    assert first == _hashes(5, actions)
    assert len(set(first)) > 500


def test_different_seeds_give_different_spawns() -> None:
    spawns = set()
    for seed in range(5):
        game = Game(GameConfig(), seed=seed)
        spawns.add(tuple((ship.x, ship.y, ship.heading) for ship in game.ships))
    assert len(spawns) == 5


def test_spawn_jitter_stays_within_20_px_and_30_deg() -> None:
    offsets = []
    for seed in range(50):
        game = Game(GameConfig(), seed=seed)
        assert game.facing == 0.0 and game.fortress_alive and game.lock == -1
        for ship, (x, y, heading) in zip(game.ships, (BAIT_SPAWN, SHOOTER_SPAWN), strict=True):
            offsets.append(
                (math.hypot(ship.x - x, ship.y - y), (ship.heading - heading + 180.0) % 360.0 - 180.0)
            )
            assert (ship.vx, ship.vy, ship.alive) == (0.0, 0.0, True)
    assert max(d for d, _ in offsets) <= 20.0 and max(abs(a) for _, a in offsets) <= 30.0
    assert max(d for d, _ in offsets) > 15.0 and max(abs(a) for _, a in offsets) > 25.0  # jitter is used


@pytest.mark.parametrize("role", ["bait", "shooter"])
@pytest.mark.parametrize("bad", [12, -1, 3.0, True, False, None, "3"], ids=repr)
def test_bad_action_raises_naming_player_and_value_and_changes_nothing(role: str, bad: object) -> None:
    game = new_game()
    run(game, 5, bait=THRUST + FIRE, shooter=LEFT)
    before = (game.state_hash(), game.frame)
    actions = (bad, NOOP) if role == "bait" else (NOOP, bad)
    with pytest.raises(ValueError, match=rf"{role}.*{re.escape(repr(bad))}"):
        game.step(*actions)
    assert (game.state_hash(), game.frame) == before


# ------------------------------------------------------------------ properties under random play

_ACTION = st.integers(0, 11)
_START = st.tuples(st.floats(-340.0, 340.0), st.floats(-300.0, 300.0), st.floats(0.0, 359.0))
_SHOTS = st.lists(st.tuples(st.floats(0.0, 360.0), st.floats(50.0, 300.0)), max_size=5)


def check_invariants(game: Game) -> None:
    c = game.config
    assert all(math.isfinite(v) for v in game.state_values())
    for ship in game.ships:
        if ship.alive:
            assert abs(ship.x) <= c.arena_x and abs(ship.y) <= c.arena_y
            assert math.hypot(ship.vx, ship.vy) <= c.ship_max_speed + 1e-9
    assert game.kills == sum(ship.counters.kills for ship in game.ships)
    shield_hits = sum(ship.counters.shield_hits for ship in game.ships)
    assert game.points == 100 * game.kills - 100 * total_deaths(game) - 20 * shield_hits
    for owner in (BAIT, SHOOTER):
        assert sum(1 for m in game.missiles if m[4] == owner) <= c.missiles_in_flight
    assert 0 <= game.vulnerable <= c.vulnerable_frames and 0.0 <= game.facing < 360.0


@settings(max_examples=50, derandomize=True, deadline=None, database=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    starts=st.tuples(_START, _START),
    shots=st.tuples(_SHOTS, _SHOTS),
    vulnerable=st.integers(0, 20),
    segments=st.lists(st.tuples(_ACTION, _ACTION, st.integers(5, 60)), min_size=4, max_size=16),
)
def test_invariants_hold_under_random_play(seed, starts, shots, vulnerable, segments) -> None:
    game = Game(GameConfig(), seed=seed)
    for ship, (x, y, heading) in zip(game.ships, starts, strict=True):
        place(ship, x, y, heading)
    for owner, owner_shots in enumerate(shots):
        for bearing, dist in owner_shots:
            missile_at_centre(game, bearing, dist, owner)
    game.vulnerable = vulnerable
    events: list[Event] = []
    for bait, shooter, repeat in segments:
        for _ in range(repeat):
            events += game.step(bait, shooter)
            check_invariants(game)
    assert len(of_kind(events, "kill")) == game.kills
    assert len(of_kind(events, "death")) == total_deaths(game)
