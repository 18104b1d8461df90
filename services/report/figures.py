"""The report's figures: matplotlib PNGs drawn from the analysis frames (services/report/analysis.py),
so that every number drawn is also in the report's data files."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from shared.plots import place_labels, save  # noqa: E402

DPI = 100


def _save(fig: plt.Figure, path: Path) -> Path:
    return save(fig, path, DPI)


def _roles_axes(roles: list, height: float = 4.5) -> tuple[plt.Figure, list[plt.Axes]]:
    fig, axes = plt.subplots(1, max(1, len(roles)), figsize=(5.5 * max(1, len(roles)), height), squeeze=False)
    return fig, list(axes[0])


def policy_space(points: pd.DataFrame, variance: pd.DataFrame, path: Path) -> Path:
    """Per role: library policies (crosses, labelled) and partners (discs, area growing with
    kills/min; each partner's name once, at the mean of its matches) on the first two principal
    components of their similarity vectors. Labels are placed where they meet no other text."""
    roles = list(variance["role"])
    fig, axes = _roles_axes(roles)
    for ax, role in zip(axes, roles, strict=False):
        mine = points[points["role"] == role]
        lib, partners = mine[mine["kind"] == "library"], mine[mine["kind"] == "partner"]
        ax.scatter(lib["pc1"], lib["pc2"], marker="x", color="black", label="library policy")
        sizes = 30 + 40 * partners["kills_per_minute"].clip(lower=0)
        ax.scatter(partners["pc1"], partners["pc2"], s=sizes, alpha=0.6, color="tab:orange", label="partner")
        share = variance[variance["role"] == role].iloc[0]
        ax.set_xlabel(f"PC1 ({100 * share['pc1']:.0f}% of variance)")
        ax.set_ylabel(f"PC2 ({100 * share['pc2']:.0f}% of variance)")
        ax.set_title(f"{role} partners in the {role} library's policy space", fontsize=10)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    if not roles:
        axes[0].text(0.5, 0.5, "no partners", ha="center", va="center")
    fig.tight_layout()  # the final layout first: labels are placed in its pixels
    for ax, role in zip(axes, roles, strict=False):
        mine = points[points["role"] == role]
        lib = mine[mine["kind"] == "library"]
        place_labels(ax, list(zip(lib["pc1"], lib["pc2"], strict=True)), list(lib["name"]), 8)
        centres, names = _clusters(mine[mine["kind"] == "partner"])
        place_labels(ax, centres, names, 7, "tab:brown")
    return _save(fig, path)


def _clusters(partners: pd.DataFrame, share: float = 0.05) -> tuple[list[tuple[float, float]], list[str]]:
    """Each partner's matches that lie within `share` of the plot's span of each other, as one point
    (their mean) and one label: a partner that played alike with every agent gets one label, one that
    played differently gets one per place."""
    span = max(np.ptp(partners["pc1"]), np.ptp(partners["pc2"]), 1e-9) if len(partners) else 1.0
    centres, names = [], []
    for name, group in partners.groupby("name", sort=True):
        clusters: list[list[np.ndarray]] = []
        for point in group[["pc1", "pc2"]].to_numpy():
            near = next(
                (c for c in clusters if np.linalg.norm(np.mean(c, axis=0) - point) < share * span), None
            )
            (near.append(point) if near is not None else clusters.append([point]))
        centres += [tuple(np.mean(c, axis=0)) for c in clusters]
        names += [str(name)] * len(clusters)
    return centres, names


def similarity(similarity: pd.DataFrame, correlations: pd.DataFrame, path: Path) -> Path:
    """Per group (kind of match, partner's seat) with pairs: similarity to the agent's optimal partner
    policy against team performance."""
    groups = list(correlations[correlations["n"] > 0].itertuples())
    fig, axes = _roles_axes(groups, 4.0)
    for ax, c in zip(axes, groups, strict=False):
        mine = similarity[(similarity["kind"] == c.kind) & (similarity["partner_role"] == c.partner_role)]
        ax.scatter(mine["similarity"], mine["kills_per_minute"], color="tab:blue")
        stat = f"r = {c.r:.2f}, p = {c.p:.3g}" if np.isfinite(c.r) else c.note
        ax.set_title(f"{c.kind}, {c.partner_role} partners:\n{stat} (n = {c.n})", fontsize=10)
        ax.set_xlabel("similarity to the optimal policy (mean log-prob)")
        ax.set_ylabel("team kills per minute")
    if not groups:
        axes[0].text(0.5, 0.5, "no pair whose agent played a library policy", ha="center", va="center")
    return _save(fig, path)


def curves(curves: pd.DataFrame, fps: float, path: Path) -> Path:
    """Moving mean of each library policy's log-probability of the partner's actions over one trial,
    rounds shaded alternately."""
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for policy, group in curves.groupby("policy", sort=False):
        ax.plot(group["frame"] / fps, group["smoothed"], label=policy, linewidth=1.2)
    first = curves[curves["policy"] == curves["policy"].iloc[0]] if len(curves) else curves
    for number, part in first.groupby("round"):
        if number % 2:
            ax.axvspan(part["frame"].min() / fps, part["frame"].max() / fps, color="grey", alpha=0.15, lw=0)
    match = curves["match"].iloc[0] if len(curves) else ""
    ax.set_title(
        f"log-probability of the partner's actions under each library policy: {match} (shade: rounds)"
    )
    ax.set_xlabel("game time (s)")
    ax.set_ylabel("log-prob, 1 s moving mean")
    ax.legend(fontsize=8, ncol=2, loc="lower left")
    return _save(fig, path)


def variants(summary: pd.DataFrame, tests: pd.DataFrame, path: Path) -> Path:
    """Per group (kind of match, partner's seat), one panel: team performance per agent variant as
    horizontal bars, mean with standard-error bars, adaptive variants in orange, each group's tests
    below its title. Groups are never drawn on one axis, as they are never compared."""
    groups = list(summary.groupby(["kind", "partner_role"], sort=True)) or [(("", ""), summary)]
    tested = tests.groupby(["kind", "partner_role"]).size() if len(tests) else pd.Series(dtype=int)
    heights = [1.6 + 0.45 * max(1, len(mine)) + 0.3 * tested.get(group, 0) for group, mine in groups]
    fig, axes = plt.subplots(len(groups), 1, figsize=(8, sum(heights)), squeeze=False,
                             gridspec_kw={"height_ratios": heights})  # fmt: skip
    for ax, ((kind, role), mine) in zip(axes[:, 0], groups, strict=True):
        if mine.empty:
            ax.text(0.5, 0.5, "no agent variants", ha="center", va="center")
            ax.set_axis_off()
            continue
        colours = ["tab:orange" if a else "tab:blue" for a in mine["adaptive"]]
        rows = range(len(mine))
        ax.barh(rows, mine["mean"], xerr=mine["stderr"].fillna(0), color=colours, capsize=4)
        ax.set_yticks(
            rows, [f"{v} (n={n})" for v, n in zip(mine["variant"], mine["n"], strict=True)], fontsize=8
        )
        ax.invert_yaxis()
        ax.set_xlabel("team kills per minute (mean ± s.e.)")
        mine_tests = tests[(tests["kind"] == kind) & (tests["partner_role"] == role)]
        lines = [
            f"{r.adaptive} vs {r.static}: {r.test}, p = {r.p:.3g}"
            if np.isfinite(r.p)
            else f"{r.adaptive}: {r.note}"
            for r in mine_tests.itertuples()
        ]
        title = "\n".join([f"{kind}, {role} partners", *(lines or ["no adaptive-vs-static test"])])
        ax.set_title(title, fontsize=9)
    return _save(fig, path)


def adapter(timeline: pd.DataFrame, path: Path, most: int = 6) -> Path:
    """For up to `most` adaptive matches: the estimated partner type and the agent's policy over time."""
    matches = list(dict.fromkeys(timeline["match"]))[:most]
    fig, axes = plt.subplots(len(matches), 1, figsize=(10, 2.6 * len(matches)), squeeze=False)
    for ax, match in zip(axes[:, 0], matches, strict=True):
        mine = timeline[timeline["match"] == match]
        labels = sorted(set(mine["partner"].replace("", "(filling)")) | set(mine["policy"]))
        level = {label: i for i, label in enumerate(labels)}
        seconds = [
            *mine["seconds"],
            mine["end"].iloc[0],
        ]  # a status holds until the next; the last to the end
        estimated = list(mine["partner"].replace("", "(filling)").map(level))
        policy = list(mine["policy"].map(level))
        ax.step(seconds, [*estimated, estimated[-1]], where="post", label="estimated partner type")
        ax.step(seconds, [*policy, policy[-1]], where="post", label="agent's policy", linestyle="--")
        ax.set_yticks(range(len(labels)), labels)
        ax.set_title(f"{match}: {mine['strategy'].iloc[0]}, window {mine['window'].iloc[0]}", fontsize=10)
        ax.set_xlabel("game time (s)")
        ax.legend(fontsize=8, loc="upper right")
    return _save(fig, path)
