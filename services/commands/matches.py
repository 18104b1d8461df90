"""`tsf` commands for whole matches and the people in them: match, play, study, match-host, replay."""

from __future__ import annotations

import ipaddress
import os
import socket
from pathlib import Path

import typer
from rich.live import Live

from services.commands.options import (
    PORTS,
    SECONDS,
    SLOTS,
    AdapterFactory,
    Duration,
    Frames,
    Host,
    Port,
    Role,
    Seed,
    adapter_options,
    bus_options,
    console,
    free_port,
    game_frames,
    keys_help,
    number,
    output,
    refuse_beside,
)
from shared.bus import BusConfig, stop_on_signals
from shared.errors import Failure, UsageError
from shared.game import FRAMES, ROLES, Range, other

commands = typer.Typer()


HOST_SECRET = typer.Option(
    None,
    envvar="TSF_HOST_SECRET_FILE",
    dir_okay=False,
    help="A file holding the secret the study server and its match hosts share (at least 16 "
    "characters); every message between them is sealed with it.",
)


def host_secret_of(path: Path | None) -> bytes:
    """The host secret from its file; match hosts without one are a UsageError."""
    from shared.secret import read_secret

    if path is None:
        raise UsageError(
            "--host-secret", "(none)", "the study server and its match hosts need a shared secret: its file"
        )
    return read_secret(path, "--host-secret")


@commands.command("match")
@adapter_options("role", "seed")
def match_command(
    context: typer.Context,
    seed: Seed = 0,
    duration: Duration = None,
    frames: Frames = None,
    bait: str = typer.Option("circle", help=keys_help("bait", "Bait agent's policy key")),
    shooter: str = typer.Option("mirror", help=keys_help("shooter", "Shooter agent's policy key")),
    lockstep: bool = typer.Option(
        False, help="Lockstep (as fast as the agents answer) instead of real time."
    ),
    match: str = typer.Option("", help="Match id (default: the time and a random suffix)."),
    out: Path = output(Path("recordings"), "Directory of the recordings.", directory=True),
    overwrite: bool = typer.Option(
        False, "--overwrite", help="Reuse the id of an existing recording; the old one is renamed aside."
    ),
    adaptive: Role | None = typer.Option(
        None,
        help="Make this seat the adaptive agent: the shipped default, the tuned library's agent over "
        "partner groups, unless the adapter options say otherwise (its results in either seat: "
        "docs/adapter.md).",
    ),
    *,
    adapter: AdapterFactory,
) -> None:
    """Start a complete match on this machine: sim, two agents and the recorder as processes (and
    with --adaptive, the adapter, set by the adapter options)."""
    from services.population.seat import SeatSpec
    from services.recorder.export import export
    from services.recorder.recording import load
    from services.runtime.launch import MatchPlan, new_match_id, run_match

    if adaptive and adaptive not in ROLES:
        raise UsageError("--adaptive", adaptive, "not a seat", ROLES)
    if adaptive:
        refuse_beside(
            context, "--adaptive", adaptive, "the adaptive agent plays that seat", {adaptive: f"--{adaptive}"}
        )
    config = adapter(role=adaptive or ROLES[1], seed=seed)  # its options are checked with or without
    seats = {"bait": SeatSpec.parse(bait, "--bait"), "shooter": SeatSpec.parse(shooter, "--shooter")}
    if adaptive:
        seats[adaptive] = SeatSpec.adaptive_agent(config)
    plan = MatchPlan(
        match or new_match_id(), seed, game_frames(duration, frames), "lockstep" if lockstep else "realtime",
        directory=out, **seats,
    )  # fmt: skip
    seats = plan.policies()
    view = {"partner": "?", "switches": 0}  # "?" until the adapter names a partner

    def adapted(status) -> None:  # noqa: ANN001 - an AdapterStatus
        if status.policy != seats[status.role]:  # a switch: counted, so that the scoreboard shows it
            view["switches"] += 1
        seats[status.role] = status.policy
        view["partner"] = (status.partner or "?") + (" (out of library)" if status.out_of_library else "")

    with Live(console=console, transient=True) as live:

        def scoreboard(state) -> None:  # noqa: ANN001 - a State
            estimate = f"  partner like {view['partner']}, switches {view['switches']}" if adaptive else ""
            live.update(
                f"[bold]{plan.match}[/] frame {state.frame}/{state.frames}  kills [green]{state.kills}[/]  "
                f"points {state.points}  bait {seats['bait']}  shooter {seats['shooter']}{estimate}"
            )

        summary, path = run_match(plan, scoreboard, adapted, overwrite, stop_on_signals())
    tables = export(load(path), path.with_suffix(".tables"))
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
    console.print(f"  recording: {path}  (Parquet tables: {tables['states'].parent})")
    if summary.failures:  # the match ran to its end; its result is not what the policies would play
        seats = ", ".join(f"the {role}'s on {n} frames" for role, n in summary.failures.items())
        where = f"policy_failure events in {path}"
        raise Failure(f"match {plan.match}: a policy failed and played no-op: {seats} ({where})")


