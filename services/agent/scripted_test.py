"""The orbit bait: it holds its radius (feedback on the radial error), stays inside the turning
activation hexagon where the circle of the same radius leaves it, waits just outside it while the
fortress is down, gives distributions, plays the same in its scalar and its compiled batch form,
and is a rule of the grammar."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.agent.scripted import CircleBait, MirrorShooter, OrbitBait, region_edge, scripted_keys
from services.sim import observation as ob
from services.sim.engine import Game
from services.sim.observation import observe

SETTLE = 150  # frames of orbiting (the bait alive, the fortress up) before a frame is judged


def _flight(bait, shooter, frames: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Over one game's first `frames` frames: the bait's distance from the fortress and whether it
    was in the region on the frames after SETTLE frames of orbiting (NaN and False on the others:
    the spawn, a death, the fortress down and the way back in), and the bait's observations."""
    game, radii, inside, seen, orbiting = Game(seed=seed), [], [], [], 0
    bait.reset(seed), shooter.reset(seed)
    for _ in range(frames):
        obs = observe(game, "bait", bait.view)
        orbiting = orbiting + 1 if game.bait.alive and game.fortress_alive else 0
        radii.append(math.hypot(game.bait.x, game.bait.y) if orbiting > SETTLE else np.nan)
        inside.append(orbiting > SETTLE and game.bait.in_region)
        seen.append(obs)
        game.step(bait.act(obs), shooter.act(observe(game, "shooter", shooter.view)))
    return np.array(radii), np.array(inside), seen


def _settled(bait, seeds: tuple[int, ...] = (0, 1)) -> tuple[np.ndarray, float]:
    """The settled frames' distances from the fortress and share in the region, over `seeds`' games
    with a mirror shooter that never fires (the fortress stays up: the orbit alone is judged)."""
    flights = [_flight(bait, MirrorShooter(rear_tolerance=-1.0), 1800, seed)[:2] for seed in seeds]
    radii = np.concatenate([r for r, _ in flights])
    inside = sum(int(i.sum()) for _, i in flights)
    return radii[~np.isnan(radii)], inside / int((~np.isnan(radii)).sum())


def test_it_holds_its_radius():
    """Settled, the orbit stays within a few px of its radius (the misses are its sidesteps from
    shells), its 90th percentile nearer than the circle's."""
    orbit, _ = _settled(OrbitBait(radius=170.0, speed=1.5, gain=0.2, damping=20.0))
    circle, _ = _settled(CircleBait(radius=170.0, speed=1.5))
    error = np.abs(orbit - 170.0)
    assert len(orbit) > 1000 and np.median(error) < 4.0 and np.percentile(error, 90) < 10.0
    assert np.percentile(error, 90) < np.percentile(np.abs(circle - 170.0), 90)


def test_it_stays_in_the_turning_hexagon_where_the_circle_leaves_it():
    """At radius 195 the circle spends most frames outside the hexagon (its flat sides are 173 px
    out); the orbit aims at the hexagon's edge less its margin and stays in, near the edge."""
    radii, orbit_in = _settled(OrbitBait(radius=195.0, margin=10.0))
    _, circle_in = _settled(CircleBait(radius=195.0, speed=1.5))
    assert orbit_in > 0.6 and circle_in < 0.3
    assert np.median(radii) > 180.0


def test_it_waits_just_outside_the_hexagon_while_the_fortress_is_down():
    """With a shooter that kills, the fortress respawns without the orbit's leaving far: it stays
    within its clearance of the edge while down, where the circle goes out to `outside`."""
    game, bait, shooter, down = Game(seed=0), OrbitBait(radius=170.0, clear=10.0), MirrorShooter(), []
    for _ in range(1800):
        obs = observe(game, "bait", bait.view)
        if not game.fortress_alive and game.bait.alive:
            down.append(math.hypot(game.bait.x, game.bait.y))
        game.step(bait.act(obs), shooter.act(observe(game, "shooter", shooter.view)))
    assert len(down) > 100 and max(down) < 230.0


def test_the_region_edge_is_the_hexagons():
    assert region_edge(200.0, 0.0, 0.0) == pytest.approx(200.0)  # a vertex on the facing
    assert region_edge(0.0, 200.0, math.pi / 2) == pytest.approx(200.0)
    assert region_edge(math.cos(math.pi / 6), math.sin(math.pi / 6), 0.0) == pytest.approx(
        200 * math.cos(math.pi / 6)
    )


def test_probs_are_distributions_and_scalar_and_batch_agree():
    """Rows from a game where it places itself by a moving shooter (both branches: the fortress up
    and down), with placement and lead in play."""
    bait = OrbitBait(radius=160.0, speed=0.5, place=1.5, lead=20.0)
    _, _, seen = _flight(bait, MirrorShooter(max_speed=7.0), 900)
    obs = np.stack(seen).astype(np.float32)
    assert (obs[:, ob.FORTRESS + ob.F_ALIVE] < 0.5).any()  # it killed: the leaving branch was played
    batch = bait.probs_batch(obs)
    np.testing.assert_allclose(batch, np.array([bait.probs(o) for o in obs]), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(batch.sum(axis=1), 1.0)
    assert (bait.rule_batch(obs) == np.array([bait.rule(o) for o in obs])).all()


def test_it_is_a_bait_rule_of_the_grammar():
    from services.population.seat import RuleSeat, seats_of

    assert "orbit" in scripted_keys("bait") and "orbit" not in scripted_keys("shooter")
    from shared.errors import UsageError

    (seat,) = seats_of(["orbit(radius=190,speed=2,place=1.5)"])
    assert seat == RuleSeat("orbit", (("radius", 190.0), ("speed", 2.0), ("place", 1.5)))
    with pytest.raises(UsageError, match="not SETTING=NUMBER for a setting of orbit"):
        seats_of(["orbit(angle=3)"])


def test_orbits_stacked_in_one_batch_play_the_games_each_plays_alone():
    """Bulk play (play_pairs: the rules of one kind as one stack, every pair a lane) gives each
    orbit setting the very game it plays in a batch of its own."""
    from services.sim.batch_play import play_batch, play_pairs

    orbits = [OrbitBait(), OrbitBait(radius=150.0, speed=2.5, place=2.0, lead=-30.0, clear=25.0)]
    shooter = MirrorShooter(max_speed=7.0)
    together = play_pairs(orbits, [shooter], np.array([0, 1, 1]), np.zeros(3, np.int64), [0, 0, 1])
    alone = [play_batch(orbits[0], shooter, [0])[0], *play_batch(orbits[1], shooter, [0, 1])]
    assert [g.counters for g in together] == [g.counters for g in alone]
    assert together[0].counters != together[1].counters  # two settings, two games
    assert [g.kills for g in together] == [g.kills for g in alone] and sum(g.kills for g in alone) > 0
