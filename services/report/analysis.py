"""The study's analyses over loaded recordings: pure functions from pandas frames to pandas frames.

Who is the partner in a recording (`seats`):
- the participant's seat, where the study sidecar names it (`role`); else
- an adaptive match: the partner is the seat the adapter watches, the other one from its statuses'
  `role` (or, with no statuses, from the seat the start record names `adaptive-...`);
- a human match (the start names no policy for a seat: "", or the launcher's "human"): the
  person's seat;
- an agent-agent match: each seat is the partner of the other, so the match gives two rows (or
  one, where the report is told the partner's role).

The partner's label is the sidecar's `participant`, else its policy key, else "person". The agent's
variant is the sidecar's `variant`, else the agent's policy key (a static agent), else
`adaptive-T<window>-<strategy>` from the adapter statuses.

Each pairing has a kind of match (`kind_of`): a study trial (the recording has a study sidecar), a
person's match outside a study, or agents only. Variants are summarised, and adaptive ones tested,
within one kind and one partner seat at a time (a group): a study's participants and agent stand-ins,
or bait partners and shooter partners, are different populations, never pooled in one comparison.

A partner's similarity to a library policy is the mean log-probability that policy gives the
partner's actions in the states the partner answered (the CEM of services/adapter/cem.py): each
recorded action of the partner's seat with the state named by its frame, one per frame (the last
received).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from services.adapter import cem
from services.agent import library, networks
from services.population.adaptive import AdapterConfig
from services.population.seat import AdaptiveSeat, SeatSpec
from services.report.load import Match
from services.table.table import Table
from shared.game import FPS, PERSON, ROLES, GameConfig, Policy, other

ROUND_ENDS = ("kill", "reset")  # the events that end a round (docs/rules.md)
SMOOTH = FPS  # frames in the log-probability curves' moving mean (one second)
KINDS = ("study trial", "person", "agents only")  # the kinds of match, never compared with each other
GROUP = ["kind", "partner_role"]  # one population: a kind of match and the partner's seat


@dataclass(frozen=True)
class Partnership:
    """One partner-agent pairing in one match."""

    match: str
    kind: str  # one of KINDS
    partner_role: str
    partner: str
    agent: str  # the key the agent seat played most (a library key, for the table)
    variant: str
    adaptive: bool
    kills_per_minute: float


def adaptive_seat(match: Match) -> str | None:
    """The adaptive agent's seat: the adapter statuses' `role`, else the seat the start record names
    by the adapter's name (the launcher records an adaptive seat as adaptive-T<window>-<strategy>)."""
    adapter = match.tables["adapter"]
    if not adapter.empty:
        return str(adapter["role"].iloc[0])
    named = {r: match.policies[r] for r in ROLES if match.policies[r]}  # a person's seat may name nothing
    return next((r for r, name in named.items() if isinstance(SeatSpec.parse(name), AdaptiveSeat)), None)


def person_seats(match: Match) -> list[str]:
    """Seats a person played: the start record names no policy for them ("", or the launcher's "human")."""
    return [r for r in ROLES if match.policies[r] in PERSON]


def kind_of(match: Match) -> str:
    """A study trial (a study sidecar names its participant or seat), a person's match outside a
    study, or agents only."""
    if match.meta.get("participant") or match.meta.get("role"):
        return KINDS[0]
    return KINDS[1] if person_seats(match) else KINDS[2]


