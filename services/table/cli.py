"""`tsf` commands for the self-play table: sweep, worker, table."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import typer
from rich.table import Table

from services.options import bus_options, console
from shared.bus import BusConfig, stop_on_signals

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
    games: int = typer.Option(20, min=1, help="Seeded one-minute games per pair (seeds 0..games-1)."),
    bait: list[str] | None = typer.Option(None, help="A library bait, repeatable (default: all)."),
    shooter: list[str] | None = typer.Option(None, help="A library shooter, repeatable (default: all)."),
    workers: int = typer.Option(2, min=0, help="Worker processes to start here (0: only remote workers)."),
    chunk: int = typer.Option(20, min=1, help="Games per job, played as the lanes of one batch."),
    out: Path = typer.Option(Path("services/agent/library/table.json"), help="Where the table goes."),
    plot: Path | None = typer.Option(None, help="Also draw the heatmap into this PNG."),
    sweep_id: str = typer.Option("table", "--sweep", help="Sweep id: the key namespace tsf/sweep/<id>/..."),
    *,
    bus: BusConfig,
) -> None:
    """Coordinate a self-play sweep: measure the table with local and remote workers; resumable."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

    from services.table.sweep import local_workers, run_sweep
    from shared.bus import free_endpoint

    bait_keys, shooter_keys = _keys(bait, "bait"), _keys(shooter, "shooter")
    endpoint = free_endpoint()
    if bus.mode != "client":
        bus = dataclasses.replace(bus, listen=(*bus.listen, endpoint))
    stop = stop_on_signals()
    columns = (BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
    with local_workers(sweep_id, endpoint, workers), Progress(*columns, console=console) as bar:
        task = bar.add_task("jobs", total=None)
        table = run_sweep(
            bus, sweep_id, out, bait_keys, shooter_keys, games, chunk,
            lambda done, total: bar.update(task, completed=done, total=total), stop,
        )  # fmt: skip
    if table is None:
        console.print("stopped; run the same command again to resume from the journal")
        raise typer.Exit(1)
    _print_table(table)
    console.print(f"table written to {out}")
    if plot is not None:
        from services.table.plot import heatmap

        console.print(f"heatmap written to {heatmap(table, plot)}")


@commands.command()
@bus_options
def worker(
    sweep_id: str = typer.Option("table", "--sweep", help="The sweep to work for."),
    worker_id: str = typer.Option("", "--id", help="This worker's name (default: host and pid)."),
    *,
    bus: BusConfig,
) -> None:
    """Run a sweep worker: plays the jobs a coordinator hands it, until the coordinator is gone."""
    import os
    import socket

    from services.table.sweep import run_worker

    name = worker_id or f"{socket.gethostname()}-{os.getpid()}".replace(".", "-")
    done = run_worker(bus, sweep_id, name, stop_on_signals())
    logging.getLogger("tsf.worker").info("worker %s did %d jobs", name, done)


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
    path: Path = typer.Argument(Path("services/agent/library/table.json"), exists=True, dir_okay=False),
    plot: Path | None = typer.Option(None, help="Draw the heatmap into this PNG."),
) -> None:
    """Show a measured table (refused if the library or rules changed since)."""
    from services.table.table import StaleTable
    from services.table.table import Table as SelfPlayTable

    try:
        table = SelfPlayTable.load(path)
    except StaleTable as error:
        console.print(f"[red]{error}[/]")
        raise typer.Exit(1) from None
    _print_table(table)
    if plot is not None:
        from services.table.plot import heatmap

        console.print(f"heatmap written to {heatmap(table, plot)}")
