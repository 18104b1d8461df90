"""The `tsf` command line: one entry point that each service and tool adds its commands to."""

from __future__ import annotations

import typer
from rich.console import Console
from rich.table import Table

from services.agent.scripted import scripted_policy
from services.sim.calibration import calibrate
from services.sim.config import GameConfig
from services.sim.play import play, summarize

app = typer.Typer(no_args_is_help=True, add_completion=False, help="Team Space Fortress.")
console = Console()


@app.command()
def game(
    bait: str = typer.Option("circle", help="Bait seat's policy key."),
    shooter: str = typer.Option("mirror", help="Shooter seat's policy key."),
    seed: int = typer.Option(0, help="Seed of the first game; game i uses seed + i."),
    games: int = typer.Option(1, min=1, help="Number of games."),
    frames: int = typer.Option(GameConfig.frames, min=1, help="Frames per game (30 per second)."),
) -> None:
    """Play headless games in-process between two policies and print the score."""
    config = GameConfig(frames=frames)
    results = []
    for s in range(seed, seed + games):
        result = play(scripted_policy(bait, "bait"), scripted_policy(shooter, "shooter"), s, config)
        results.append(result)
        deaths = {role: sum(c["deaths"].values()) for role, c in result.counters.items()}
        console.print(
            f"game seed={s}: {result.kills} kills in {result.frames} frames "
            f"({result.kills_per_minute:.1f}/min), points {result.points}, deaths {deaths}"
        )
    if games > 1:
        console.print(f"{bait} + {shooter}: {summarize(results)}")


@app.command("calibrate")
def calibrate_command(games: int = typer.Option(20, min=2, help="Seeded one-minute games per pair.")) -> None:
    """Score the calibration pairs of the rules page (mean and standard error of kills/min)."""
    table = Table(title=f"Calibration: kills per minute over {games} seeded one-minute games")
    for column in ("pair", "bait seat", "shooter seat", "kills/min", "s.e."):
        table.add_column(column)
    for label, bait, shooter, summary in calibrate(games):
        table.add_row(label, bait, shooter, f"{summary.mean:.2f}", f"{summary.stderr:.2f}")
    console.print(table)


if __name__ == "__main__":
    app()
