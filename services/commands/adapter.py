"""`tsf` commands for measuring the adaptive agent and the library it reads: diversity, eval,
calibrate-adapter."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from services.agent.seats import policy_for
from services.commands.options import (
    GAMES,
    LOCAL_WORKERS,
    PEOPLE_RECORDINGS,
    RAY,
    Partners,
    Role,
    Strategies,
    bus_options,
    console,
    given,
    number,
    output,
    progress_bars,
    refuse_beside,
)
from services.population.adaptive import WINDOWS, AdapterConfig
from shared.bus import BusConfig, stop_on_signals
from shared.errors import UsageError
from shared.game import ROLES, Range, other

if TYPE_CHECKING:
    from services.evaluation.populations import Population

commands = typer.Typer()


@commands.command()
def diversity(
    games: int = number(5, GAMES, "Seeded games of each policy."),
    bait_partner: str = typer.Option("S4", help="The shooter every bait plays with."),
    shooter_partner: str = typer.Option("B1", help="The bait every shooter plays with."),
    out: Path | None = output(
        None, "Write the two matrices as CSV files into this directory.", directory=True
    ),
) -> None:
    """The library's CEM matrices: mean log-probability of policy i's actions under policy j."""
    from services.adapter.cem import cem_matrix
    from services.agent import library, networks

    partners = {  # both checked before the first matrix
        "bait": policy_for(bait_partner, "shooter", "--bait-partner"),
        "shooter": policy_for(shooter_partner, "bait", "--shooter-partner"),
    }
    for role, partner in (("bait", bait_partner), ("shooter", shooter_partner)):
        keys = library.keys(role)
        m = cem_matrix([networks.load(k) for k in keys], partners[role], list(range(games)))
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


# The options of `tsf eval` that choose or play games: nothing with --games, whose games were played.
PLAYING = (
    "seeds", "window", "strategy", "strategy_window", "variants", "partner", "partners_from", "population",
    "held_out", "identify_seeds", "sessions", "workers", "job_games", "sweep_id", "ray",
)  # fmt: skip


def _population(
    context: typer.Context, role: str, name: str, partner: list[str], partners_from: Path | None, out: Path
) -> Population:
    """The partners' population the options name: `--population` (`--held-out` its alias), or a
    user's list (`--partner`, `--partners-from`). Options that contradict it are one line, before
    anything runs: partners beside a named population, strategies beside a test split."""
    from services.evaluation import populations

    named = given(context, "population") or given(context, "held_out")
    population_option = "--held-out" if given(context, "held_out") else "--population"
    beside = f"beside {population_option}" + ("" if given(context, "held_out") else f" {name}")
    for option, value in (("--partner", partner[0] if partner else None), ("--partners-from", partners_from)):
        if named and value is not None:
            raise UsageError(option, value, f"{beside}: give partners or a population, not both")
    if partner and partners_from is not None:
        raise UsageError("--partners-from", partners_from, "give --partner or --partners-from, not both")
    if partners_from is not None:
        from services.proxy.study import partners_from as study_partners

        people, excluded = study_partners(partners_from, other(role), out / "proxies")
        for line in excluded:
            console.print(f"excluded {line}")
        console.print(f"partners: {', '.join(people.values())}")
        return populations.listed(list(people.values()), other(role), f"partners from {partners_from}")
    if partner:
        return populations.listed(partner, other(role))
    chosen = populations.named(name, other(role), population_option)
    asked = {"--strategy": given(context, "strategy"), "--variants": given(context, "variants")}
    for option in (o for o, yes in asked.items() if yes and chosen.run is not None):
        strategies = context.params["strategy"] or ()
        value = ",".join(s.value for s in strategies) if option == "--strategy" else "given"
        raise UsageError(
            option,
            value,
            f"{beside}: a test split measures the shipped agents at "
            "--strategy-window, not the study's variants; compare those on another population",
            [n for n in populations.NAMES if n != populations.HELD_OUT] + ["your --partner list"],
        )
    return chosen


# `tsf eval`'s options that say the most, as types (Typer's Annotated form), so that the command
# reads as its parameters.
Population = Annotated[
    str,
    typer.Option(
        help="The partners, by name: default (every library policy, its noisy, delayed, sticky and "
        "human-like stand-ins, switchers and partners outside the library), held-out (the shipped "
        "grown library's test split: partners its growth never saw), or a grown library's directory "
        "(its test split); docs/adapter.md.",
    ),
]
PartnerList = Annotated[
    list[str] | None,
    typer.Option(help="A partner by name, repeatable: your own population (instead of --population)."),
]
PartnersFrom = Annotated[
    Path | None,
    typer.Option(
        help="A study's recordings: one proxy per participant of the partners' seat (trained into "
        "OUT/proxies, or loaded from there) as the partners, reported per participant and pooled; "
        "or a directory of `tsf humans fit`: each participant's fitted stand-in.",
    ),
]
Windows = Annotated[
    list[int] | None,
    number(
        ...,
        WINDOWS,
        "A window T of identification and, with --variants, of the study's CEM agent, "
        "repeatable (default: 150, 400, 800).",
    ),
]
Variants = Annotated[
    bool,
    typer.Option(
        help="Compare the study's adaptive variants (its CEM agent at each --window, each --strategy "
        "at --strategy-window) with the study's static policies, instead of the shipped agents (the "
        "static policies of every shipped library, the default agent and the study's).",
    ),
]
StrategyList = Annotated[
    list[Strategies] | None,
    typer.Option(
        help="A strategy compared at --strategy-window, repeatable (means --variants; default: all; a "
        "-skill one only where its skill model was measured for the seat and window).",
    ),
]
Games = Annotated[
    Path | None,
    typer.Option(
        help="Team games already played (an evaluation's team.csv): analysed again, not played; the "
        "comparison, per_partner.csv, the figure and summary.md go to --out (no identification).",
    ),
]


@commands.command("eval")
@bus_options
def eval_command(
    context: typer.Context,
    role: Role = typer.Option("shooter", help="The adaptive agent's seat; the partners play the other."),
    population: Population = "default",
    held_out: bool = typer.Option(False, help="The same as --population held-out."),
    partner: PartnerList = None,
    partners_from: PartnersFrom = None,
    seeds: int = number(5, GAMES, "Seeded one-minute games per partner and agent."),
    window: Windows = None,
    variants: Variants = False,
    strategy: StrategyList = None,
    strategy_window: int = number(
        AdapterConfig.window, WINDOWS, "The window of the adaptive agents other than the CEM variants."
    ),
    identify_seeds: int = number(3, GAMES, "Games per library partner for identification."),
    identify: bool = typer.Option(True, help="Measure identification accuracy."),
    performance: bool = typer.Option(True, help="Measure team performance."),
    sessions: bool = typer.Option(
        False, help="Play team games as sessions of three trials with the same partner (--seeds: people)."
    ),
    workers: int = LOCAL_WORKERS,
    out: Path = output(
        Path("tsf-eval"),
        "Directory for the numbers, figures and summary, and the journal a stopped run resumes from "
        "(the shipped results: --out docs/eval).",
        directory=True,
    ),
    job_games: int | None = number(
        None,
        Range(1, 1000),  # 1,000 team games of the population are about 32 KiB: a message has 64
        "Games of one job, played as one batch (default: 256 team, 32 identification games).",
    ),
    sweep_id: str = typer.Option(
        "eval", "--sweep", help="Sweep id of the jobs: tsf worker --sweep ID joins."
    ),
    games: Games = None,
    ray: str | None = RAY,
    *,
    bus: BusConfig,
) -> None:
    """Evaluate the adaptive agent on the job system's workers (here, and any `tsf worker --sweep
    eval` reached with --connect): identification, team performance against a population of
    partners (the one thing to choose: --population, or your own --partner), the test against the
    best static policy, and the figures. By default the shipped agents are compared: the static
    policies of every shipped library, the default agent and the study's. Resumable; the numbers
    do not depend on the workers. With --games, an evaluation's games are analysed again."""
    from services.evaluation.evaluation import KINDS, EvalPlan, evaluate, reanalyse
    from services.jobs.engine import on_workers, open_engine

    if role not in ROLES:
        raise UsageError("--role", role, "not a seat", ROLES)
    if not (identify or performance):
        raise UsageError("--no-identify", "with --no-performance", "measures nothing: leave one out")
    if games is not None:
        played_only = {name: f"--{name.replace('_', '-')}" for name in PLAYING}
        refuse_beside(context, "--games", games, "its games are analysed as they were played", played_only)
        summary = reanalyse(games, role, out)
        console.print(summary.read_text())
        console.print(f"written to {out}")
        return
    if held_out and given(context, "population") and population != "held-out":
        raise UsageError("--held-out", f"with --population {population}", "give one population")
    name = "held-out" if held_out else population
    partners = _population(context, role, name, partner or [], partners_from, out)
    plan = EvalPlan(
        role, partners, seeds, tuple(window or EvalPlan.windows), tuple(s.value for s in strategy or ()),
        strategy_window, identify_seeds, identify, performance, sessions, job_games, variants,
    )  # fmt: skip
    with (
        open_engine(bus, sweep_id, out / "eval.journal", KINDS, workers, ray, stop_on_signals()) as engine,
        progress_bars() as shown,
    ):
        report = evaluate(plan, on_workers(engine), shown)
    summary = report.write(out)
    console.print(summary.read_text())
    console.print(f"written to {out}")


@commands.command("calibrate-adapter")
@bus_options
def calibrate_adapter(
    workers: int = LOCAL_WORKERS,
    out: Path = output(
        Path("tsf-calibration.json"),
        "Where the thresholds go (the adapter reads calibration.json beside the table, in the library "
        "directory in use; name it here to replace it), and its journal (OUT.journal).",
    ),
    sweep_id: str = typer.Option(
        "calibrate", "--sweep", help="Sweep id of the jobs: tsf worker --sweep ID joins."
    ),
    seeds: int = number(
        2, GAMES, "Seeded one-minute games of each pair (seeds 0..N-1); 2 for the shipped one."
    ),
    ray: str | None = RAY,
    partners: Partners = typer.Option(
        "library",
        help="library: the study's library policies (calibration.json); groups: the grown library's "
        "partner groups' members, written into a copy of its groups.json at --out.",
    ),
    *,
    bus: BusConfig,
) -> None:
    """Measure the adapter's out-of-library thresholds: one game of each library policy with each
    of the other seat's, per seed (or of each partner group's member with each member of ours), as
    jobs on the job system's workers or on Ray. Resumable."""
    from services.evaluation.thresholds import KINDS, calibrate, write_calibration
    from services.jobs.engine import on_workers, open_engine

    if partners == "groups" and out.exists():  # the groups' figures go into a groups file, nothing else
        try:
            seats = json.loads(out.read_text())["seats"]
        except (OSError, ValueError, KeyError, TypeError):
            seats = None
        if not isinstance(seats, dict):
            raise UsageError(
                "--out", out, "not a groups file (groups.json): --partners groups writes into one"
            )
    journal = out.with_name(out.name + ".journal")
    with (
        open_engine(bus, sweep_id, journal, KINDS, workers, ray, stop_on_signals()) as engine,
        progress_bars() as shown,
    ):
        result = calibrate(
            seeds=list(range(seeds)),
            run=on_workers(engine),
            progress=shown("frames played"),
            partners=partners,
        )
    for role, thresholds in result["thresholds"].items():
        console.print(f"{role}: " + ", ".join(f"T={t}: {v:.2f}" for t, v in thresholds.items()))
    console.print(f"written to {write_calibration(result, out)}")


humans_commands = typer.Typer(no_args_is_help=True, help="Stand-ins for people (docs/humans.md).")
commands.add_typer(humans_commands, name="humans")


@humans_commands.callback()
def humans_command() -> None:
    """Stand-ins for people: human-like partners fitted from recordings (docs/humans.md)."""


@humans_commands.command("fit")
def humans_fit(
    recordings: list[Path] = PEOPLE_RECORDINGS,
    role: Role = typer.Option(..., help="The person's seat."),
    out: Path = output(..., "Directory the stand-ins are written into.", directory=True),
) -> None:
    """Fit a stand-in per participant: the likeliest library policy, the skill whose simulated
    stand-ins come nearest the participant's keys and score, and the model's own parameters
    (reaction, looks, holds, fire habits, lapses, slips, foresight), which the stand-in plays
    with. Play one as humans:OUT@PARTICIPANT."""
    import shlex
    import sys

    from services.proxy.humans import fit, write

    fitted = fit(recordings, role)
    path = write(out, role, fitted, shlex.join(["tsf", *sys.argv[1:]]))
    for name, person in fitted.items():
        s = person["statistics"]
        console.print(
            f"{name}: {person['partner']} ({len(person['recordings'])} recordings; "
            f"{s['kills_per_minute']:.2f} kills/min, {s['key_changes_per_s']:.1f} key changes/s, "
            f"shortest press {s['hold_ms']:.0f} ms, "
            f"response {s['response_ms']:.0f} ms)"
        )
        fitted_with = ", ".join(
            f"{k} {v:.3g}" + (f" ± {person['errors'][k]:.2g}" if k in person["errors"] else "")
            for k, v in person["parameters"].items()
        )
        console.print(f"  parameters (± the fit's error): {fitted_with}")
        t = person["traits"]
        console.print(
            "  traits: " + ", ".join(f"{k} {'-' if v is None else f'{v:.3g}'}" for k, v in t.items())
        )
    console.print(f"written to {path}; play one as humans:{out}@PARTICIPANT")
