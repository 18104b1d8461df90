"""The `tsf` command line: one entry point that each service and tool adds its commands to."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.live import Live
from rich.table import Table

from services.adapter.core import STRATEGIES
from services.agent.library import policy_for
from services.sim.calibration import calibrate
from services.sim.config import GameConfig
from services.sim.play import play, summarize
from shared.bus import BusConfig, stop_on_signals
from shared.errors import Failure, UsageError

app = typer.Typer(no_args_is_help=True, add_completion=False, help="Team Space Fortress.")
console = Console()

# Options every bus service shares. The environment can set them (space-separated endpoints), so that
# one deployment file configures every service's bus in one place (compose.yaml).
Mode = Annotated[
    str, typer.Option("--mode", envvar="TSF_MODE", help="zenoh mode: peer (default), client or router.")
]
Listen = Annotated[
    list[str] | None,
    typer.Option("--listen", envvar="TSF_LISTEN", help="Endpoint to listen on (repeatable)."),
]
Connect = Annotated[
    list[str] | None,
    typer.Option("--connect", envvar="TSF_CONNECT", help="Endpoint to connect to (repeatable)."),
]
Multicast = Annotated[bool, typer.Option("--multicast", help="Turn multicast scouting on (off by default).")]
LowLatency = Annotated[bool, typer.Option("--low-latency", help="zenoh low-latency transport (all peers).")]
User = Annotated[
    str, typer.Option("--user", help="Log-in for a secured router; the password comes from TSF_BUS_PASSWORD.")
]
Password = Annotated[str, typer.Option("--password", envvar="TSF_BUS_PASSWORD", hidden=True)]
Match = Annotated[
    str, typer.Option("--match", envvar="TSF_MATCH", help="Match id: the key namespace tsf/<match>/...")
]


BUS_OPTIONS = {  # parameter name: (annotation, default)
    "zmode": (Mode, "peer"),
    "listen": (Listen, None),
    "connect": (Connect, None),
    "multicast": (Multicast, False),
    "low_latency": (LowLatency, False),
    "user": (User, ""),
    "password": (Password, ""),
}


def bus_options(command: Callable[..., None]) -> Callable[..., None]:
    """Give a service's command the bus options every service shares; the command receives them as
    one `bus: BusConfig` (and logging is set up, since services log)."""
    own = [p for p in inspect.signature(command, eval_str=True).parameters.values() if p.name != "bus"]
    shared = [
        inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)
        for name, (annotation, default) in BUS_OPTIONS.items()
    ]

    @functools.wraps(command)
    def with_bus(**options: object) -> None:
        mode, listen, connect, multicast, low_latency, user, password = (options.pop(n) for n in BUS_OPTIONS)
        logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
        listen = listen or (() if mode == "client" else ("tcp/127.0.0.1:0",))
        bus = BusConfig(mode, tuple(listen), tuple(connect or ()), multicast, low_latency, user, password)
        command(bus=bus, **options)

    with_bus.__signature__ = inspect.Signature(own + shared)
    return with_bus


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
def train(
    keys: list[str] = typer.Argument(None, help="Library keys to train (default: every learned policy)."),
    steps: int | None = typer.Option(None, min=1, help="Environment steps (default: the recipe's)."),
    seed: int | None = typer.Option(None, help="Training seed (default: the recipe's)."),
    log_dir: Path = typer.Option(Path("runs"), help="CSV training logs go to LOG_DIR/KEY."),
    score_games: int = typer.Option(10, min=0, help="Games scored with the first partner after training."),
) -> None:
    """Train library policies by their registry recipes (needs the `train` extra)."""
    from services.agent import library

    todo = library.learned(keys or [])
    try:
        from services.agent.train import train as train_policy
    except ModuleNotFoundError as error:
        raise Failure(f"{error}: training needs the `train` extra, pip install -e '.[train]'") from None
    for key in todo:
        console.print(f"[bold]training {key}[/]: {library.registry()[key].description}")
        entry = train_policy(key, steps, seed, log_dir / key, score_games=score_games)
        score = entry.get("score")
        console.print(f"  {entry['file']} sha256 {entry['sha256'][:12]} in {entry['seconds']} s")
        if score:
            console.print(
                f"  {score['kills_per_minute']:.2f} ± {score['stderr']:.2f} kills/min with {score['partner']}"
            )


def _score_text(score: dict) -> str:
    return f"{score['kills_per_minute']:.2f} ± {score['stderr']:.2f} kills/min with {score['partner']}"


@app.command("library")
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


@app.command()
def diversity(
    games: int = typer.Option(5, min=1, help="Seeded games of each policy."),
    bait_partner: str = typer.Option("S4", help="The shooter every bait plays with."),
    shooter_partner: str = typer.Option("B1", help="The bait every shooter plays with."),
    out: Path | None = typer.Option(None, help="Write the two matrices as CSV files into this directory."),
) -> None:
    """The library's CEM matrices: mean log-probability of policy i's actions under policy j."""
    from services.adapter.cem import cem_matrix
    from services.agent import library

    partners = {  # both checked before the first matrix
        "bait": policy_for(bait_partner, "shooter", "--bait-partner"),
        "shooter": policy_for(shooter_partner, "bait", "--shooter-partner"),
    }
    for role, partner in (("bait", bait_partner), ("shooter", shooter_partner)):
        keys = library.keys(role)
        m = cem_matrix([library.load(k) for k in keys], partners[role], list(range(games)))
        table = Table(title=f"{role}s with {partner}: mean log-probability of row's actions under column")
        for column in ("", *keys):
            table.add_column(column)
        for key, row in zip(keys, m, strict=True):
            cells = (f"[bold]{v:.2f}[/]" if k == key else f"{v:.2f}" for k, v in zip(keys, row, strict=True))
            table.add_row(key, *cells)
        console.print(table)
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
            header = ",".join(["policy", *keys])
            rows = [",".join([k, *(f"{v:.4f}" for v in row)]) for k, row in zip(keys, m, strict=True)]
            (out / f"cem_{role}.csv").write_text("\n".join([header, *rows]) + "\n")


def _keys(text: str, role: str) -> list[str]:
    from services.agent import library

    keys = [k.strip() for k in text.split(",") if k.strip()] if text else library.keys(role)
    unknown = [k for k in keys if k not in library.keys(role)]
    if unknown:
        raise typer.BadParameter(f"not {role}s of the library: {unknown}")
    return keys


@app.command()
@bus_options
def sweep(
    games: int = typer.Option(20, min=1, help="Seeded one-minute games per pair (seeds 0..games-1)."),
    baits: str = typer.Option("", help="Comma-separated baits (default: all)."),
    shooters: str = typer.Option("", help="Comma-separated shooters (default: all)."),
    workers: int = typer.Option(2, min=0, help="Worker processes to start here (0: only remote workers)."),
    chunk: int = typer.Option(10, min=1, help="Games per job."),
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

    bait_keys, shooter_keys = _keys(baits, "bait"), _keys(shooters, "shooter")
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


@app.command()
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


@app.command("table")
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


@app.command()
@bus_options
def sim(
    match: Match,
    seed: int = typer.Option(0),
    frames: int = typer.Option(GameConfig.frames, min=1),
    mode: str = typer.Option("realtime", "--sim-mode", help="realtime (30 Hz) or lockstep."),
    bait: str = typer.Option("", help="Bait's policy key, for the record."),
    shooter: str = typer.Option("", help="Shooter's policy key, for the record."),
    wait_players: float = typer.Option(10.0, help="Seconds to wait for both seats before starting."),
    wait_recorder: float = typer.Option(0.0, help="Seconds to wait for a recorder before starting."),
    wait_adapter: float = typer.Option(0.0, help="Seconds to wait for an adapter before starting."),
    *,
    bus: BusConfig,
) -> None:
    """Run the sim service for one match."""
    from services.sim.service import run_sim

    summary = run_sim(
        bus, match, seed, GameConfig(frames=frames), mode, {"bait": bait, "shooter": shooter},
        stop_on_signals(), wait_players, wait_recorder, wait_adapter=wait_adapter,
    )  # fmt: skip
    logging.getLogger("tsf.sim").info(
        "match %s over: %d kills in %d frames; timing %s", match, summary.kills, summary.frame, summary.timing
    )


@app.command()
@bus_options
def agent(
    match: Match,
    role: str = typer.Option(..., help="bait or shooter"),
    policy: str = typer.Option(..., help="Policy key to play (a library or scripted key)."),
    seed: int = typer.Option(0, help="The match's seed (the policy's seed derives from it)."),
    *,
    bus: BusConfig,
) -> None:
    """Run an agent service that plays one seat."""
    from services.agent.service import run_agent

    run_agent(
        bus,
        match,
        role,
        policy,
        seed,
        stop_on_signals(),
    )


@app.command()
@bus_options
def recorder(
    match: Match,
    out: Path = typer.Option(Path("recordings"), help="Directory of the recordings."),
    *,
    bus: BusConfig,
) -> None:
    """Run the recorder service for one match."""
    from services.recorder.service import run_recorder

    path = run_recorder(bus, match, out, stop_on_signals())
    logging.getLogger("tsf.recorder").info("recording written to %s", path)


@app.command()
@bus_options
def adapter(
    match: Match,
    role: str = typer.Option("shooter", help="The seat of the adaptive agent (its partner plays the other)."),
    window: int = typer.Option(400, min=1, help="T: frames of partner play the similarity averages over."),
    strategy: str = typer.Option("cem", help=f"One of {', '.join(STRATEGIES)}."),
    initial: str = typer.Option(
        "best-average", help="Policy before the first estimate: best-average or random."
    ),
    warmup: int = typer.Option(0, min=0, help="Frames before the first estimate (0: min(T, 150))."),
    dwell: int = typer.Option(0, min=0, help="-dwell strategies: frames a new choice must hold (0: T/10)."),
    hazard: float = typer.Option(
        0.0, min=0.0, max=0.99, help="bayes: per-frame switching probability (0: 1/T)."
    ),
    noise: float = typer.Option(
        0.05, min=0.0, max=0.99, help="bayes: probability of a random partner action."
    ),
    seed: int = typer.Option(0, help="Draws the random initial policy."),
    *,
    bus: BusConfig,
) -> None:
    """Run the adapter service: watch the partner, switch the agent of ROLE to the best response."""
    from services.adapter.core import AdapterConfig
    from services.adapter.service import run_adapter

    config = AdapterConfig(role, window, strategy, initial, warmup, dwell, hazard, noise, seed)
    run_adapter(bus, match, config, stop_on_signals())


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
    match: str = typer.Option("", help="Match id (default: the time and a random suffix)."),
    out: Path = typer.Option(Path("recordings"), help="Directory of the recordings."),
    overwrite: bool = typer.Option(
        False, "--overwrite", help="Reuse the id of an existing recording; the old one is renamed aside."
    ),
    adaptive: str = typer.Option("", help="Make this seat (bait or shooter) the adaptive agent."),
    window: int = typer.Option(400, min=1, help="--adaptive: the window T in frames."),
    strategy: str = typer.Option("cem", help=f"--adaptive: one of {', '.join(STRATEGIES)}."),
) -> None:
    """Start a complete match on this machine: sim, two agents and the recorder as processes (and
    with --adaptive, the adapter)."""
    from services.launch import MatchPlan, new_match_id, run_match
    from services.recorder.recording import export_parquet, load

    plan = MatchPlan(
        match or new_match_id(), seed, round(duration * 30), "lockstep" if lockstep else "realtime",
        bait, shooter, out, adaptive=adaptive, window=window, strategy=strategy,
    )  # fmt: skip
    seats = plan.policies()
    view = {"partner": "-"}

    def adapted(status) -> None:  # noqa: ANN001 - an AdapterStatus
        seats[status.role] = status.policy
        view["partner"] = (status.partner or "?") + (" (out of library)" if status.out_of_library else "")

    with Live(console=console, transient=True) as live:

        def scoreboard(state) -> None:  # noqa: ANN001 - a State
            estimate = f"  partner like {view['partner']}" if adaptive else ""
            live.update(
                f"[bold]{plan.match}[/] frame {state.frame}/{state.frames}  kills [green]{state.kills}[/]  "
                f"points {state.points}  bait {seats['bait']}  shooter {seats['shooter']}{estimate}"
            )

        summary, path = run_match(plan, scoreboard, adapted, overwrite, stop_on_signals())
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


@app.command("replay")
@bus_options
def replay_command(
    recording: Path = typer.Argument(..., exists=True, dir_okay=False, help="A recording (.tsflog)."),
    allow_torn: bool = typer.Option(
        False, "--allow-torn", help="Accept a missing end (no summary, a torn last record), nothing else."
    ),
    video: Path | None = typer.Option(None, help="Write the re-simulated match as an .mp4 or .gif."),
    scale: float = typer.Option(1.0, min=0.1, help="Video pixels per world pixel."),
    every: int = typer.Option(1, min=1, help="Video: draw every N-th frame (the video keeps real speed)."),
    live: bool = typer.Option(False, "--live", help="Put the match back on the bus at the game's pace."),
    speed: float = typer.Option(1.0, min=0.01, help="--live: playback speed (1 = real time)."),
    as_match: str = typer.Option("", "--as", help="--live: publish under this match id (default: its own)."),
    delay: float = typer.Option(1.0, min=0.0, help="--live: seconds to wait for watchers before starting."),
    *,
    bus: BusConfig,
) -> None:
    """Re-simulate a recording and check every state hash; optionally write a video or re-broadcast it."""
    from services.recorder.recording import load, replay
    from services.recorder.replay import republish, write_video

    try:
        loaded = load(recording)
    except ValueError as error:
        raise Failure(str(error)) from None
    if problems := loaded.problems(allow_torn):
        raise Failure(f"{recording}: incomplete: {'; '.join(problems)}")
    mismatches = replay(loaded)
    tail = "" if not loaded.problems() else " [yellow](its end is missing: --allow-torn)[/]"
    if mismatches:
        raise Failure(f"{recording}: {len(mismatches)} states differ, first at frame {mismatches[0]}")
    console.print(f"{recording}: all {len(loaded.states)} states reproduce their hashes{tail}")
    if video is not None:
        count = write_video(loaded, video, scale, every)
        console.print(f"video: {video} ({count} frames)")
    if live:
        sent = republish(bus, recording, as_match or None, speed, delay, stop_on_signals())
        console.print(f"republished {sent} messages")


@app.command()
def alive(
    match: Match,
    service: str = typer.Option(..., help="sim, agent, recorder, adapter or human."),
    role: str = typer.Option("", help="The seat, for an agent or a human."),
    connect: Connect = None,
    timeout: float = typer.Option(2.0, help="Seconds to wait for the bus."),
) -> None:
    """Exit 0 if the service's liveliness token is on the bus, else 1 (a container healthcheck).

    Asks as a zenoh client of the endpoint it connects to (default: this host's tcp/127.0.0.1:7447),
    so the probe never joins the match's mesh of peers."""
    import zenoh

    from shared import keys
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


Host = Annotated[str, typer.Option(help="Address the web page is served on (0.0.0.0: every interface).")]
Port = Annotated[int, typer.Option(min=0, max=65535, help="Port of the web page (0: any free port).")]


@app.command()
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

    run_human(bus, match, tokens, host, port, stop_on_signals(), show)


@app.command("play")
def play_command(
    role: str = typer.Option("bait", help="The seat you play: bait or shooter."),
    partner: str = typer.Option(
        "adaptive",
        help="Who plays the other seat: `adaptive` (the adaptive agent), a policy key (see `tsf "
        "library`), or `human` for a person.",
    ),
    window: int = typer.Option(400, min=1, help="--partner adaptive: the window T in frames."),
    strategy: str = typer.Option("cem", help="--partner adaptive: the adapter's strategy (see tsf match)."),
    seed: int = typer.Option(0, help="The game's seed."),
    duration: float = typer.Option(60.0, min=0.1, help="Game length in seconds (30 frames each)."),
    wait: float = typer.Option(600.0, help="Seconds to wait for the players to press start."),
    host: Host = "127.0.0.1",
    port: Port = 8000,
    match: str = typer.Option("", help="Match id (default: the time and a random suffix)."),
    out: Path = typer.Option(Path("recordings"), help="Directory of the recordings."),
) -> None:
    """Play a match from a browser, with an agent or another person; prints the link(s) to open."""
    from services.agent.library import check_seat
    from services.human.play import play_with_people
    from services.launch import HUMAN, MatchPlan, new_match_id

    if role not in ("bait", "shooter"):
        raise typer.BadParameter("role is bait or shooter")
    other = "shooter" if role == "bait" else "bait"
    seats: dict = {role: HUMAN}
    if partner == "adaptive":
        seats.update(adaptive=other, window=window, strategy=strategy)
    else:
        if partner != HUMAN:
            check_seat(partner, other, "--partner")  # before anyone opens the page
        seats[other] = partner
    plan = MatchPlan(
        match or new_match_id(), seed, round(duration * 30), "realtime", directory=out, wait_players=wait,
        **seats,
    )  # fmt: skip

    def links(urls: dict[str, str]) -> None:
        for seat, url in urls.items():
            console.print(f"[bold]{seat}[/]: open {url}")

    summary, path = play_with_people(plan, host, port, links, stop=stop_on_signals())
    console.print(
        f"[bold]{plan.match}[/]: {summary.kills} kills in {summary.frame} frames "
        f"= {summary.kills_per_minute:.2f} kills/min, points {summary.points}; recording: {path}"
    )


@app.command("eval")
def eval_command(
    role: str = typer.Option("shooter", help="The adaptive agent's seat; the partners play the other."),
    seeds: int = typer.Option(5, min=1, help="Seeded one-minute games per partner and agent."),
    windows: str = typer.Option("150,400,800", help="Windows T of the study's CEM agent (comma-separated)."),
    strategies: str = typer.Option(",".join(STRATEGIES), help="Strategies compared at --strategy-window."),
    strategy_window: int = typer.Option(400, min=1, help="The window of the strategies other than cem."),
    partner: list[str] | None = typer.Option(
        None, help="A partner by name, repeatable (default: the population; see docs/adapter.md)."
    ),
    identify_seeds: int = typer.Option(3, min=1, help="Games per library partner for identification."),
    identify: bool = typer.Option(True, help="Measure identification accuracy."),
    performance: bool = typer.Option(True, help="Measure team performance."),
    workers: int = typer.Option(0, min=0, help="Processes (default: one per core)."),
    out: Path = typer.Option(Path("docs/eval"), help="Directory for the numbers, figures and summary."),
) -> None:
    """Evaluate the adaptive agent in-process: identification, team performance, the test against
    the best static policy, and the figures."""
    import os

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

    from services.adapter import evaluate, figures
    from services.adapter.core import other
    from services.adapter.partners import SWITCH_AT, population
    from services.agent import library

    workers = workers or os.cpu_count() or 1
    try:
        window_list = [int(w) for w in windows.split(",") if w.strip()]
    except ValueError:
        raise UsageError("--windows", windows, "not whole numbers separated by commas") from None
    partners = partner or [p for group in population(other(role)).values() for p in group]
    agents = library.keys(role) + evaluate.variants(window_list, strategies.split(","), strategy_window)
    columns = (BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
    ident, rows, comparison = None, [], None
    with Progress(*columns, console=console) as bar:
        if identify:
            task = bar.add_task("identification", total=None)
            ident = evaluate.identification(
                role, window_list, list(range(identify_seeds)), workers,
                lambda done, total: bar.update(task, completed=done, total=total),
            )  # fmt: skip
        if performance:
            task = bar.add_task("team games", total=None)
            rows = evaluate.team(
                role, partners, agents, list(range(seeds)), workers,
                lambda done, total: bar.update(task, completed=done, total=total),
            )  # fmt: skip
            comparison = evaluate.compare(rows)
    summary = evaluate.write_results(out, ident, rows, comparison)
    if ident:
        figures.accuracy_vs_window(ident, out / "identification.png")
        keys = library.keys(other(role))
        first, second = keys[0], keys[len(keys) // 2]
        scores = evaluate.switch_scores(first, second, 0, role)
        title = f"Partner noisy(switch({first},{second})), switching at {SWITCH_AT / 30:.0f} s"
        figures.logprob_curves(scores, keys, min(window_list), title, out / "logprob_curves.png", SWITCH_AT)
    if comparison:
        figures.adaptive_vs_static(comparison, out / "adaptive_vs_static.png")
    console.print(summary.read_text())
    console.print(f"written to {out}")


@app.command("calibrate-adapter")
def calibrate_adapter(
    workers: int = typer.Option(0, min=0, help="Processes (default: one per core)."),
) -> None:
    """Measure the adapter's out-of-library thresholds into services/adapter/calibration.json."""
    import os

    from services.adapter.evaluate import calibrate, write_calibration

    result = calibrate(workers=workers or os.cpu_count() or 1)
    for role, thresholds in result["thresholds"].items():
        console.print(f"{role}: " + ", ".join(f"T={t}: {v:.2f}" for t, v in thresholds.items()))
    console.print(f"written to {write_calibration(result)}")


@app.command("report")
def report_command(
    recordings: list[Path] = typer.Argument(..., help="Recordings (.tsflog); bad ones are named, left out."),
    out: Path = typer.Option(Path("report"), help="Directory for report.html, figures/, data/ and parquet/."),
    table: Path | None = typer.Option(None, help="The self-play table (default: the library's)."),
    partner_role: str = typer.Option(
        "", help="Only this seat is the partner in agent-agent matches (default: each seat in turn)."
    ),
    trial: str = typer.Option("", help="Match whose log-prob curves are drawn (default: the first)."),
    reference_games: int = typer.Option(2, min=1, help="Games per library policy for the reference points."),
) -> None:
    """The study's figures and numbers from recordings: one self-contained HTML report."""
    from services.report.report import build_report
    from services.table.table import DEFAULT_TABLE, StaleTable

    if partner_role not in ("", "bait", "shooter"):
        raise typer.BadParameter("bait or shooter", param_hint="--partner-role")
    try:
        report = build_report(
            recordings, out, table or DEFAULT_TABLE, partner_role or None, trial or None, reference_games
        )
    except StaleTable as error:
        console.print(f"[red]{error}[/]")
        raise typer.Exit(1) from None
    for problem in report.problems:
        colour = "yellow" if problem.used else "red"
        console.print(f"[{colour}]{problem.name}: {problem.reason}[/]")
    console.print(f"report: {report.html}  ({len(report.figures)} figures, numbers in {out / 'data'})")
    if not report.matches:
        raise Failure(f"none of the {len(recordings)} recordings is usable; {report.html} names why")


@app.command()
def study(
    config: Path = typer.Argument(
        ..., exists=True, dir_okay=False, help="The study's TOML file (see services/study/configs/)."
    ),
    out: Path = typer.Option(Path("studies"), help="Studies go to OUT/<name>: progress and recordings."),
    host: Host = "127.0.0.1",
    port: Port = 8000,
) -> None:
    """Serve a study: participants open the link, consent, get a role and play every agent variant."""
    from services.study.core import StudyConfig
    from services.study.runner import run_study

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    protocol = StudyConfig.load(config)
    directory = out / protocol.name

    def show(gateway) -> None:  # noqa: ANN001 - a Gateway
        console.print(
            f"[bold]{protocol.name}[/]: {len(protocol.variants)} agents x {protocol.trials} trials of "
            f"{protocol.trial_seconds:g} s; progress and recordings in {directory}"
        )
        console.print(f"participants open [bold]{gateway.url}[/] (Ctrl-C ends the study server)")

    done = run_study(protocol, directory, host, port, stop_on_signals(), show)
    finished = sum(done.next_trial(p) is None for p in done.participants.values())
    console.print(f"{len(done.participants)} participants, {finished} finished")


def main() -> None:
    """The `tsf` command (services/entry.py: one line, not a traceback, when it ends badly)."""
    from services.entry import run

    raise SystemExit(run(app))


if __name__ == "__main__":
    main()
