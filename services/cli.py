"""The `tsf` command line: one entry point that each service and tool adds its commands to."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.live import Live
from rich.table import Table

from services.agent.scripted import scripted_policy
from services.sim.calibration import calibrate
from services.sim.config import GameConfig
from services.sim.play import play, summarize
from shared.bus import BusConfig, stop_on_signals

app = typer.Typer(no_args_is_help=True, add_completion=False, help="Team Space Fortress.")
console = Console()

# Options every bus service shares.
Mode = Annotated[str, typer.Option("--mode", help="zenoh mode: peer (default), client or router.")]
Listen = Annotated[list[str] | None, typer.Option("--listen", help="Endpoint to listen on (repeatable).")]
Connect = Annotated[list[str] | None, typer.Option("--connect", help="Endpoint to connect to (repeatable).")]
Multicast = Annotated[bool, typer.Option("--multicast", help="Turn multicast scouting on (off by default).")]
LowLatency = Annotated[bool, typer.Option("--low-latency", help="zenoh low-latency transport (all peers).")]
User = Annotated[
    str, typer.Option("--user", help="Log-in for a secured router; the password comes from TSF_BUS_PASSWORD.")
]
Password = Annotated[str, typer.Option("--password", envvar="TSF_BUS_PASSWORD", hidden=True)]
Match = Annotated[str, typer.Option("--match", help="Match id: the key namespace tsf/<match>/...")]


def _bus(
    mode: str,
    listen: list[str] | None,
    connect: list[str] | None,
    multicast: bool,
    low_latency: bool,
    user: str,
    password: str,
) -> BusConfig:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    listen_default = () if mode == "client" else ("tcp/127.0.0.1:0",)
    return BusConfig(
        mode, tuple(listen or listen_default), tuple(connect or ()), multicast, low_latency, user, password
    )


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


@app.command()
def sim(
    match: Match,
    seed: int = typer.Option(0),
    frames: int = typer.Option(GameConfig.frames, min=1),
    mode: str = typer.Option("realtime", "--sim-mode", help="realtime (30 Hz) or lockstep."),
    bait: str = typer.Option("", help="Bait's policy key, for the record."),
    shooter: str = typer.Option("", help="Shooter's policy key, for the record."),
    wait_players: float = typer.Option(10.0, help="Seconds to wait for both seats before starting."),
    wait_recorder: float = typer.Option(0.0, help="Seconds to wait for a recorder before starting."),
    zmode: Mode = "peer",
    listen: Listen = None,
    connect: Connect = None,
    multicast: Multicast = False,
    low_latency: LowLatency = False,
    user: User = "",
    password: Password = "",
) -> None:
    """Run the sim service for one match."""
    from services.sim.service import run_sim

    bus = _bus(zmode, listen, connect, multicast, low_latency, user, password)
    summary = run_sim(
        bus, match, seed, GameConfig(frames=frames), mode, {"bait": bait, "shooter": shooter},
        stop_on_signals(), wait_players, wait_recorder,
    )  # fmt: skip
    logging.getLogger("tsf.sim").info(
        "match %s over: %d kills in %d frames; timing %s", match, summary.kills, summary.frame, summary.timing
    )


@app.command()
def agent(
    match: Match,
    role: str = typer.Option(..., help="bait or shooter"),
    policy: str = typer.Option(..., help="Policy key to play (a library or scripted key)."),
    seed: int = typer.Option(0, help="The match's seed (the policy's seed derives from it)."),
    zmode: Mode = "peer",
    listen: Listen = None,
    connect: Connect = None,
    multicast: Multicast = False,
    low_latency: LowLatency = False,
    user: User = "",
    password: Password = "",
) -> None:
    """Run an agent service that plays one seat."""
    from services.agent.service import run_agent

    run_agent(
        _bus(zmode, listen, connect, multicast, low_latency, user, password),
        match,
        role,
        policy,
        seed,
        stop_on_signals(),
    )


@app.command()
def recorder(
    match: Match,
    out: Path = typer.Option(Path("recordings"), help="Directory of the recordings."),
    zmode: Mode = "peer",
    listen: Listen = None,
    connect: Connect = None,
    multicast: Multicast = False,
    low_latency: LowLatency = False,
    user: User = "",
    password: Password = "",
) -> None:
    """Run the recorder service for one match."""
    from services.recorder.service import run_recorder

    path = run_recorder(
        _bus(zmode, listen, connect, multicast, low_latency, user, password), match, out, stop_on_signals()
    )
    logging.getLogger("tsf.recorder").info("recording written to %s", path)


@app.command()
def router(
    listen: Annotated[list[str] | None, typer.Option("--listen", help="Endpoint (repeatable).")] = None,
    credentials: Path | None = typer.Option(
        None, help="Dictionary file of `user:password` lines: turns on log-in and access control."
    ),
) -> None:
    """Run a zenoh router (a Python session in router mode) for matches across machines."""
    from services.router import run_router

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    endpoints = tuple(listen or ("tcp/0.0.0.0:7447",))
    logging.getLogger("tsf.router").info("routing on %s%s", endpoints, " (secured)" if credentials else "")
    run_router(endpoints, credentials, stop_on_signals())


@app.command("match")
def match_command(
    seed: int = typer.Option(0, help="The game's seed."),
    duration: float = typer.Option(60.0, min=0.1, help="Game length in seconds (30 frames each)."),
    bait: str = typer.Option("circle", help="Bait agent's policy key."),
    shooter: str = typer.Option("mirror", help="Shooter agent's policy key."),
    lockstep: bool = typer.Option(
        False, help="Lockstep (as fast as the agents answer) instead of real time."
    ),
    match: str = typer.Option("", help="Match id (default: from the clock)."),
    out: Path = typer.Option(Path("recordings"), help="Directory of the recordings."),
) -> None:
    """Start a complete match on this machine: sim, two agents and the recorder as processes."""
    from services.launch import MatchPlan, new_match_id, run_match
    from services.recorder.recording import export_parquet, load

    plan = MatchPlan(
        match or new_match_id(), seed, round(duration * 30), "lockstep" if lockstep else "realtime",
        bait, shooter, out,
    )  # fmt: skip
    with Live(console=console, transient=True) as live:

        def scoreboard(state) -> None:  # noqa: ANN001 - a State
            live.update(
                f"[bold]{plan.match}[/] frame {state.frame}/{state.frames}  "
                f"kills [green]{state.kills}[/]  points {state.points}  bait {bait}  shooter {shooter}"
            )

        summary, path = run_match(plan, scoreboard)
    export = export_parquet(load(path), path.with_suffix(".parquet"))
    console.print(
        f"[bold]{plan.match}[/]: {summary.kills} kills in {summary.frame} frames "
        f"= {summary.kills_per_minute:.2f} kills/min, points {summary.points}"
    )
    for role, counters in summary.counters.items():
        deaths = ", ".join(f"{cause} {n}" for cause, n in counters["deaths"].items())
        hits = counters["shield_hits"]
        console.print(f"  {role}: kills {counters['kills']}, deaths by cause: {deaths}, shield hits {hits}")
    if summary.timing:
        console.print("  timing (ms): " + ", ".join(f"{k} {v:.2f}" for k, v in summary.timing.items()))
    console.print(f"  recording: {path}  (Parquet: {export['states'].parent})")


if __name__ == "__main__":
    app()
