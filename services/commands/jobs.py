"""`tsf` commands of the job system: worker (and its slots)."""

from __future__ import annotations

import logging
import os
import socket
import sys

import typer

from services.commands.options import bus_options, number
from shared.bus import BusConfig, stop_on_signals
from shared.game import Range

commands = typer.Typer()
SLOTS = Range(1, 256)  # worker processes one `tsf worker` runs


@commands.command()
@bus_options
def worker(
    sweep_id: str = typer.Option("table", "--sweep", help="The sweep (table or evaluation) to work for."),
    worker_id: str = typer.Option("", "--id", help="This worker's name (default: host and pid)."),
    slots: int = number(1, SLOTS, "Jobs run at once, one process each (a slot fills a core)."),
    *,
    bus: BusConfig,
) -> None:
    """Run a worker: plays the jobs a coordinator hands it (table cells, evaluation games), until
    the coordinator is gone."""
    from services import growth
    from services.evaluation import evaluation, thresholds
    from services.jobs.bus import run_worker
    from services.table import table
    from shared.processes import Processes

    name = worker_id or f"{socket.gethostname()}-{os.getpid()}".replace(".", "-")
    stop = stop_on_signals()
    if slots == 1:
        runners = (
            table.KINDS | evaluation.KINDS | thresholds.KINDS | growth.KINDS
        )  # every kind it may be handed
        done = run_worker(bus, sweep_id, name, runners, stop)
        logging.getLogger("tsf.worker").info("worker %s did %d jobs", name, done)
        return
    command = [sys.executable, "-m", "services.commands", "worker", *bus.to_args(), "--sweep", sweep_id]
    with Processes() as processes:
        for i in range(slots):
            processes.start(f"slot{i}", [*command, "--id", f"{name}-{i}"])
        while not stop.is_set() and any(c.poll() is None for c in processes.children.values()):
            stop.wait(0.5)


workers_commands = typer.Typer(
    no_args_is_help=True, help="Worker containers on Docker engines (the Docker SDK)."
)
commands.add_typer(workers_commands, name="workers")


@workers_commands.callback()
def workers_group() -> None:
    """Worker containers on Docker engines (the Docker SDK): up, down, ls."""


HOSTS = typer.Option(
    None,
    "--host",
    help="A Docker engine by URL (tcp://..., ssh://user@host), repeatable (default: this machine's).",
)
ONE_SWEEP = typer.Option(None, "--sweep", help="Only this sweep's workers (default: every one).")


@workers_commands.command("up")
def workers_up(
    connect: str = typer.Option(
        ..., help="The router the workers and the coordinator meet at (tcp/HOST:PORT)."
    ),
    count: int = number(1, Range(1, 1024), "Worker containers to start, spread over the hosts."),
    host: list[str] | None = HOSTS,
    sweep_id: str = typer.Option(
        "table", "--sweep", help="The sweep they work for (tsf sweep/eval --sweep)."
    ),
    slots: int = number(1, SLOTS, "Slots of each worker (jobs at once, one process each)."),
    image: str = typer.Option("tsf:local", help="The project's image (built locally; see Dockerfile)."),
    pull: bool = typer.Option(False, help="Pull the image where an engine lacks it (default: refuse)."),
) -> None:
    """Start worker containers from the project's image, labelled with their sweep."""
    from services.commands.options import console
    from services.jobs import deploy

    started = deploy.up(count, connect, sweep_id, host or ["local"], image, slots, pull)
    for w in started:
        console.print(f"{w.host}: {w.name} (sweep {w.sweep})")


@workers_commands.command("down")
def workers_down(
    host: list[str] | None = HOSTS,
    sweep_id: str | None = ONE_SWEEP,
) -> None:
    """Stop and remove worker containers."""
    from services.commands.options import console
    from services.jobs import deploy

    gone = deploy.down(host or ["local"], sweep_id)
    console.print(f"removed {len(gone)} worker container(s)")


@workers_commands.command("ls")
def workers_ls(
    host: list[str] | None = HOSTS,
    sweep_id: str | None = ONE_SWEEP,
) -> None:
    """List worker containers: engine, name, sweep, status."""
    from services.commands.options import console
    from services.jobs import deploy

    for w in deploy.ls(host or ["local"], sweep_id):
        console.print(f"{w.host}\t{w.name}\t{w.sweep}\t{w.status}")
