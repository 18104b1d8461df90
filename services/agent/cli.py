"""`tsf` commands for playing and training policies in-process: game, calibrate, train, library."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from services.agent.calibration import calibrate
from services.agent.library import policy_for
from services.options import console
from services.sim.play import play, summarize
from shared.errors import Failure, UsageError
from shared.game import FPS, GameConfig

commands = typer.Typer()


@commands.command()
def game(
    bait: str = typer.Option("circle", help="Bait seat's policy key."),
    shooter: str = typer.Option("mirror", help="Shooter seat's policy key."),
    seed: int = typer.Option(0, help="Seed of the first game; game i uses seed + i."),
    games: int = typer.Option(1, min=1, help="Number of games."),
    frames: int = typer.Option(GameConfig.frames, min=1, help=f"Frames per game ({FPS} per second)."),
) -> None:
    """Play headless games in-process between two policies and print the score."""
    config = GameConfig(frames=frames)
    results = []
    for s in range(seed, seed + games):
        result = play(
            policy_for(bait, "bait", "--bait"), policy_for(shooter, "shooter", "--shooter"), s, config
        )
        results.append(result)
        deaths = {role: sum(c["deaths"].values()) for role, c in result.counters.items()}
        console.print(
            f"game seed={s}: {result.kills} kills in {result.frames} frames "
            f"({result.kills_per_minute:.1f}/min), points {result.points}, deaths {deaths}"
        )
    if games > 1:
        console.print(f"{bait} + {shooter}: {summarize(results)}")


@commands.command("calibrate")
def calibrate_command(games: int = typer.Option(20, min=2, help="Seeded one-minute games per pair.")) -> None:
    """Score the calibration pairs of the rules page (mean and standard error of kills/min)."""
    table = Table(title=f"Calibration: kills per minute over {games} seeded one-minute games")
    for column in ("pair", "bait seat", "shooter seat", "kills/min", "s.e."):
        table.add_column(column)
    for label, bait, shooter, summary in calibrate(games):
        table.add_row(label, bait, shooter, f"{summary.mean:.2f}", f"{summary.stderr:.2f}")
    console.print(table)


@commands.command()
def train(
    keys: list[str] = typer.Argument(None, help="Library keys to train."),
    all_: bool = typer.Option(False, "--all", help="Train every learned policy of the library."),
    out: Path = typer.Option(
        Path("tsf-library"),
        "--library",
        help="Library to train into; a new one starts as a copy of the shipped library. "
        "Retraining the shipped library needs its path: --library services/agent/library.",
    ),
    steps: int | None = typer.Option(None, min=1, help="Environment steps (default: the recipe's)."),
    seed: int | None = typer.Option(None, min=0, help="Training seed (default: the recipe's)."),
    runs: Path = typer.Option(Path("runs"), help="Learning curves and checkpoints go to RUNS/KEY."),
    figures: Path | None = typer.Option(None, help="Also draw each learning curve to FIGURES/train_KEY.png."),
    warm_start: bool = typer.Option(
        False, help="Imitate the recipe's scripted demonstrator before RL (not the shipped recipes)."
    ),
    jobs: int = typer.Option(1, min=1, max=64, help="Policies trained at once (processes)."),
    score_games: int = typer.Option(
        20, min=0, max=1000, help="Games scored with the first partner after training."
    ),
) -> None:
    """Train library policies by their registry recipes (needs the `train` extra). A run stopped
    part way resumes from its last checkpoint in RUNS/KEY."""
    import time

    from services.agent import library

    if bool(keys) == all_:
        raise UsageError("KEYS", " ".join(keys or []) or "(none)", "give library keys or --all, not both")
    todo = library.learned(keys or [])
    try:
        from services.agent.train import train_library
    except ModuleNotFoundError as error:
        raise Failure(f"{error}: training needs the `train` extra, pip install -e '.[train]'") from None
    started = time.monotonic()
    console.print(f"training {', '.join(todo)} into {out}, {jobs} at a time")
    options = {"steps": steps, "seed": seed, "run_dir": runs, "figures": figures}
    options |= {"warm_start": warm_start, "score_games": score_games, "progress": jobs == 1}
    entries = train_library(todo, out, jobs, **options)
    for key, entry in entries.items():
        score = entry.get("score")
        console.print(
            f"{key}: {entry['steps']:,} steps in {entry['seconds']} s, sha256 {entry['sha256'][:12]}"
            + (f", {_score_text(score)}" if score else "")
        )
    console.print(f"trained {len(entries)} policies in {time.monotonic() - started:.0f} s (wall)")


def _score_text(score: dict) -> str:
    return f"{score['kills_per_minute']:.2f} ± {score['stderr']:.2f} kills/min with {score['partner']}"


@commands.command("library")
def library_command() -> None:
    """List the policy library: recipe, training record and score of each policy."""
    from services.agent import library

    manifest = library.manifest()
    table = Table(title=f"Policy library (manifest {library.manifest_hash()})")
    for column in ("key", "role", "family", "algorithm", "steps", "seed", "score"):
        table.add_column(column)
    for key, recipe in library.registry().items():
        entry = manifest.get(key, {})
        score = entry.get("score")
        steps = entry.get("steps", "untrained" if recipe.algorithm else "-")
        seed = str(entry.get("seed", "-"))
        score = _score_text(score) if score else "-"
        table.add_row(key, recipe.role, recipe.family, recipe.algorithm or "rule", str(steps), seed, score)
    console.print(table)
