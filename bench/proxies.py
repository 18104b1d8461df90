"""Do proxies work? Measured without real people (docs/proxies.md, "Figures").

For each source (a human-like hand on a known library bait, `human(Bk)`), stand-in participants
play one-minute trials with the shooter S5; their recordings are written in-process as the
recorder writes them (services/proxy/synthetic.py; docs/proxies.md says why not through the
gateway); a proxy is trained on them (`tsf proxy train`'s core, split by participant). Then:

(a) held-out log-likelihood per frame of the held-out participant's actions under the proxy and
    under the generating library policy Bk (goal: the proxy within 0.1 nats of Bk, or above it);
(b) CEM identification: the library bait with the highest mean log-probability of the proxy's own
    actions over games with S5, and the share of 400-frame windows identified as Bk (the same for
    the generator human(Bk), for reference);
(c) team performance: kills per minute of the proxy and of human(Bk) with each of S4-S7, mean and
    standard error over seeded games (the batched evaluation of services/evaluation/evaluate.py).

    .venv/bin/python bench/proxies.py [--sources B1 B5 B8] [--participants 3] [--trials 3]
        [--games 8] [--history 0] [--out bench-proxies]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from pathlib import Path

import numpy as np

from services.adapter.cem import log_probs, rollout
from services.agent import library, networks, seats
from services.evaluation.evaluate import play_games
from services.evaluation.identification import windowed
from services.population.partners import make_partner
from services.population.seat import seats_of
from services.proxy.data import extract
from services.proxy.synthetic import record_trial, trial_seed
from services.proxy.train import Settings, train

AGENT = "S5"  # the shooter the stand-ins play with
SHOOTERS = ("S4", "S5", "S6", "S7")
WINDOW = 400


def record(out: Path, source: str, participants: int, trials: int, base: int) -> list[Path]:
    paths = []
    for p in range(participants):
        for t in range(trials):
            seed = trial_seed(base, p, t) if trials <= 3 else base + trials * p + t
            path = out / f"{source}-p{p}-t{t}.tsflog"
            if not path.with_name(f"{path.stem}.study.json").exists():  # kept from an earlier run
                record_trial(path, f"human({source})", "bait", AGENT, seed, f"{source}-p{p}")
            paths.append(path)
    return paths


def held_out_loglik(paths: list[Path], proxy_dir: Path, source: str) -> tuple[float, float, int]:
    """Mean log-likelihood per frame of the held-out participants' actions: proxy, generator, frames."""
    record = json.loads((proxy_dir / "manifest.json").read_text())
    data = extract(paths, "bait")
    rows = data.rows(record["split"]["held_out"])
    proxy = seats.policy_for(f"proxy:{proxy_dir}", "bait")
    actions = data.actions[rows]
    ours = np.log(proxy.probs_given(data.obs[rows], data.previous[rows])[np.arange(len(rows)), actions])
    theirs = log_probs([networks.load(source)], data.obs[rows].astype(np.float64), actions)[:, 0]
    return float(ours.mean()), float(theirs.mean()), len(rows)


def identify(partner_name: str, source: str, games: int) -> tuple[str, float]:
    """The library bait the CEM finds most like the partner over `games` games with S5, and the
    share of WINDOW-frame windows whose best score is `source`."""
    baits = library.keys("bait")
    policies = [networks.load(k) for k in baits]
    means, hits, windows = np.zeros(len(baits)), 0, 0
    for seed in range(games):
        states, actions = rollout(make_partner(partner_name, "bait"), networks.load(AGENT), 1000 + seed)
        scores = log_probs(policies, states, actions)
        means += scores.mean(axis=0) / games
        best = windowed(scores, WINDOW).argmax(axis=1)
        hits, windows = hits + int((best == baits.index(source)).sum()), windows + len(best)
    return baits[int(means.argmax())], hits / max(windows, 1)


def team(partner_name: str, games: int) -> dict[str, tuple[float, float]]:
    """Kills per minute (mean, standard error) of the partner with each shooter of SHOOTERS."""
    plan = [(partner_name, shooter, 2000 + seed) for shooter in SHOOTERS for seed in range(games)]
    outcomes = play_games([(*seats_of(names), seed) for *names, seed in plan], "shooter")
    out = {}
    for i, shooter in enumerate(SHOOTERS):
        values = [o.kills_per_minute for o in outcomes[i * games : (i + 1) * games]]
        out[shooter] = (statistics.fmean(values), statistics.stdev(values) / math.sqrt(len(values)))
    return out