@commands.command("play")
@adapter_options("role", "seed")
def play_command(
    role: Role = typer.Option("bait", help="The seat you play."),
    partner: str = typer.Option(
        "adaptive",
        help="Who plays the other seat: `adaptive` (the adaptive agent), a policy key (`tsf keys` lists "
        "every key that loads), or `human` for a person.",
    ),
    seed: Seed = 0,
    duration: Duration = None,
    frames: Frames = None,
    wait: float = number(600.0, SECONDS, "Seconds to wait for the players to press start."),
    host: Host = "127.0.0.1",
    port: Port = 8000,
    match: str = typer.Option("", help="Match id (default: the time and a random suffix)."),
    out: Path = output(Path("recordings"), "Directory of the recordings.", directory=True),
    *,
    adapter: AdapterFactory,
) -> None:
    """Play a match from a browser, with an agent or another person; prints the link(s) to open."""
    from services.human.play import play_with_people
    from services.population.seat import PersonSeat, SeatSpec, check_live
    from services.runtime.launch import MatchPlan, new_match_id

    if role not in ROLES:
        raise typer.BadParameter("role is bait or shooter")
    partner_role = other(role)
    seats = {role: PersonSeat()}
    if partner == "adaptive":
        seats[partner_role] = SeatSpec.adaptive_agent(adapter(role=partner_role, seed=seed))
    else:
        spec = SeatSpec.parse(partner, "--partner")
        seats[partner_role] = check_live(spec, partner_role, "--partner")  # before anyone opens the page
    plan = MatchPlan(
        match or new_match_id(), seed, game_frames(duration, frames), "realtime", directory=out,
        wait_players=wait, **seats,
    )  # fmt: skip

    def links(urls: dict[str, str]) -> None:
        for seat, url in urls.items():
            console.print(f"[bold]{seat}[/]: open {url}")

    free_port(host, port)
    summary, path = play_with_people(plan, host, port, links, stop=stop_on_signals())
    console.print(
        f"[bold]{plan.match}[/]: {summary.kills} kills in {summary.frame} frames "
        f"= {summary.kills_per_minute:.2f} kills/min, points {summary.points}; recording: {path}"
    )


RATES = Range(0.0, 1000.0)  # a limit's events a second (0: no limit)
ARRIVALS = Range(0.01, 1000.0)  # new participant ids a second, for everyone (always limited)


def ip_address(text: str, option: str) -> str:
    """`text` as an IP address, as a peer's address is written (a UsageError for anything else)."""
    try:
        return str(ipaddress.ip_address(text.strip()))
    except ValueError:
        raise UsageError(option, text, "an IP address, e.g. 127.0.0.1 or ::1") from None


