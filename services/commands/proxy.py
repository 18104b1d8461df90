"""`tsf proxy`: human proxies cloned from recorded play (docs/proxies.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from services.commands.options import PEOPLE_RECORDINGS, Role, console, number, output
from services.proxy import trainer
from services.proxy.data import HISTORY
from shared.game import SEEDS, Range

commands = typer.Typer()
proxy_commands = typer.Typer(no_args_is_help=True, help="Human proxies: policies cloned from recorded play.")
commands.add_typer(proxy_commands, name="proxy")
SHARE = Range(0.01, 0.99)
EPOCHS = Range(1, 10_000)
WIDTH = Range(1, 4096)


@proxy_commands.callback()
def proxy_command() -> None:
    """Human proxies: policies cloned from recorded play (docs/proxies.md)."""


@proxy_commands.command("train")
def train_command(
    recordings: list[Path] = PEOPLE_RECORDINGS,
    role: Role = typer.Option(..., help="The person's seat to clone."),
    out: Path = output(..., "Directory the proxy is written into.", directory=True),
    held_out: float = number(0.25, SHARE, "Share of the participants held out (at least one)."),
    seed: int = number(0, SEEDS, "Seed of the split and the training."),
    epochs: int = number(200, EPOCHS, "Epochs at most."),
    patience: int = number(10, EPOCHS, "Epochs without a better held-out log-likelihood before stopping."),
    hidden: list[int] = typer.Option([64, 64], help="Hidden layer widths, repeatable."),
    history: int = number(0, Range(0, HISTORY), "The proxy's own last actions it reads (keys held down)."),
) -> None:
    """Clone the person's seat of the recordings: behaviour cloning with a held-out split by
    participant, early stopping on held-out log-likelihood; writes the numpy proxy, its manifest and
    the learning curve. Play it as proxy:OUT."""
    for width in hidden:
        if width not in WIDTH:
            raise typer.BadParameter(f"{width} is not in {WIDTH}", param_hint="--hidden")
    train = trainer()
    settings = train.Settings(tuple(hidden), epochs, patience, seed=seed, history=history)
    record = train.train(recordings, role, out, settings, held_out)
    for line in record["excluded"]:
        console.print(f"excluded {line}")
    split, metrics = record["split"], record["metrics"]
    console.print(
        f"{len(record['recordings'])} recordings, {len(record['participants'])} participants: trained on "
        f"{', '.join(split['train'])} ({record['frames']['train']} frames), held out "
        f"{', '.join(split['held_out'])} ({record['frames']['held_out']} frames)"
    )
    console.print(
        f"held-out log-likelihood {metrics['held_out_loglik']:.3f} nats/frame at epoch "
        f"{metrics['best_epoch']} of {metrics['epochs']} (training {metrics['train_loglik']:.3f})"
    )
    console.print(f"written to {out}; play it as proxy:{out}")