def table(results: dict) -> list[str]:
    """The figures of one run as Markdown rows (docs/proxies.md): per source, (a), (b) and (c), with
    each shooter's difference proxy - generator in standard errors of the difference."""
    lines = [
        "| source | (a) proxy | (a) Bk | (a) difference | (b) proxy identified as (windows as Bk) | "
        "(b) generator identified as (windows as Bk) | (c) proxy - generator, kills/min (z) |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for source, r in results.items():
        cells = [
            source,
            f"{r['proxy_ll']:.3f}",
            f"{r['source_ll']:.3f}",
            f"{r['proxy_ll'] - r['source_ll']:+.3f}",
        ]
        for label in ("proxy", "generator"):
            found = r.get(f"{label}_identified")
            cells.append(f"{found} ({r[f'{label}_window_share']:.0%})" if found else "-")
        if "proxy_team" in r:
            diffs = []
            for shooter, (mean, se) in r["proxy_team"].items():
                other_mean, other_se = r["generator_team"][shooter]
                z = (mean - other_mean) / math.hypot(se, other_se) if se or other_se else 0.0
                diffs.append(f"{shooter} {mean - other_mean:+.2f} ({z:+.1f})")
            cells.append(", ".join(diffs))
        else:
            cells.append("-")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def curve(paths: list[Path]) -> list[str]:
    """The data-size curve from results files of several --trials: per source and size, (a), (b)
    and how many of the shooters' differences in (c) are within two standard errors."""
    lines = [
        "| source | trials per participant | (a) proxy | (a) proxy - Bk | (b) proxy identified as "
        "(windows as Bk) | (c) shooters within 2 s.e. |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    runs = {int(path.stem.split("-")[1]): json.loads(path.read_text()) for path in paths}
    for source in next(iter(runs.values())):
        for trials, results in sorted(runs.items()):
            r = results[source]
            within = sum(
                abs(m - r["generator_team"][s][0]) <= 2 * math.hypot(e, r["generator_team"][s][1])
                for s, (m, e) in r["proxy_team"].items()
            )
            lines.append(
                f"| {source} | {trials} | {r['proxy_ll']:.3f} | {r['proxy_ll'] - r['source_ll']:+.3f} | "
                f"{r['proxy_identified']} ({r['proxy_window_share']:.0%}) | {within} of {len(SHOOTERS)} |"
            )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sources", nargs="+", default=["B1", "B5", "B8"])
    parser.add_argument("--participants", type=int, default=3)
    parser.add_argument("--trials", type=int, default=3, help="one-minute trials per participant")
    parser.add_argument("--games", type=int, default=8, help="games per measurement of (b) and (c)")
    parser.add_argument("--out", type=Path, default=Path("bench-proxies"))
    parser.add_argument("--skip", nargs="*", default=[], choices=["identify", "team"])
    parser.add_argument("--history", type=int, default=0, help="the proxies' own last actions read")
    parser.add_argument("--table", nargs="*", type=Path, help="print earlier runs' results files as Markdown")
    parser.add_argument(
        "--curve", nargs="*", type=Path, help="print results files of several --trials as a curve"
    )
    args = parser.parse_args()
    if args.curve:
        print(*curve(args.curve), sep="\n")
        return
    if args.table:
        for path in args.table:
            print(f"{path.name}:", *table(json.loads(path.read_text())), sep="\n")
        return
    results = {}
    for i, source in enumerate(args.sources):
        started = time.monotonic()
        paths = record(
            args.out / "recordings" / f"{source}-{args.trials}",
            source,
            args.participants,
            args.trials,
            50 * i,
        )
        recorded = time.monotonic() - started
        proxy_dir = args.out / f"proxy-{source}-{args.trials}-h{args.history}"
        held = max(1, round(args.participants / 3)) / args.participants
        train(paths, "bait", proxy_dir, Settings(history=args.history), held)
        proxy_ll, source_ll, frames = held_out_loglik(paths, proxy_dir, source)
        row = {"proxy_ll": proxy_ll, "source_ll": source_ll, "held_out_frames": frames}
        print(
            f"{source}: recorded {len(paths)} trials in {recorded:.0f} s; held-out log-likelihood per frame "
            f"proxy {proxy_ll:.3f}, {source} {source_ll:.3f} (difference {proxy_ll - source_ll:+.3f}) "
            f"over {frames} frames",
            flush=True,
        )
        for name, label in ((f"proxy:{proxy_dir}", "proxy"), (f"human({source})", "generator")):
            if "identify" not in args.skip:
                found, share = identify(name, source, args.games)
                row[f"{label}_identified"], row[f"{label}_window_share"] = found, share
                print(
                    f"  CEM: {label} identified as {found}; {share:.0%} of {WINDOW}-frame windows as {source}"
                )
            if "team" not in args.skip:
                row[f"{label}_team"] = team(name, args.games)
                cells = ", ".join(f"{s} {m:.2f} ± {e:.2f}" for s, (m, e) in row[f"{label}_team"].items())
                print(f"  team ({label}): {cells} kills/min", flush=True)
        results[source] = row
    path = args.out / f"results-{args.trials}-h{args.history}.json"
    path.write_text(json.dumps(results, indent=1) + "\n")
    print(*table(results), f"written to {path}", sep="\n")


if __name__ == "__main__":
    main()