STUDY_CONFIG = typer.Argument(
    ..., exists=True, dir_okay=False, help="The study's TOML file (see services/study/configs/)."
)
MAX_MATCHES = typer.Option(
    4, min=0, help="Matches at once on this machine (0: only on match hosts); more wait in a queue."
)
TRIAL_TIMEOUT = typer.Option(
    120.0, min=1.0, help="Seconds a trial's match may take beyond its length before it is ended and replayed."
)
CERT = typer.Option(None, exists=True, dir_okay=False, help="TLS certificate chain (PEM).")
KEY = typer.Option(None, exists=True, dir_okay=False, help="TLS private key (PEM), with --cert.")
ORIGIN = typer.Option(
    None,
    help="The study's public origin, e.g. https://study.example.org: its pages may open the socket "
    "and requests for its host name are taken (repeatable; needed when participants reach the "
    "server by a name, as behind a reverse proxy).",
)
PER_ADDRESS = typer.Option(8, min=0, help="Sockets one address may hold at once (0: no cap).")
MAX_LAG = number(
    25.0,
    Range(0.0, 1000.0),
    "Milliseconds this machine's matches' frames may reach the server late (the worst of the last "
    "5 s) before new matches wait until they catch up (0: never).",
)
TRUSTED_PROXY = typer.Option(
    None,
    help="A reverse proxy's address (e.g. 127.0.0.1) whose X-Forwarded-For names the client: the "
    "limits per address count clients, not the proxy (repeatable; no other peer's header is read).",
)
ARRIVALS_OPTION = number(1.0, ARRIVALS, "New participant ids a second, on average (bursts of 20).")
ARRIVALS_PER_ADDRESS = number(
    0.1, RATES, "New participant ids a second from one address (bursts of 5; 0: no limit)."
)
RECONNECTS = number(
    0.1,
    RATES,
    "Reconnects a second of one participant, by any way back in (their id and key, a signed link, "
    "the platform's link; bursts of 5); 0: none, a participant who leaves cannot come back.",
)
TEST_TOKEN = typer.Option(
    "", envvar="TSF_TEST_TOKEN", help="Stand-ins that show this token get the observation values."
)
LINK_SECRET = typer.Option(
    None,
    envvar="TSF_LINK_SECRET_FILE",
    dir_okay=False,
    help="Sign the links: a file holding the secret; new participants then need a worker id and "
    "its signature (sig=HMAC-SHA256 of the id, hex).",
)
LISTEN = typer.Option(
    None,
    help="Be the router that match hosts (`tsf match-host`) connect to, at this zenoh endpoint, "
    "e.g. tcp/0.0.0.0:7447 (repeatable).",
)
CONNECT = typer.Option(
    None, help="Meet match hosts at this zenoh router (`tsf router`), e.g. tcp/10.0.0.1:7447 (repeatable)."
)
DASHBOARD_TOKEN = typer.Option(
    None,
    exists=True,
    dir_okay=False,
    help="Serve the experimenter's dashboard to whoever shows the token this file holds "
    "(16-64 characters, e.g. from `openssl rand -hex 24`), on --dashboard-port.",
)
DASHBOARD_PORT = number(8001, PORTS, "Port of the experimenter's dashboard (--dashboard-token).")
CHECK = typer.Option(
    False,
    "--check",
    help="Check everything serving would refuse (the study's config: every setting, every variant's "
    "agent in every seat; and the serving options beside it: ports, TLS files, proxies, secrets, "
    "capacity), say so and exit: a lab's pre-flight. Nothing is started or written.",
)


@commands.command()
def study(
    config: Path = STUDY_CONFIG,
    out: Path = output(Path("studies"), "Studies go to OUT/<name>: progress and recordings.", directory=True),
    host: Host = "127.0.0.1",
    port: Port = 8000,
    max_matches: int = MAX_MATCHES,
    trial_timeout: float = TRIAL_TIMEOUT,
    cert: Path | None = CERT,
    key: Path | None = KEY,
    origin: list[str] | None = ORIGIN,
    per_address: int = PER_ADDRESS,
    max_lag: float = MAX_LAG,
    trusted_proxy: list[str] | None = TRUSTED_PROXY,
    arrivals: float = ARRIVALS_OPTION,
    arrivals_per_address: float = ARRIVALS_PER_ADDRESS,
    reconnects: float = RECONNECTS,
    test_token: str = TEST_TOKEN,
    link_secret: Path | None = LINK_SECRET,
    listen: list[str] | None = LISTEN,
    connect: list[str] | None = CONNECT,
    host_secret: Path | None = HOST_SECRET,
    dashboard_token: Path | None = DASHBOARD_TOKEN,
    dashboard_port: int = DASHBOARD_PORT,
    check: bool = CHECK,
) -> None:
    """Serve a study: participants open the link, consent, get a role and play every agent variant.
    With --listen or --connect, match hosts on other machines add capacity beyond --max-matches.
    Everything is checked before anything starts, --check or not: a mistake in the config or in the
    options is one line (exit 2)."""
    from services.human.gateway import Web
    from services.study.crowd import BONUSES
    from services.study.preflight import load_checked
    from services.study.runner import no_server, run_study
    from services.study.serving import Serving, check_tls

    trusted = tuple(ip_address(a, "--trusted-proxy") for a in trusted_proxy or ())
    hosts, sealing, signed = _study_bus(max_matches, listen, connect, host_secret, link_secret)
    check_tls(cert, key)
    board, token = _dashboard(dashboard_token, dashboard_port, host, port, cert, key, trusted)
    free_port(host, port)  # before the pool starts and anything is written
    protocol = load_checked(config)
    web = Web(host, port, cert, key, tuple(origin or ()), per_address, trusted)
    serving = Serving(
        max_matches, trial_timeout, test_token=test_token, hosts=hosts, link_secret=signed,
        host_secret=sealing, dashboard=board, dashboard_token=token,
        arrivals=arrivals, arrivals_per_address=arrivals_per_address, reconnects=reconnects,
        max_lag=max_lag / 1e3,
    )  # fmt: skip
    directory = out / protocol.name
    if check:
        no_server(directory)
        console.print(
            f"{config}: study {protocol.name}, {len(protocol.variants)} variants x {protocol.trials} "
            f"trials of {protocol.trial_seconds:g} s: every setting, every variant's agent in each "
            "seat it plays and every serving option checked; ready to serve"
        )
        return

    def show(gateway) -> None:  # noqa: ANN001 - a Gateway
        console.print(
            f"[bold]{protocol.name}[/]: {len(protocol.variants)} agents x {protocol.trials} trials of "
            f"{protocol.trial_seconds:g} s; progress and recordings in {directory}"
        )
        console.print(f"participants open [bold]{gateway.url}[/] (Ctrl-C ends the study server)")
        if board is not None:
            dashboard = gateway.url.replace(f":{gateway.port}/", f":{board.port}/")
            console.print(f"the dashboard: [bold]{dashboard}#token=[/]<the token in {dashboard_token}>")

    done = run_study(protocol, directory, web, stop_on_signals(), show, serving)
    finished = sum(done.next_trial(p) is None for p in done.participants.values())
    console.print(f"{len(done.participants)} participants, {finished} finished")
    if protocol.crowd.bonus is not None:
        console.print(f"bonuses for the platform's bulk upload: {directory / BONUSES}")


