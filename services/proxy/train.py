"""Behaviour cloning of a person's seat (torch: the `train` extra).

The network maps the world-view observation (docs/observation.md) through tanh hidden layers to
the logits of the three heads (turn, thrust, fire); the loss is the negative log-likelihood of the
recorded actions under the floored factored distribution that ProxyPolicy plays (services/agent/proxy.py), so
the exported numpy policy is the trained one exactly. Training stops when the held-out
participants' log-likelihood has not improved for `patience` epochs, and the best epoch is kept.
"""

from __future__ import annotations

import csv
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch as th

from services.agent import library
from services.agent.networks import FLOOR, HEAD_SIZES, HEADS, inputs
from services.agent.proxy import save
from services.proxy.data import HISTORY, Dataset, Split, extract, split
from shared.game import N_ACTIONS, N_FIRE, N_THRUST, OBS_SIZE
from shared.provenance import provenance

SIZES = [HEAD_SIZES[h] for h in HEADS]
CURVE = ("epoch", "train_loglik", "held_out_loglik")


@dataclass
class Settings:
    hidden: tuple[int, ...] = (64, 64)
    epochs: int = 200  # at most
    patience: int = 10  # epochs without a better held-out log-likelihood before stopping
    batch: int = 256
    lr: float = 1e-3
    seed: int = 0
    history: int = 0  # the proxy's own last actions it reads (services/agent/proxy.py)


@dataclass
class Fitted:
    arrays: dict[str, np.ndarray]
    curve: list[tuple[int, float, float]] = field(default_factory=list)  # CURVE rows
    best_epoch: int = 0

    @property
    def best(self) -> tuple[int, float, float]:
        return next(row for row in self.curve if row[0] == self.best_epoch)


def network(hidden: tuple[int, ...], history: int = 0) -> th.nn.Sequential:
    inputs = OBS_SIZE + N_ACTIONS * history
    layers: list[th.nn.Module] = []
    for width in hidden:
        layers += [th.nn.Linear(inputs, width), th.nn.Tanh()]
        inputs = width
    return th.nn.Sequential(*layers, th.nn.Linear(inputs, sum(SIZES)))


def head_log_probs(logits: th.Tensor) -> list[th.Tensor]:
    """Each head's log-distribution: softmax with FLOOR mixed in (policy.head_probs, in torch)."""
    return [
        th.log((1.0 - FLOOR) * th.softmax(part, dim=-1) + FLOOR / part.shape[-1])
        for part in th.split(logits, SIZES, dim=-1)
    ]


def log_likelihood(model: th.nn.Module, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """Per-row log-probability of the actions (shared.game.join_action's layout: turn major)."""
    turn = actions // (N_THRUST * N_FIRE)
    thrust = (actions // N_FIRE) % N_THRUST
    fire = actions % N_FIRE
    heads = head_log_probs(model(obs))
    return sum(h.gather(1, c[:, None])[:, 0] for h, c in zip(heads, (turn, thrust, fire), strict=True))


def fit(data: Dataset, split: Split, settings: Settings | None = None) -> Fitted:
    """Train on the split's training participants, stopping early on the held-out ones."""
    s = settings or Settings()
    th.manual_seed(s.seed)
    generator = th.Generator().manual_seed(s.seed)
    if not 0 <= s.history <= HISTORY:
        raise ValueError(f"history must be 0 to {HISTORY}, got {s.history}")
    model = network(s.hidden, s.history)
    optimiser = th.optim.Adam(model.parameters(), lr=s.lr)
    sets = {}
    for name, people in (("train", split.train), ("held_out", split.held_out)):
        rows = data.rows(people)
        x = inputs(data.obs[rows], data.previous[rows], s.history).astype(np.float32)
        sets[name] = (th.as_tensor(x), th.as_tensor(data.actions[rows]))
    fitted, best, waited = Fitted({}), -math.inf, 0
    for epoch in range(1, s.epochs + 1):
        obs, actions = sets["train"]
        model.train()
        for batch in th.randperm(len(actions), generator=generator).split(s.batch):
            optimiser.zero_grad()
            loss = -log_likelihood(model, obs[batch], actions[batch]).mean()
            loss.backward()
            optimiser.step()
        model.eval()
        with th.no_grad():
            train_ll, held_ll = (float(log_likelihood(model, *sets[n]).mean()) for n in ("train", "held_out"))
        fitted.curve.append((epoch, train_ll, held_ll))
        if held_ll > best:
            best, waited, fitted.best_epoch = held_ll, 0, epoch
            fitted.arrays = arrays(model)
        else:
            waited += 1
            if waited >= s.patience:
                break
    return fitted


def arrays(model: th.nn.Sequential) -> dict[str, np.ndarray]:
    """The linear layers as networks.Network arrays w0, b0, ... (float32)."""
    linear = [m for m in model if isinstance(m, th.nn.Linear)]
    out = {}
    for i, m in enumerate(linear):
        out[f"w{i}"] = m.weight.detach().cpu().numpy().astype(np.float32).copy()
        out[f"b{i}"] = m.bias.detach().cpu().numpy().astype(np.float32).copy()
    return out


def write_curve(fitted: Fitted, directory: Path) -> tuple[Path, Path]:
    """The learning curve as curve.csv and curve.png (mean log-likelihood per frame by epoch)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    csv_path, png = directory / "curve.csv", directory / "curve.png"
    with open(csv_path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(CURVE)
        writer.writerows((e, f"{t:.5f}", f"{h:.5f}") for e, t, h in fitted.curve)
    epochs = [row[0] for row in fitted.curve]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(epochs, [row[1] for row in fitted.curve], label="training participants")
    ax.plot(epochs, [row[2] for row in fitted.curve], label="held-out participants")
    ax.axvline(fitted.best_epoch, color="grey", linestyle=":", label=f"kept: epoch {fitted.best_epoch}")
    ax.set_xlabel("epoch")
    ax.set_ylabel("log-likelihood per frame (nats)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    plt.close(fig)
    return csv_path, png


def train(
    paths: list[Path],
    role: str,
    out: Path,
    settings: Settings | None = None,
    held_out: float = 0.25,
    by: str = "participant",
) -> dict:
    """`tsf proxy train`: extract, split by participant (or, `by` "recording", by recording: one
    person's proxy), fit, and write the proxy into `out` (proxy.npz, manifest.json, curve.csv,
    curve.png). Returns the manifest."""
    s = settings or Settings()
    data = extract(paths, role, by)
    parts = split(data, held_out, s.seed)
    fitted = fit(data, parts, s)
    epoch, train_ll, held_ll = fitted.best
    record = {
        "role": role,
        "view": "world",
        "recordings": [asdict(source) for source in data.sources],
        "excluded": data.excluded,
        "participants": data.participants,
        "split": {"train": parts.train, "held_out": parts.held_out, "by": by},
        "frames": {"train": len(data.rows(parts.train)), "held_out": len(data.rows(parts.held_out))},
        "metrics": {
            "held_out_loglik": held_ll,
            "train_loglik": train_ll,
            "best_epoch": epoch,
            "epochs": len(fitted.curve),
        },
        "settings": asdict(s),
        "provenance": provenance(**library.provenance_hashes()),
    }
    record["command"] = record["provenance"]["command"]
    meta = {
        "activation": "tanh",
        "role": role,
        "view": "world",
        "history": s.history,
        "heads": dict(zip(HEADS, SIZES, strict=True)),
    }
    record = save(out, fitted.arrays, meta, record)
    write_curve(fitted, Path(out))
    return record
