"""`tsf` commands for playing and training policies in-process: game, calibrate, train, library."""

from __future__ import annotations

import enum
import os
import time
from pathlib import Path

import typer
from rich.table import Table

from services.agent.calibration import calibrate
from services.agent.library import NAMED
from services.agent.seats import policy_for
from services.commands.options import (
    GAMES,
    LOCAL_WORKERS,
    RAY,
    WORKERS,
    Duration,
    Frames,
    Role,
    bus_options,
    console,
    game_frames,
    keys_help,
    number,
    output,
)
from services.population.families import SPEC
from services.sim.observation import VIEWS
from services.sim.play import play, summarize
from shared.bus import BusConfig, stop_on_signals
from shared.errors import Failure, UsageError, missing_extra
from shared.game import SEEDS, GameConfig, Range

commands = typer.Typer()
STEPS = Range(1, 10**9)  # environment steps of one training
STEPS_OR_DEFAULT = Range(0, 10**9)
SEARCH_TRIALS = Range(1, 10_000)  # settings one search plays
SCORED = Range(0, GAMES.high)  # games a trained or added policy is scored over (0: not scored)
View = enum.Enum("View", {v: v for v in VIEWS}, type=str)


@commands.command()
def game(
    bait: str = typer.Option("circle", help=keys_help("bait", "Bait seat's policy key")),
    shooter: str = typer.Option("mirror", help=keys_help("shooter", "Shooter seat's policy key")),
    seed: int = number(0, SEEDS, "Seed of the first game; game i uses seed + i."),
    games: int = number(1, GAMES, "Number of games."),
    duration: Duration = None,
    frames: Frames = None,
) -> None:
    """Play headless games in-process between two policies and print the score."""
    if seed + games - 1 not in SEEDS:
        raise UsageError(
            "--seed", seed, f"the last game's seed {seed + games - 1} is outside the range {SEEDS}"
        )
    config = GameConfig(frames=game_frames(duration, frames))
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
    score_games: int = number(20, SCORED, "Games scored with the first library partner after training."),
    every: int = number(250_000, STEPS, "Environment steps between the curve's points and checkpoints."),
) -> None:
    """Train library policies by their registry recipes into a library directory (needs the
    `train` extra). A run stopped part way resumes from its last checkpoint in RUNS/KEY."""
    from services.agent import library

    if bool(keys) == all_:
        raise UsageError("KEYS", " ".join(keys or []) or "(none)", "give library keys or --all, not both")
    todo = library.learned(keys or [])
    try:
        from services.training.loop import train_library
    except ModuleNotFoundError as error:
        raise Failure(f"training {missing_extra(error) or error}") from None
    started = time.monotonic()
    console.print(f"training {', '.join(todo)} into {out}, {jobs} at a time")
    options = {"steps": steps, "seed": seed, "run_dir": runs, "figures": figures}
    options |= {"warm_start": warm_start, "score_games": score_games, "progress": jobs == 1, "every": every}
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


library_commands = typer.Typer(
    invoke_without_command=True, help="List the policy library; `tsf library add` adds a model of yours."
)
commands.add_typer(library_commands, name="library")


@library_commands.callback()
def library_command(context: typer.Context) -> None:
    """List the policy library (and those in TSF_LIBRARY): each policy's recipe, record and score."""
    if context.invoked_subcommand is not None:
        return
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
        algorithm = entry.get("algorithm") or recipe.algorithm or "rule"
        table.add_row(key, recipe.role, recipe.family, algorithm, str(steps), seed, score)
    console.print(table)


@library_commands.command("add")
def library_add(
    key: str = typer.Argument(..., help="The new policy's key (a letter, then letters, digits, - and _)."),
    model: Path = typer.Argument(
        ...,
        help="A Stable-Baselines3 model (.zip) trained on tsf/Role-v0, or a proxy (tsf proxy train).",
    ),
    role: Role = typer.Option(..., help="The seat it plays."),
    library_dir: Path = output(
        ..., "Your library directory (created if need be).", directory=True, names=("--library",)
    ),
    view: View = typer.Option(View.world, help="The observation view it was trained on."),
    partner: str = typer.Option(
        "",
        help="Partner it is scored with, a key `tsf keys` lists (default: S5 for a bait, B5 for a shooter).",
    ),
    games: int = number(10, SCORED, "One-minute games it is scored over (0: not scored)."),
) -> None:
    """Export an SB3 model into a library of yours: numpy weights, registry and manifest entries with
    hashes and provenance. List the directory in TSF_LIBRARY to play its keys everywhere."""
    from services.agent.add import add

    entry = add(key, model, role, library_dir, view.value, partner, games)
    console.print(f"{key}: {library_dir / entry['file']} sha256 {entry['sha256'][:12]}")
    if entry.get("score"):
        console.print(f"  {_score_text(entry['score'])}")
    console.print(f"  play it everywhere with TSF_LIBRARY={library_dir.resolve()}")


@library_commands.command("grow")
@bus_options
def library_grow(
    population: Path = typer.Option(
        SPEC, "--population", help="The partner population's spec (default: the shipped population.toml)."
    ),
    out: Path = output(
        Path("tsf-grown"),
        "Directory of the run: the population, cross-play, groups, responses, selection, the grown "
        "library (OUT/library) and summary.md; run the same command again to resume.",
        directory=True,
    ),
    workers: int = LOCAL_WORKERS,
    ray: str | None = RAY,
    *,
    bus: BusConfig,
) -> None:
    """Grow a library for coverage: a generated partner population per seat, its cross-play, groups
    by what works with them, a PPO best response per group, and the members that leave an adaptive
    teammate the most room (held-out oracle headroom on the validation population); then the grown
    library's table, calibration and the test population's figures (docs/library.md)."""
    summary = _grow(population, out, workers, ray, bus, "tsf library grow").run()
    console.print((out / "summary.md").read_text())
    console.print(
        f"the grown library: TSF_LIBRARY={(out / 'library').resolve()} ({len(summary['members'])} members)"
    )


