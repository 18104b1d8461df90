"""`tsf` commands of the job system: worker (and its slots)."""

from __future__ import annotations

import logging

import typer

from services.options import bus_options, number
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
    import os
    import socket
    import sys

    from services.jobs.bus import run_worker
    from services.processes import Processes

    name = worker_id or f"{socket.gethostname()}-{os.getpid()}".replace(".", "-")
    stop = stop_on_signals()
    if slots == 1:
        done = run_worker(bus, sweep_id, name, stop)
        logging.getLogger("tsf.worker").info("worker %s did %d jobs", name, done)
        return
    command = [sys.executable, "-m", "services.cli", "worker", *bus.to_args(), "--sweep", sweep_id]
    with Processes() as processes:
        for i in range(slots):
            processes.start(f"slot{i}", [*command, "--id", f"{name}-{i}"])
        while not stop.is_set() and any(c.poll() is None for c in processes.children.values()):
            stop.wait(0.5)