def seats(match: Match, partner_role: str | None = None) -> list[Partnership]:
    """The partner-agent pairings of a match (the rule is in the module docstring)."""
    policies, adapter, adaptive = match.policies, match.tables["adapter"], adaptive_seat(match)
    if match.meta.get("role") in ROLES:
        roles = [match.meta["role"]]
    else:
        roles = [other(adaptive)] if adaptive else person_seats(match) or list(ROLES)
    out = []
    for role in roles:
        if partner_role not in (None, role):
            continue
        agent_role = other(role)
        if agent_role == adaptive and not adapter.empty:
            window, strategy = int(adapter["window"].iloc[0]), str(adapter["strategy"].iloc[0])
            variant = AdapterConfig(agent_role, window, strategy).name
        else:
            variant = "person" if policies[agent_role] in PERSON else policies[agent_role]
        partner = "person" if policies[role] in PERSON else policies[role]
        out.append(
            Partnership(
                match.name,
                kind_of(match),
                role,
                match.meta.get("participant") or partner,
                most_played(match, agent_role),
                match.meta.get("variant") or variant,
                agent_role == adaptive,
                match.kills_per_minute,
            )
        )
    return out


def most_played(match: Match, role: str) -> str:
    """The policy key behind most of a seat's actions ("" for a person)."""
    played = match.tables["actions"].query("role == @role")["policy"]
    return str(played.mode().iloc[0]) if not played.empty else match.policies[role]


def partner_stream(match: Match, role: str) -> pd.DataFrame:
    """The partner's (frame, world-view observation, action) pairs, one per answered frame."""
    actions = match.tables["actions"].query("role == @role").drop_duplicates("frame", keep="last")
    states = match.tables["states"][["frame", f"{role}_obs"]].rename(columns={f"{role}_obs": "obs"})
    return actions[["frame", "action"]].merge(states, on="frame").sort_values("frame", ignore_index=True)


def log_probs(stream: pd.DataFrame, policies: list[Policy]) -> np.ndarray:
    """(frames, policies): log pi(a_t | s_t) of each policy for each pair of a partner's stream."""
    return cem.log_probs(policies, [list(o) for o in stream["obs"]], stream["action"].to_numpy())


def library_policies(role: str, config: GameConfig) -> dict[str, Policy]:
    return {key: networks.load(key, config) for key in library.keys(role)}


def partner_vectors(matches: list[Match], partner_role: str | None = None) -> pd.DataFrame:
    """One row per seat: who played, team performance, and the mean log-probability of the
    partner's actions under each library policy of the partner's role (columns named by key)."""
    rows = []
    loaded: dict[tuple[str, str], dict[str, Policy]] = {}
    for match in matches:
        for seat in seats(match, partner_role):
            config = match.config
            cache_key = (seat.partner_role, config.hash())
            if cache_key not in loaded:
                loaded[cache_key] = library_policies(seat.partner_role, config)
            policies = loaded[cache_key]
            stream = partner_stream(match, seat.partner_role)
            means = log_probs(stream, list(policies.values())).mean(axis=0) if len(stream) else []
            rows.append({**seat.__dict__, "frames": len(stream), **dict(zip(policies, means, strict=False))})
    return pd.DataFrame(rows, columns=[*Partnership.__dataclass_fields__, "frames", *library.keys()])


def reference_partner(table: Table, role: str) -> str:
    """The library policy of the other role that plays best with the `role` policies on average."""
    if role == "bait":
        return max(table.shooters, key=lambda s: sum(table.mean(b, s) for b in table.baits))
    return max(table.baits, key=lambda b: sum(table.mean(b, s) for s in table.shooters))


def reference_vectors(role: str, table: Table, games: int, config: GameConfig) -> pd.DataFrame:
    """The library policies of `role` as reference points: row i is the mean log-probability under
    each policy of policy i's own actions over `games` games with the reference partner (the CEM
    matrix of docs/library.md)."""
    policies = library_policies(role, config)
    partner = networks.load(reference_partner(table, role), config)
    matrix = cem.cem_matrix(list(policies.values()), partner, list(range(games)), config)
    return pd.DataFrame(matrix, index=list(policies), columns=list(policies))