@library_commands.command("search")
def library_search(
    seat: Role = typer.Option(..., help="Our seat: its rule (mirror or circle) is searched."),
    family: str | None = typer.Option(
        None, "--family", help="The rule to search (default: the seat's own; the bait seat also has orbit)."
    ),
    trials: int = number(100, SEARCH_TRIALS, "Settings played in all (every study asks one a round)."),
    seeds: int = number(8, GAMES, "Seeded games per (partner, setting) pair, in the search and the test."),
    seed: int = number(0, SEEDS, "The sampler's seed."),
    run: Path | None = typer.Option(
        None, "--run", help="A grown run's library, with its run's records (default: the shipped grown one)."
    ),
    out: Path = output(
        Path("tsf-search"),
        "Where the search writes its trials (search-SEAT.json, resumed by running again) and its "
        "figures (measured-SEAT.json).",
        directory=True,
    ),
) -> None:
    """Tune our seat's rule by search (Optuna's TPE) on a grown run's training members, per partner
    group and over them all, without retraining anything; then measure each group's best setting on
    the run's test split against the run's best member and the study library's best static."""
    from services.growth.searched import check_run, families, markdown, search_run

    if family is not None and family not in families(str(seat)):
        raise UsageError("--family", family, f"is no searchable rule of the {seat} seat", families(str(seat)))
    run = run or NAMED["grown"]
    check_run(run)
    console.print(markdown(search_run(str(seat), run, out, trials, seeds, seed, family)), soft_wrap=True)


@library_commands.command("condition")
@bus_options
def library_condition(
    out: Path = typer.Argument(..., help="The directory of a finished `tsf library grow` run."),
    seat: Role = typer.Option(..., help="Our seat: the conditioned teammate plays it."),
    steps: int = number(
        0,
        STEPS_OR_DEFAULT,
        "PPO steps (0: the spec's response steps, times the partner groups for the conditioned network).",
    ),
    separate: bool = typer.Option(
        False, "--separate", help="Each group's best response trained on to --steps instead, compared alike."
    ),
    population: Path = typer.Option(SPEC, "--population", help="The run's partner population spec."),
    workers: int = number(os.cpu_count() or 1, WORKERS, "Worker processes to start here."),
    ray: str | None = RAY,
    *,
    bus: BusConfig,
) -> None:
    """Try the conditioned teammate: one PPO network told its partner's group, trained with every
    group at once, against switching among the grown library's members (and the groups' best
    responses), the partner's group given to both, on the run's validation and test partners. Writes
    OUT/conditioned-SEAT-STEPS/ (the network told each group, as a library) and its .json; with
    --separate, OUT/responses-SEAT-STEPS/ and its .json."""
    from services.growth.conditioned import markdown, run_conditioned

    if not (out / "library" / "groups.json").exists():
        raise UsageError("OUT", out, "is no finished `tsf library grow` run (no library/groups.json)")
    grow = _grow(population, out, workers, ray, bus, "tsf library condition")
    console.print(markdown(run_conditioned(grow, str(seat), steps or None, separate)))


def _grow(population: Path, out: Path, workers: int, ray: str | None, bus: BusConfig, command: str):  # noqa: ANN202
    """A Grow over `out` whose stages' jobs run on the job engine (workers here, on the bus, or Ray)."""
    from contextlib import contextmanager
    from importlib.util import find_spec

    from services.growth.grow import KINDS, Grow
    from services.jobs.engine import on_workers, open_engine
    from services.population.families import read

    spec = read(population)
    if find_spec("stable_baselines3") is None:
        raise UsageError(command, "train", "needs the train extra: pip install -e '.[train]'")
    stop = stop_on_signals()

    @contextmanager
    def engine(stage: str):  # noqa: ANN202 - a context manager of a Runner
        journal = out / f"{stage}.journal"
        with open_engine(
            bus, f"grow-{stage}", journal, KINDS, workers, ray, stop, job_timeout=7200.0
        ) as opened:
            yield on_workers(opened)

    return Grow(spec, out, engine, console.print, max(workers, 1))


@commands.command("keys")
def keys_command(role: Role | None = typer.Option(None, help="Only the keys of this seat.")) -> None:
    """Every policy key that loads, by library, with the seat it plays: the study's (B1-B9, S1-S7),
    the grown libraries' (GB1.., GS1..; TB1.., TS1..: the default agent's), the partner population's members
    (PB01a.., PS01a..), the scripted rules, yours in TSF_LIBRARY; and the other forms a key can take."""
    from services.agent.seats import listed_keys
    from services.population.adaptive import STRATEGIES

    table = Table(title="Policy keys")
    for column in ("key", "seat", "library", "what"):
        table.add_column(column)
    for row in listed_keys(role):
        table.add_row(*row)
    seats = role or "either"
    table.add_row("PATH.zip", seats, "yours", "an SB3 model trained on tsf/Role-v0 (docs/library.md)")
    table.add_row("package.module:attr", "its own", "yours", "a policy object of yours (docs/library.md)")
    table.add_row("proxy:DIR", "its own", "yours", "a proxy cloned from recorded people (docs/proxies.md)")
    strategies = ", ".join(STRATEGIES)
    table.add_row(
        "adaptive-T<window>-<strategy>", seats, "agents", f"the adaptive agent; strategies: {strategies}"
    )
    console.print(table)
