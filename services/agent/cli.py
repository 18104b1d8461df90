"""`tsf` commands for playing and training policies in-process: game, calibrate, train, library."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from services.agent.calibration import calibrate
from services.agent.library import policy_for
from services.options import GAMES, console, number, output
from services.sim.play import play, summarize
from shared.errors import Failure, UsageError
from shared.game import FPS, FRAMES, SEEDS, GameConfig, Range

commands = typer.Typer()
STEPS = Range(1, 10**9)  # environment steps of one training


@commands.command()
def game(
    bait: str = typer.Option("circle", help="Bait seat's policy key."),
    shooter: str = typer.Option("mirror", help="Shooter seat's policy key."),
    seed: int = number(0, SEEDS, "Seed of the first game; game i uses seed + i."),
    games: int = number(1, GAMES, "Number of games."),
    frames: int = number(GameConfig.frames, FRAMES, f"Frames per game ({FPS} per second)."),
) -> None:
    """Play headless games in-process between two policies and print the score."""
    if seed + games - 1 not in SEEDS:
        raise UsageError(
            "--seed", seed, f"the last game's seed {seed + games - 1} is outside the range {SEEDS}"
        )
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
def calibrate_command(
    games: int = number(20, Range(2, GAMES.high), "Seeded one-minute games per pair."),
) -> None:
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
    out: Path = output(
        Path("tsf-library"),
        "The library the weights and manifest go to; a new directory starts as a copy of the "
        "shipped library. The shipped library itself is written only when named here.",
        directory=True,
        names=("--library", "--out"),
    ),
    steps: int | None = number(None, STEPS, "Environment steps (default: the recipe's)."),
    seed: int | None = number(None, SEEDS, "Training seed (default: the recipe's)."),
    runs: Path = output(Path("runs"), "Learning curves and checkpoints go to RUNS/KEY.", directory=True),
    figures: Path | None = output(None, "Also draw each learning curve to FIGURES/train_KEY.png.", True),
    warm_start: bool = typer.Option(
        False, help="Imitate the recipe's scripted demonstrator before RL (not the shipped recipes)."
    ),
    jobs: int = number(1, Range(1, 64), "Policies trained at once (processes)."),
    score_games: int = number(
        20, Range(0, GAMES.high), "Games scored with the first partner after training."
    ),
) -> None:
    """Train library policies by their registry recipes into a library directory (needs the
    `train` extra). A run stopped part way resumes from its last checkpoint in RUNS/KEY."""
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
            f"{key}: {entry['steps']:,} steps in {entry['seconds']} s, {out / entry['file']} "
            f"sha256 {entry['sha256'][:12]}" + (f", {_score_text(score)}" if score else "")
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
