"""`tsf` commands for the self-play table: sweep, table."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from services.commands.options import (
    GAMES,
    RAY,
    WORKERS,
    Role,
    bus_options,
    console,
    number,
    output,
    progress_bars,
)
from services.table.table import LANES
from shared.bus import BusConfig, stop_on_signals
from shared.errors import Failure, UsageError
from shared.game import Range, other
from shared.messages import JOB_SEEDS

commands = typer.Typer()


def _keys(chosen: list[str] | None, role: str) -> list[str]:
    from services.agent import library

    keys = chosen or library.keys(role)
    unknown = [k for k in keys if k not in library.keys(role)]
    if unknown:
        raise typer.BadParameter(f"not {role}s of the library: {unknown}")
    return keys


@commands.command()
@bus_options
def sweep(
    games: int = number(20, GAMES, "Seeded one-minute games per pair (seeds 0..games-1)."),
    bait: list[str] | None = typer.Option(None, help="A library bait, repeatable (default: all)."),
    shooter: list[str] | None = typer.Option(None, help="A library shooter, repeatable (default: all)."),
    workers: int = number(2, WORKERS, "Worker processes to start here (0: only remote workers)."),
    chunk: int = number(20, JOB_SEEDS, "Games per job."),
    lanes: int = number(LANES, Range(1, 100_000), "Games a worker plays at once, as the lanes of one batch."),
    out: Path = output(
        Path("tsf-table.json"),
        "Where the table goes (and its journal, OUT.journal). The shipped table is written only "
        "when named here.",
    ),
    plot: Path | None = output(None, "Also draw the heatmap into this PNG."),
    sweep_id: str = typer.Option("table", "--sweep", help="Sweep id: the key namespace tsf/sweep/<id>/..."),
    ray: str | None = RAY,
    *,
    bus: BusConfig,
) -> None:
    """Coordinate a self-play sweep: measure the table with local and remote workers; resumable."""
    from services.table.sweep import journal_path, run_sweep

    bait_keys, shooter_keys = _keys(bait, "bait"), _keys(shooter, "shooter")
    stop = stop_on_signals()
    with progress_bars() as shown:
        table = run_sweep(
            bus, sweep_id, out, bait_keys, shooter_keys, games, chunk, shown("games"), stop, lanes=lanes,
            workers=workers, ray=ray,
        )  # fmt: skip
    if table is None:
        raise Failure(f"stopped; run the same command again to resume from {journal_path(out)}")
    _print_table(table)
    console.print(f"table written to {out}")
    if plot is not None:
        from services.table.plot import heatmap

        console.print(f"heatmap written to {heatmap(table, plot)}")


def _print_table(table) -> None:  # noqa: ANN001 - a services.table.table.Table
    grid = Table(title=f"P: mean kills/min over {table.games} games (bold: best shooter for the bait)")
    for column in ("", *table.shooters):
        grid.add_column(column)
    for bait in table.baits:
        best = table.best_shooter(bait)
        cells = (
            f"[bold]{table.mean(bait, s):.2f}[/]" if s == best else f"{table.mean(bait, s):.2f}"
            for s in table.shooters
        )
        grid.add_row(bait, *cells)
    console.print(grid)
    console.print(f"mean of the table: {table.overall_mean():.2f} kills/min")


@commands.command("table")
def table_command(
    path: Path | None = typer.Argument(
        None, exists=True, dir_okay=False, help="A table file (default: the library's shipped table)."
    ),
    plot: Path | None = output(None, "Draw the heatmap into this PNG."),
) -> None:
    """Show a measured table (refused if the library or rules changed since)."""
    from services.table.table import DEFAULT_TABLE, StaleTable
    from services.table.table import Table as SelfPlayTable

    try:
        table = SelfPlayTable.load(path or DEFAULT_TABLE)
    except StaleTable as error:
        console.print(f"[red]{error}[/]")
        raise typer.Exit(1) from None
    _print_table(table)
    if plot is not None:
        from services.table.plot import heatmap

        console.print(f"heatmap written to {heatmap(table, plot)}")


@commands.command("skill-table")
def skill_table(
    role: Role = typer.Option("shooter", help="Our seat: its library teammates are the columns."),
    games: int = number(20, GAMES, "Seeded one-minute games per cell (seeds 0..games-1)."),
    teammate: list[str] | None = typer.Option(None, help="Our seat's teammate, repeatable (default: all)."),
    style: list[str] | None = typer.Option(
        None, help="A partner style (library key), repeatable; default all."
    ),
    workers: int = number(1, WORKERS, "Processes playing batches at once."),
    out: Path = output(Path("tsf-skill-table.json"), "Where the skill table goes."),
    plot: Path | None = output(None, "Also draw the heatmap into this PNG."),
    into: Path | None = typer.Option(
        None,
        exists=True,
        dir_okay=False,
        help="Add the teammates as columns to this skill table (its role, styles, games).",
    ),
) -> None:
    """Measure the skill table: every library teammate of our seat with calibrated human-like
    stand-ins of each style (the other seat's library) and skill (novice, typical, practised),
    beside P; writes and prints each stand-in's best response beside P's for its style (OUT.md).
    With --into, measures only the --teammate columns and adds them to that table."""
    from services.evaluation.skills import SkillTable, measure, summary

    before = SkillTable.load(into) if into else None
    if before:
        new = [t for t in _keys(teammate, before.role) if t not in before.teammates]
        if not teammate or not new:
            raise UsageError(
                "--teammate", " ".join(teammate or []) or "(none)", f"name teammates {into} lacks"
            )
        with progress_bars() as shown:
            added = measure(
                before.role, new, list(before.styles), before.skills, before.games, workers, shown("games")
            )
        table = before.extend(added)
    else:
        partner_role = other(role)
        with progress_bars() as shown:
            table = measure(
                role, _keys(teammate, role), _keys(style, partner_role), games=games, workers=workers,
                progress=shown("games"),
            )  # fmt: skip
    table.save(out)
    text = summary(table, _p_best(table))
    out.with_suffix(".md").write_text(text)
    console.print(text, markup=False)
    console.print(f"skill table written to {out} (and its summary to {out.with_suffix('.md')})")
    if plot is not None:
        from services.table.plot import skill_heatmap

        console.print(f"heatmap written to {skill_heatmap(table, plot, _p_best(table))}")


@commands.command("skill-model")
def skill_model_command(
    table: Path = typer.Option(
        ..., exists=True, dir_okay=False, help="The skill table (tsf skill-table) the adapter picks from."
    ),
    window: int = number(400, Range(1, 1800), "The adapter's window T the features are read over."),
    out: Path = output(
        Path("tsf-skill.json"),
        "Where the model goes (the shipped one: services/agent/library/skill.json).",
    ),
) -> None:
    """Measure the adaptive agent's skill model (strategies with -skill): the skill table's means,
    and what the window of a stand-in of each style and skill, and of each library policy, shows
    (docs/adapter.md). Plays 12 games of each (seeds 64-75) with the table's best static teammate."""
    import sys

    from services.agent import library
    from services.evaluation.skills import SkillTable, skill_model

    try:
        skills = SkillTable.load(table)
    except (KeyError, TypeError, ValueError) as error:
        raise UsageError("--table", table, f"not a skill table of tsf skill-table ({error})") from None
    if set(skills.styles) != set(library.keys(other(skills.role))):
        raise UsageError("--table", table, "its styles are not the partner library in use")
    with progress_bars() as shown:
        model = skill_model(skills, window, progress=shown("styles played"))
    console.print(f"skill model written to {model.save(out, ' '.join(['tsf', *sys.argv[1:]]))}")


def _p_best(table) -> dict[str, str]:  # noqa: ANN001 - a services.evaluation.skills.SkillTable
    """P's best response to each style of the skill table ({} without a current P)."""
    from services.table.table import DEFAULT_TABLE, StaleTable
    from services.table.table import Table as SelfPlayTable

    try:
        p = SelfPlayTable.load(DEFAULT_TABLE)
    except StaleTable:  # TSF_LIBRARY adds members: the shipped P still holds for the shipped pairs
        from services.agent import library

        p = SelfPlayTable.load(library.LIBRARY / "table.json", check=False)
        if p.library != library.manifest_hash(library.LIBRARY):
            return {}
    if table.role == "shooter":
        return {s: p.best_shooter(s) for s in table.styles if s in p.baits}
    return {s: p.best_bait(s) for s in table.styles if s in p.shooters}