def pca2(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows' coordinates on the first two principal components, and the share of variance each
    explains. Signs are fixed so that each component's largest loading is positive."""
    centred = matrix - matrix.mean(axis=0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    vt = vt[:2]
    vt = vt * np.sign(vt[np.arange(len(vt)), np.abs(vt).argmax(axis=1)])[:, None]
    total = float((s**2).sum())
    explained = (s[:2] ** 2) / total if total > 0 else np.zeros(min(2, len(s)))
    coords = centred @ vt.T
    pad = 2 - coords.shape[1]  # fewer rows or columns than two components: the rest is zero
    return np.pad(coords, ((0, 0), (0, pad))), np.pad(explained, (0, pad))


def policy_space(
    partners: pd.DataFrame, references: dict[str, pd.DataFrame]
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per role, the partners' and the library policies' similarity vectors projected together on
    two principal components; the points, and the variance the components explain."""
    points, variance = [], []
    for role, reference in references.items():
        keys = list(reference.columns)
        mine = partners[partners["partner_role"] == role]
        matrix = np.vstack([reference.to_numpy(), mine[keys].to_numpy()])
        coords, explained = pca2(matrix)
        labels = [("library", key, "", math.nan) for key in reference.index] + [
            ("partner", row.partner, row.match, row.kills_per_minute) for row in mine.itertuples()
        ]
        for (kind, name, match, kpm), (pc1, pc2) in zip(labels, coords, strict=True):
            points.append({"role": role, "kind": kind, "name": name, "match": match,
                           "kills_per_minute": kpm, "pc1": pc1, "pc2": pc2})  # fmt: skip
        variance.append({"role": role, "pc1": explained[0], "pc2": explained[1], "points": len(matrix)})
    point_columns = ["role", "kind", "name", "match", "kills_per_minute", "pc1", "pc2"]
    variance_columns = ["role", "pc1", "pc2", "points"]
    return pd.DataFrame(points, columns=point_columns), pd.DataFrame(variance, columns=variance_columns)


def similarity_to_optimal(partners: pd.DataFrame, table: Table) -> pd.DataFrame:
    """Each seat whose agent played a library policy: the partner's similarity to the policy of its
    role that the table says plays best with that agent."""
    rows = []
    for _, row in partners.iterrows():
        agent, role = row["agent"], row["partner_role"]
        if role == "bait" and agent in table.shooters:
            optimal = table.best_bait(agent)
        elif role == "shooter" and agent in table.baits:
            optimal = table.best_shooter(agent)
        else:
            continue
        rows.append(
            {"match": row["match"], "kind": row["kind"], "partner_role": role, "partner": row["partner"],
             "agent": agent, "optimal": optimal, "similarity": row[optimal],
             "kills_per_minute": row["kills_per_minute"]}
        )  # fmt: skip
    columns = ["match", *GROUP, "partner", "agent", "optimal", "similarity", "kills_per_minute"]
    return pd.DataFrame(rows, columns=columns)


def correlations(similarity: pd.DataFrame) -> pd.DataFrame:
    """Pearson r and its two-sided p between similarity to optimal and team performance, per group
    (kind of match, partner's seat). r and p are left empty (NaN), with the reason, with fewer than
    three seats or a constant column."""
    rows = []
    for (kind, role), mine in similarity.groupby(GROUP, sort=True):
        x, y = mine["similarity"].to_numpy(float), mine["kills_per_minute"].to_numpy(float)
        refusal = "fewer than 3 seats" if len(mine) < 3 else "a constant column" if _constant(x, y) else ""
        r, p, note = _test(stats.pearsonr, refusal, x, y)
        rows.append({"kind": kind, "partner_role": role, "n": len(mine), "r": r, "p": p, "note": note})
    return pd.DataFrame(rows, columns=[*GROUP, "n", "r", "p", "note"])


def _constant(*samples: np.ndarray) -> bool:
    return any(np.ptp(x) == 0 for x in samples)


def _test(test: Callable, refusal: str, *samples: np.ndarray) -> tuple[float, float, str]:
    """A scipy test's statistic and p-value, or NaNs and the reason it was not run."""
    if refusal:
        return math.nan, math.nan, refusal
    result = test(*samples)
    return float(result.statistic), float(result.pvalue), ""


def rounds(match: Match, frames: np.ndarray) -> np.ndarray:
    """The round (0, 1, ...) each frame belongs to: a round ends at a kill or a both-dead reset."""
    events = match.tables["events"]
    ends = np.sort(events[events["kind"].isin(ROUND_ENDS)]["frame"].to_numpy())
    return np.searchsorted(ends, frames, side="left")


def curves(match: Match, seat: Partnership, smooth: int = SMOOTH) -> pd.DataFrame:
    """Over one trial: the log-probability of the partner's every action under each library policy
    of its role, its moving mean over `smooth` frames, and the round of the frame."""
    policies = library_policies(seat.partner_role, match.config)
    stream = partner_stream(match, seat.partner_role)
    values = log_probs(stream, list(policies.values()))
    frames = stream["frame"].to_numpy()
    round_of = rounds(match, frames)
    parts = []
    for j, key in enumerate(policies):
        series = pd.Series(values[:, j])
        parts.append(
            pd.DataFrame(
                {
                    "match": match.name,
                    "partner_role": seat.partner_role,
                    "policy": key,
                    "frame": frames,
                    "round": round_of,
                    "log_prob": values[:, j],
                    "smoothed": series.rolling(smooth, min_periods=1).mean().to_numpy(),
                }
            )  # fmt: skip
        )
    return pd.concat(parts, ignore_index=True)


def round_means(curves: pd.DataFrame) -> pd.DataFrame:
    """Each policy's mean log-probability of the partner's actions in each round of the trial."""
    if curves.empty:
        return pd.DataFrame(columns=["policy", "round", "frames", "log_prob"])
    grouped = curves.groupby(["policy", "round"], sort=False)["log_prob"]
    return grouped.agg(frames="size", log_prob="mean").reset_index()


def variants(partners: pd.DataFrame) -> pd.DataFrame:
    """Team performance per agent variant within each group (kind of match, partner's seat):
    matches, mean and standard error of kills per minute."""
    columns = [*GROUP, "variant", "adaptive", "n", "mean", "stderr"]
    rows = []
    for (kind, role, variant, adaptive), group in partners.groupby(
        [*GROUP, "variant", "adaptive"], sort=True
    ):
        values = group["kills_per_minute"].to_numpy(float)
        stderr = values.std(ddof=1) / math.sqrt(len(values)) if len(values) > 1 else math.nan
        values_row = (kind, role, variant, bool(adaptive), len(values), values.mean(), stderr)
        rows.append(dict(zip(columns, values_row, strict=True)))
    return pd.DataFrame(rows, columns=columns)


TEST_COLUMNS = [*GROUP, "adaptive", "static", "test", "n_adaptive", "n_static", "mean_adaptive",
                "mean_static", "t", "p", "note"]  # fmt: skip


def adaptive_tests(partners: pd.DataFrame, summary: pd.DataFrame) -> pd.DataFrame:
    """Within each group, each adaptive variant against the group's best static one (the highest mean
    among static variants with two or more matches), two-sided.

    Where every partner played both variants (a within-partner design, as in the study, and as in
    agent-only sweeps over partners), a paired t-test on each partner's mean: it removes the large
    differences between partners from the comparison. Otherwise Welch's unequal-variance t-test
    over matches: the groups are then different partners, of unequal sizes, with no reason to
    share a variance. The `test` column says which was run; a group with no static variant to
    compare with gets no test, and `left_out` says so."""
    rows = []
    for (kind, role), mine in summary.groupby(GROUP, sort=True):
        static = mine[(~mine["adaptive"]) & (mine["n"] >= 2)]
        if static.empty:
            continue
        best = static.sort_values(["mean", "variant"], ascending=[False, True]).iloc[0]["variant"]
        pairs = partners[(partners["kind"] == kind) & (partners["partner_role"] == role)]
        for variant in mine[mine["adaptive"]]["variant"]:
            test = _test_variant(pairs[pairs["variant"] == variant], pairs[pairs["variant"] == best])
            rows.append(dict(zip(TEST_COLUMNS, (kind, role, variant, best, *test), strict=True)))
    return pd.DataFrame(rows, columns=TEST_COLUMNS)


def _test_variant(a: pd.DataFrame, b: pd.DataFrame) -> tuple:
    """The test of one adaptive variant's pairings `a` against the best static one's `b`."""
    x, y = a["kills_per_minute"].to_numpy(float), b["kills_per_minute"].to_numpy(float)
    per_a = a.groupby("partner")["kills_per_minute"].mean()
    per_b = b.groupby("partner")["kills_per_minute"].mean()
    if len(per_a) >= 2 and set(per_a.index) == set(per_b.index):
        test, x, y = "paired t (partner means)", per_a.sort_index().to_numpy(), per_b.sort_index().to_numpy()
        refusal = "no variance in the differences" if _constant(x - y) else ""
        t, p, note = _test(stats.ttest_rel, refusal, x, y)
    else:
        test = "Welch t"
        refusal = (
            "fewer than 2 adaptive matches" if len(x) < 2
            else "no variance in either group" if _constant(x) and _constant(y)
            else ""
        )  # fmt: skip
        t, p, note = _test(functools.partial(stats.ttest_ind, equal_var=False), refusal, x, y)
    return test, len(x), len(y), x.mean(), y.mean(), t, p, note


def left_out(summary: pd.DataFrame, tests: pd.DataFrame) -> pd.DataFrame:
    """What the adaptive-vs-static tests did not compare, and why: every group without a test (no
    adaptive variant, or no static variant with two or more matches), and every static variant too
    rare to be a group's best static one. Groups are never compared with each other."""
    rows = []
    tested = set(zip(tests["kind"], tests["partner_role"], strict=True))
    for (kind, role), mine in summary.groupby(GROUP, sort=True):
        matches = int(mine["n"].sum())
        if (kind, role) not in tested:
            adaptive = mine[mine["adaptive"]]
            reason = (
                "no adaptive variant to test"
                if adaptive.empty
                else "no static variant with 2 or more matches to test the adaptive ones against"
            )
            rows.append({"kind": kind, "partner_role": role, "variant": "", "n": matches, "reason": reason})
            continue
        for row in mine[(~mine["adaptive"]) & (mine["n"] < 2)].itertuples():
            reason = "fewer than 2 matches: not a candidate for the best static variant"
            rows.append(
                {"kind": kind, "partner_role": role, "variant": row.variant, "n": row.n, "reason": reason}
            )
    return pd.DataFrame(rows, columns=[*GROUP, "variant", "n", "reason"])


def left_out_lines(left: pd.DataFrame) -> list[str]:
    """`left_out` as sentences, for the console and the report's page."""
    return [
        f"{r.kind}, {r.partner_role} partners"
        + (f", {r.variant}" if r.variant else "")
        + f" ({r.n} pairings): {r.reason}"
        for r in left.itertuples()
    ]


def adapter_timeline(matches: list[Match]) -> pd.DataFrame:
    """Every adapter status of the adaptive matches: the estimated partner type and the agent's
    policy over time (seconds of game time; `end`: the match's length in seconds)."""
    parts = []
    for match in matches:
        adapter = match.tables["adapter"]
        if adapter.empty:
            continue
        part = adapter[
            ["frame", "role", "partner", "policy", "strategy", "window", "filled", "out_of_library"]
        ]
        config = match.config
        parts.append(
            part.assign(match=match.name, seconds=part["frame"] / config.fps, end=config.frames / config.fps)
        )
    columns = ["match", "frame", "seconds", "role", "partner", "policy", "strategy", "window", "filled",
               "out_of_library", "end"]  # fmt: skip
    return pd.concat(parts, ignore_index=True)[columns] if parts else pd.DataFrame(columns=columns)