def _study_bus(
    max_matches: int,
    listen: list[str] | None,
    connect: list[str] | None,
    host_secret: Path | None,
    link_secret: Path | None,
) -> tuple[BusConfig | None, bytes, bytes]:
    """The study's router for match hosts (None: this machine only), the host secret that seals
    their messages and the link secret; a UsageError where no match could run."""
    from shared.secret import read_secret

    hosts, sealing = None, b""
    if listen or connect:
        hosts = BusConfig("router" if listen else "client", tuple(listen or ()), tuple(connect or ()))
        sealing = host_secret_of(host_secret)
    elif max_matches == 0:
        raise UsageError(
            "--max-matches",
            0,
            "no match could run: give match hosts with --listen or --connect, or 1 or more",
        )
    return hosts, sealing, read_secret(link_secret, "--link-secret") if link_secret else b""


def _dashboard(
    token_file: Path | None,
    port: int,
    host: str,
    study_port: int,
    cert: Path | None,
    key: Path | None,
    trusted: tuple[str, ...],
):  # noqa: ANN202 - (Web | None, str)
    """Where the experimenter's dashboard is served and its token; (None, "") without --dashboard-token."""
    from services.human.gateway import Web
    from services.study.dashboard import read_token

    if token_file is None:
        return None, ""
    try:
        token = read_token(token_file.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        raise UsageError("--dashboard-token", str(token_file), str(error)) from None
    if port == study_port:
        raise UsageError("--dashboard-port", port, "the participants' port: give another")
    free_port(host, port, "--dashboard-port")
    return Web(host, port, cert, key, trusted=trusted), token


@commands.command("match-host")
@bus_options
def match_host_command(
    slots: int = number(2, SLOTS, "Matches this host runs at once."),
    host_id: str = typer.Option("", "--id", help="This host's name (default: host name and pid)."),
    out: Path = output(Path("recordings"), "Directory of the recordings made here.", directory=True),
    host_secret: Path | None = HOST_SECRET,
    *,
    bus: BusConfig,
) -> None:
    """Run the matches a study server offers over the router (`--connect` the study's router), up to
    --slots at once; their recordings go back to the server, hash checked."""
    from services.study.host import run_match_host

    name = host_id or f"{socket.gethostname()}-{os.getpid()}".replace(".", "-")
    if not bus.connect:
        raise UsageError(
            "--connect", "(none)", "a match host needs the router's endpoint, e.g. tcp/10.0.0.1:7447"
        )
    played = run_match_host(bus, name, slots, out, stop_on_signals(), host_secret_of(host_secret))
    console.print(f"match host {name} ran {played} matches")


@commands.command("replay")
@bus_options
def replay_command(
    recording: Path = typer.Argument(..., exists=True, dir_okay=False, help="A recording (.tsflog)."),
    allow_torn: bool = typer.Option(
        False, "--allow-torn", help="Accept a missing end (no summary, a torn last record), nothing else."
    ),
    video: Path | None = output(None, "Write the re-simulated match as an .mp4 or .gif."),
    scale: float = number(1.0, Range(0.1, 10.0), "Video pixels per world pixel."),
    every: int = number(1, FRAMES, "Video: draw every N-th frame (the video keeps real speed)."),
    live: bool = typer.Option(False, "--live", help="Put the match back on the bus at the game's pace."),
    speed: float = number(1.0, Range(0.01, 100.0), "--live: playback speed (1 = real time)."),
    as_match: str = typer.Option("", "--as", help="--live: publish under this match id (default: its own)."),
    delay: float = number(1.0, SECONDS, "--live: seconds to wait for watchers before starting."),
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
