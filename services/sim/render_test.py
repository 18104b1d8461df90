import numpy as np

from services.agent.scripted import CircleBait, Idle
from services.sim.engine import Game
from services.sim.observation import observe
from services.sim.render import OPENING, SHIP_COLOURS, render


def _pixel(game: Game, image: np.ndarray, x: float, y: float, scale: float) -> np.ndarray:
    c = game.config
    return image[round((c.arena_y - y) * scale), round((x + c.arena_x) * scale)]


def _codes(image: np.ndarray) -> np.ndarray:
    """One integer per pixel colour, so that colour comparisons are single array operations."""
    return (image[..., 0].astype(np.int32) << 16) | (image[..., 1].astype(np.int32) << 8) | image[..., 2]


def _code(colour: tuple[int, int, int]) -> int:
    return (colour[0] << 16) | (colour[1] << 8) | colour[2]


def _count(image: np.ndarray, colour: tuple[int, int, int]) -> int:
    return int(np.count_nonzero(_codes(image) == _code(colour)))


def test_image_shape_dtype_and_ships_in_their_colours():
    game = Game(seed=0)
    for scale in (1.0, 2.0):
        image = render(game, scale)
        assert image.dtype == np.uint8
        assert image.shape == (round(626 * scale) + 1, round(710 * scale) + 1, 3)
        assert len(np.unique(_codes(image))) >= 6
        for ship in game.ships:
            assert tuple(_pixel(game, image, ship.x, ship.y, scale)) == SHIP_COLOURS[ship.role]


def test_a_dead_ship_is_not_drawn():
    game = Game(seed=0)
    game.bait.alive = False
    image = render(game)
    assert _count(image, SHIP_COLOURS["bait"]) == 0
    assert _count(image, SHIP_COLOURS["shooter"]) > 200


def test_the_rear_arc_opens_only_while_vulnerable():
    game = Game(seed=0)
    bait, shooter = CircleBait(), Idle("shooter")
    while game.vulnerable == 0:
        assert _count(render(game), OPENING) == 0
        game.step(bait.act(observe(game, "bait")), shooter.act(observe(game, "shooter")))
    image = render(game)
    assert _count(image, OPENING) > 50
    rows, cols = np.nonzero(_codes(image) == _code(OPENING))
    c = game.config
    x, y = cols.mean() - c.arena_x, c.arena_y - rows.mean()
    facing = np.radians(game.facing)
    assert x * np.cos(facing) + y * np.sin(facing) < -0.8 * np.hypot(x, y)  # opposite the facing
