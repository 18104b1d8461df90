"""`tsf` commands that run one service each, for matches spread over processes or machines: sim,
agent, recorder, adapter, human, router, and the alive probe."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import typer

from services.adapter import core
from services.commands.options import (
    PRIORITY,
    SECONDS,
    AdapterFactory,
    Connect,
    Duration,
    Frames,
    Host,
    Match,
    Pool,
    Port,
    Role,
    Seed,
    Service,
    SimMode,
    adapter_options,
    bus_options,
    console,
    free_port,
    game_frames,
    in_pool,
    keys_help,
    number,
    output,
)
from services.population.seat import SeatSpec
from shared import keys
from shared.bus import BusConfig, stop_on_signals
from shared.errors import UsageError
from shared.game import FPS, SEEDS, GameConfig

commands = typer.Typer()


@commands.command()
@bus_options
def sim(
    match: Match = "",
    pool: Pool = "",
    seed: Seed = 0,
    duration: Duration = None,
    frames: Frames = None,
    mode: SimMode = typer.Option(
        "realtime", "--sim-mode", help=f"realtime: {FPS} Hz; lockstep: as fast as answered."
    ),
    bait: str = typer.Option("", help="Bait's policy key, for the record."),
    shooter: str = typer.Option("", help="Shooter's policy key, for the record."),
    wait_players: float = number(10.0, SECONDS, "Seconds to wait for both seats before starting."),
    wait_recorder: float = number(0.0, SECONDS, "Seconds to wait for a recorder before starting."),
    wait_adapter: float = number(0.0, SECONDS, "Seconds to wait for an adapter before starting."),
    priority: int = number(
        0, PRIORITY, "Nice steps to raise the sim's priority by: at its first frame; a pool's at once."
    ),
    *,
    bus: BusConfig,
) -> None:
    """Run the sim service for one match (--match), or a pool's sim for every match ordered (--pool)."""
    from services.sim.pool import run_pool
    from services.sim.service import run_sim

    if in_pool(match, pool):
        run_pool(bus, pool, stop_on_signals(), priority)
        return
    config = GameConfig(frames=game_frames(duration, frames))
    summary = run_sim(
        bus, match, seed, config, mode, {"bait": bait, "shooter": shooter},
        stop_on_signals(), wait_players, wait_recorder, wait_adapter=wait_adapter, priority=priority,
    )  # fmt: skip
    logging.getLogger("tsf.sim").info(
        "match %s over: %d kills in %d frames; timing %s", match, summary.kills, summary.frame, summary.timing
    )


@commands.command()
@bus_options
def agent(
    match: Match = "",
    pool: Pool = "",
    role: Role | None = typer.Option(None, help="The seat (with --match)."),
    policy: str = typer.Option(
        "",
        help=keys_help(
            None,
            "With --match: policy key to play, or an adaptive agent's name (adaptive-T<window>-<strategy>)",
        ),
    ),
    seed: int = number(0, SEEDS, "The match's seed (the policy's seed derives from it)."),
    *,
    bus: BusConfig,
) -> None:
    """Run an agent service that plays one seat (--match), or every agent seat of a pool's matches
    (--pool: each match's seats, policies and seed come from its order)."""
    from services.agent.service import run_agent, run_agent_pool

    if in_pool(match, pool):
        run_agent_pool(bus, pool, stop_on_signals())
        return
    if role is None or not policy:
        raise UsageError("--role" if role is None else "--policy", "(none)", "needed with --match")
    adaptive = SeatSpec.parse(policy, "--policy").adaptive(role, seed)
    start = core.initial_policy(adaptive) if adaptive else policy
    run_agent(bus, match, role, start, seed, stop_on_signals(), adaptive is not None)


@commands.command()
@bus_options
def recorder(
    match: Match = "",
    pool: Pool = "",
    out: Path = output(Path("recordings"), "Directory of the recordings.", directory=True),
    *,
    bus: BusConfig,
) -> None:
    """Run the recorder service for one match, or for every match of a pool until stopped."""
    from services.recorder.service import run_pool_recorder, run_recorder

    if in_pool(match, pool):
        run_pool_recorder(bus, pool, out, stop_on_signals())
        return
    path = run_recorder(bus, match, out, stop_on_signals())
    logging.getLogger("tsf.recorder").info("recording written to %s", path)


@commands.command()
@bus_options
@adapter_options()
def adapter(match: Match = "", pool: Pool = "", *, adapter: AdapterFactory, bus: BusConfig) -> None:
    """Run the adapter service: watch the partner, switch the agent of ROLE to the best response.
    With --pool, for every adaptive match of a pool (each one's adapter settings, seat and seed
    come from its order; the options here are then unused)."""
    from services.adapter.service import run_adapter, run_adapter_pool

    if in_pool(match, pool):
        run_adapter_pool(bus, pool, stop_on_signals())
    else:
        run_adapter(bus, match, adapter(), stop_on_signals())


@commands.command()
@bus_options
def human(
    match: Match,
    token: list[str] | None = typer.Option(
        None, "--token", help="ROLE=TOKEN: a seat open to people (repeatable; none: spectators only)."
    ),
    host: Host = "127.0.0.1",
    port: Port = 8000,
    *,
    bus: BusConfig,
) -> None:
    """Run the human gateway: a web page that plays a match's seats from browsers, by seat token,
    and shows the match (or its live replay) to spectators."""
    from services.human.gateway import run_human
    from services.human.play import seat_links

    token = token or []
    tokens = dict(t.split("=", 1) for t in token if "=" in t)
    if len(tokens) != len(token):
        raise typer.BadParameter("give each seat as ROLE=TOKEN")

    def show(gateway) -> None:  # noqa: ANN001 - a Gateway
        for role, link in seat_links(gateway.url, tokens).items():
            console.print(f"{role}: {link}")
        console.print(f"watch: {gateway.url}?watch=1")

    free_port(host, port)
    run_human(bus, match, tokens, host, port, stop_on_signals(), show)


@commands.command()
def router(
    listen: Annotated[list[str] | None, typer.Option("--listen", help="Endpoint (repeatable).")] = None,
    credentials: Path | None = typer.Option(
        None, help="Dictionary file of `user:password` lines: turns on log-in and access control."
    ),
) -> None:
    """Run a zenoh router (a Python session in router mode) for matches across machines."""
    from shared.router import run_router

    endpoints = tuple(listen or ("tcp/0.0.0.0:7447",))
    run_router(endpoints, credentials, stop_on_signals())


@commands.command()
def alive(
    match: Match,
    service: Service = typer.Option(..., help="The service asked about."),
    role: Role | None = typer.Option(None, help="The seat, for an agent or a human."),
    connect: Connect = None,
    timeout: float = number(2.0, SECONDS, "Seconds to wait for the bus."),
) -> None:
    """Exit 0 if the service's liveliness token is on the bus, else 1 (a container healthcheck).

    Asks as a zenoh client of the endpoint it connects to (default: this host's tcp/127.0.0.1:7447),
    so the probe never joins the match's mesh of peers."""
    import zenoh

    from shared.bus import session

    key = keys.alive(match, service, role or None)
    bus = BusConfig("client", (), tuple(connect or ("tcp/127.0.0.1:7447",)), wait_router=timeout)
    try:
        with session(bus) as z:
            found = any(reply.ok is not None for reply in z.liveliness().get(key, timeout=timeout))
    except zenoh.ZError as error:
        console.print(f"cannot reach the bus: {error}")
        found = False
    console.print(f"{key}: {'alive' if found else 'not on the bus'}")
    if not found:
        raise typer.Exit(1)
