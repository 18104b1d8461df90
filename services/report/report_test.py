"""The report on short matches recorded in-process through the real log writer: agent-agent, adaptive
and a person's seat, plus a truncated and a garbage file. Every number checked here is recomputed
directly from the recordings (services/recorder/recording.load), not from the report's Parquet path."""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import statistics
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from scipy import stats

from services.adapter.cem import log_probs
from services.agent import library, networks
from services.recorder.recording import Recording, load
from services.recorder.recording_test import Script, record_match
from services.report import figures
from services.report.analysis import adaptive_tests, left_out, left_out_lines, seats, variants
from services.report.load import Match, load_matches
from services.report.report import Report, build_report
from services.table.plot import heatmap
from services.table.table import Table
from shared.game import GameConfig
from shared.messages import AdapterStatus, PolicySwitch
from shared.plots import legibility, save
from shared.provenance import FIELDS

FRAMES = 450  # 15 s: long enough for the weak pairs to score less than the strong ones
STATIC = [("B5", "S5"), ("B9", "S5"), ("B2", "S4"), ("B3", "S6"), ("B4", "S7"), ("B8", "S1")]
ADAPTIVE = [("B5", 10), ("B9", 11), ("B4", 12)]  # partner bait, seed; the shooter adapts (window 100)
WINDOW = 100


def adaptive_script(name: str, partner: str, seed: int) -> Script:
    """The shooter starts as S1, the adapter names the partner at frame 100 and switches to the
    table's best shooter for it."""
    best = Table.load().best_shooter(partner)

    def status(frame: int, filled: int, estimate: str, policy: str) -> AdapterStatus:
        """The adapter's status at `frame` (`filled` frames of its window seen)."""
        scores = {estimate: -0.5} if estimate else {}
        return AdapterStatus(
            match=name,
            frame=frame,
            sender="adapter",
            role="shooter",
            strategy="cem",
            window=WINDOW,
            filled=filled,
            partner=estimate,
            policy=policy,
            scores=scores,
        )

    return Script(
        name, seed, FRAMES, {"bait": partner, "shooter": "S1"},
        statuses=(status(0, 0, "", "S1"), *(status(f, WINDOW, partner, best) for f in (WINDOW, 2 * WINDOW))),
        switches=(PolicySwitch(
            match=name, frame=WINDOW, sender="adapter", role="shooter", policy=best, reason="partner"
        ),),
    )  # fmt: skip


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Report, dict[str, Path], Path]:
    root = tmp_path_factory.mktemp("report")
    paths: dict[str, Path] = {}
    for i, (bait, shooter) in enumerate(STATIC):
        name = f"static-{bait}-{shooter}"
        paths[name] = root / f"{name}.tsflog"
        record_match(
            paths[name], script=Script(name, i, FRAMES, {"bait": bait, "shooter": shooter}, None, (), ())
        )
    for partner, seed in ADAPTIVE:
        name = f"adaptive-{partner}"
        paths[name] = root / f"{name}.tsflog"
        record_match(paths[name], script=adaptive_script(name, partner, seed))
    person = "person-1"  # a person's bait seat (B4 stands in for the person), with a study sidecar
    paths[person] = root / f"{person}.tsflog"
    script = Script(
        person, 20, FRAMES, {"bait": "B4", "shooter": "S5"}, {"bait": "", "shooter": "S5"}, (), ()
    )
    record_match(paths[person], script=script)
    sidecar = {"participant": "P01", "role": "bait", "session": 1, "status": "done"}
    (root / f"{person}.study.json").write_text(json.dumps(sidecar))
    dropped = root / "dropped.tsflog"  # a participant who dropped out: the study runner marks it
    shutil.copy(paths["static-B9-S5"], dropped)
    (root / "dropped.study.json").write_text(json.dumps({**sidecar, "status": "dropped"}))
    truncated, garbage = root / "truncated.tsflog", root / "garbage.tsflog"
    shutil.copy(paths["static-B5-S5"], truncated)
    with truncated.open("r+b") as f:
        f.truncate(truncated.stat().st_size // 2)
    garbage.write_bytes(b"not a recording at all")
    report = build_report([*paths.values(), dropped, truncated, garbage], root / "out", reference_games=1)
    return report, paths, root / "out"


def csv(out: Path, name: str) -> pd.DataFrame:
    return pd.read_csv(out / "data" / f"{name}.csv", keep_default_na=False, na_values=[""])


def stream(recording: Recording, role: str) -> tuple[list[list[float]], list[int]]:
    """The partner's (world-view state, action) pairs straight from the decoded recording."""
    obs = {s.frame: s.obs[role] for s in recording.states}
    pairs = {a.frame: a.action for _, a in recording.actions if a.role == role and a.frame in obs}
    frames = sorted(pairs)
    return [obs[f] for f in frames], [pairs[f] for f in frames]


def test_bad_recordings_are_named_and_the_rest_builds(built: tuple[Report, dict[str, Path], Path]) -> None:
    report, paths, out = built
    problems = csv(out, "problems").set_index("name")
    assert "no summary" in problems.loc["truncated", "reason"] and not problems.loc["truncated", "used"]
    assert "unreadable" in problems.loc["garbage", "reason"]
    assert "marked this attempt dropped" in problems.loc["dropped", "reason"]
    page = report.html.read_text()
    assert all(f"{name} (left out)" in page for name in ("truncated", "garbage", "dropped"))
    assert set(csv(out, "partners")["match"]) == set(paths) and report.matches == len(paths)


def test_a_torn_tail_after_the_summary_is_noted_and_used(
    built: tuple[Report, dict[str, Path], Path], tmp_path: Path
) -> None:
    _, paths, _ = built
    torn = tmp_path / "torn.tsflog"
    torn.write_bytes(paths["static-B5-S5"].read_bytes() + b"\x40\x00\x00\x00\x00\x00\x00\x00half a record")
    matches, problems = load_matches([torn], tmp_path / "pq")
    assert [m.name for m in matches] == ["torn"] and matches[0].kills_per_minute == pytest.approx(
        load(paths["static-B5-S5"]).summary.kills_per_minute
    )
    assert [(p.name, p.used) for p in problems] == [("torn", True)] and "torn" in problems[0].reason


def test_seats_follow_the_partner_rule(built: tuple[Report, dict[str, Path], Path]) -> None:
    _, paths, out = built
    partners = csv(out, "partners")
    seats = {(r.match, r.partner_role): r for r in partners.itertuples()}
    assert len(partners) == 2 * len(STATIC) + len(ADAPTIVE) + 1
    b5 = seats[("static-B5-S5", "bait")]
    assert (b5.partner, b5.agent, b5.variant, b5.adaptive) == ("B5", "S5", "S5", False)
    assert seats[("static-B5-S5", "shooter")].variant == "B5"
    adaptive = seats[("adaptive-B9", "bait")]
    assert (adaptive.variant, adaptive.adaptive) == (f"adaptive-T{WINDOW}-cem", True)
    assert ("adaptive-B9", "shooter") not in seats
    person = seats[("person-1", "bait")]
    assert (person.partner, person.variant) == ("P01", "S5") and ("person-1", "shooter") not in seats


def test_seats_from_the_start_record_alone(
    tmp_path: Path, built: tuple[Report, dict[str, Path], Path]
) -> None:
    """A person's seat named "human" (the launcher's key), an adaptive seat with no statuses, and the
    participant's seat named by a study sidecar."""
    _, paths, _ = built
    [match], _ = load_matches([paths["static-B5-S5"]], tmp_path)

    def announcing(policies: dict[str, str]) -> Match:
        info = match.tables["match"].assign(policies=[policies])
        return dataclasses.replace(match, tables={**match.tables, "match": info})

    [human] = seats(announcing({"bait": "human", "shooter": "S5"}))
    assert (human.partner_role, human.partner, human.variant, human.adaptive) == (
        "bait",
        "person",
        "S5",
        False,
    )
    [adaptive] = seats(announcing({"bait": "B5", "shooter": "adaptive-T400-cem"}))
    assert (adaptive.partner_role, adaptive.variant, adaptive.adaptive) == ("bait", "adaptive-T400-cem", True)
    assert adaptive.agent == "S5"  # the key behind its actions
    [participant] = seats(
        dataclasses.replace(match, meta={"role": "shooter", "participant": "P7", "variant": "v"})
    )
    assert (participant.partner_role, participant.partner, participant.variant) == ("shooter", "P7", "v")


def test_similarity_vectors_and_performance(built: tuple[Report, dict[str, Path], Path]) -> None:
    _, paths, out = built
    partners = csv(out, "partners")
    config = GameConfig(frames=FRAMES)
    for row in partners.itertuples():
        recording = load(paths[row.match])
        assert row.kills_per_minute == pytest.approx(recording.summary.kills_per_minute)
        states, actions = stream(recording, row.partner_role)
        assert row.frames == len(actions) == FRAMES
        for key in library.keys(row.partner_role)[:3]:  # a few judges per seat keep the test quick
            direct = log_probs([networks.load(key, config)], states, actions).mean()
            assert getattr(row, key) == pytest.approx(direct, rel=1e-9)
        others = library.keys("shooter" if row.partner_role == "bait" else "bait")
        assert all(math.isnan(getattr(row, key)) for key in others)


def test_similarity_to_optimal_and_correlation(built: tuple[Report, dict[str, Path], Path]) -> None:
    _, _, out = built
    table, partners = Table.load(), csv(out, "partners")
    similarity = csv(out, "similarity")
    correlations = csv(out, "correlations").set_index(["kind", "partner_role"])
    for row in similarity.itertuples():
        best = table.best_bait(row.agent) if row.partner_role == "bait" else table.best_shooter(row.agent)
        assert row.optimal == best
        seat = partners[(partners["match"] == row.match) & (partners["partner_role"] == row.partner_role)]
        assert row.similarity == pytest.approx(seat.iloc[0][best]) and row.kind == seat.iloc[0]["kind"]
    # the scripted seats of no match here: every seat's agent is a library policy
    assert len(similarity) == len(partners)
    # one correlation per group: the study trial's single pair is not pooled with the agent matches
    assert correlations.loc[("study trial", "bait"), "n"] == 1
    assert correlations.loc[("study trial", "bait"), "note"] == "fewer than 3 seats"
    for role in ("bait", "shooter"):
        mine = similarity[(similarity["partner_role"] == role) & (similarity["kind"] == "agents only")]
        x, y = mine["similarity"].to_numpy(), mine["kills_per_minute"].to_numpy()
        r = np.corrcoef(x, y)[0, 1]
        t = r * math.sqrt((len(x) - 2) / (1 - r * r))
        group = ("agents only", role)
        assert correlations.loc[group, "n"] == len(mine)
        assert correlations.loc[group, "r"] == pytest.approx(r)
        assert correlations.loc[group, "p"] == pytest.approx(2 * stats.t.sf(abs(t), len(x) - 2))


def test_policy_space(built: tuple[Report, dict[str, Path], Path]) -> None:
    _, _, out = built
    points, variance = csv(out, "policy_space"), csv(out, "policy_space_variance").set_index("role")
    references = csv(out, "references")
    partners = csv(out, "partners")
    for role in ("bait", "shooter"):
        keys = library.keys(role)
        ref = references[references["role"] == role].set_index("policy")[keys]
        matrix = np.vstack([ref.to_numpy(), partners[partners["partner_role"] == role][keys].to_numpy()])
        eigen = np.sort(np.linalg.eigvalsh(np.cov(matrix.T)))[::-1]
        assert variance.loc[role, ["pc1", "pc2"]].to_numpy() == pytest.approx(eigen[:2] / eigen.sum())
        mine = points[points["role"] == role]
        assert list(mine[mine["kind"] == "library"]["name"]) == keys
        assert (mine["kind"] == "partner").sum() == (partners["partner_role"] == role).sum()
        # the projection keeps the spread: the points' variance along each axis is the eigenvalue
        assert np.var(mine[["pc1", "pc2"]].to_numpy(), axis=0, ddof=1) == pytest.approx(eigen[:2])
        # a library policy is most similar to itself in its own row of the reference matrix
        assert all(ref.loc[key].idxmax() == key for key in keys)


def test_adaptive_vs_static_within_each_kind_and_seat(built: tuple[Report, dict[str, Path], Path]) -> None:
    """Variants are summarised per group (kind of match, partner's seat): the study trial's S5 is not
    pooled with the agent matches' S5, nor a bait variant with the shooter variants; the adaptive
    shooter is tested against the best static shooter of the agent matches with bait partners."""
    report, paths, out = built
    variants, tests = csv(out, "variants"), csv(out, "adaptive_tests")
    agents = variants[(variants["kind"] == "agents only") & (variants["partner_role"] == "bait")]
    agents = agents.set_index("variant")
    kpm = {name: load(path).summary.kills_per_minute for name, path in paths.items()}
    adaptive = [kpm[f"adaptive-{p}"] for p, _ in ADAPTIVE]
    row = agents.loc[f"adaptive-T{WINDOW}-cem"]
    assert row["n"] == len(ADAPTIVE) and row["mean"] == pytest.approx(statistics.fmean(adaptive))
    assert row["stderr"] == pytest.approx(statistics.stdev(adaptive) / math.sqrt(len(adaptive)))
    s5 = [kpm[f"static-{b}-{s}"] for b, s in STATIC if s == "S5"]
    assert agents.loc["S5", "n"] == len(s5) and agents.loc["S5", "mean"] == pytest.approx(
        statistics.fmean(s5)
    )
    study = variants[variants["kind"] == "study trial"]
    assert list(zip(study["partner_role"], study["variant"], study["n"], strict=True)) == [("bait", "S5", 1)]
    shooters = variants[(variants["kind"] == "agents only") & (variants["partner_role"] == "shooter")]
    assert set(shooters["variant"]) == {b for b, _ in STATIC}  # the baits, as the shooters' agents
    statics = agents[(~agents["adaptive"]) & (agents["n"] >= 2)]
    best = statics["mean"].idxmax()
    [test] = tests.itertuples()
    assert (test.kind, test.partner_role, test.static, test.test) == ("agents only", "bait", best, "Welch t")
    group = csv(out, "partners").query(
        "kind == 'agents only' and partner_role == 'bait' and variant == @best"
    )
    b = np.array([kpm[m] for m in group["match"]])
    a = np.array(adaptive)
    se = math.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    assert test.t == pytest.approx((a.mean() - b.mean()) / se)
    # what was not compared is said, in the data, on the page and in the report's lines
    left = csv(out, "left_out")
    untested = left[left["variant"].isna()]
    assert set(zip(untested["kind"], untested["partner_role"], strict=True)) == {
        ("agents only", "shooter"),
        ("study trial", "bait"),
    }
    assert set(left.dropna(subset=["variant"])["variant"]) == set(statics.index.symmetric_difference(
        agents[~agents["adaptive"]].index))  # fmt: skip
    page = report.html.read_text()
    assert "Not compared: study trial, bait partners (1 pairings): no adaptive variant to test" in page
    assert "never across them" in page and len(report.left_out) == len(left)


def test_left_out_names_a_group_with_no_static_variant_to_compare() -> None:
    rows = [
        {"kind": "study trial", "partner_role": "bait", "partner": p, "variant": v,
         "adaptive": v.startswith("a"), "kills_per_minute": k}
        for p, v, k in (("P1", "adaptive-T400-cem", 3.0), ("P2", "adaptive-T400-cem", 4.0), ("P1", "S5", 2.0))
    ]  # fmt: skip
    partners = pd.DataFrame(rows)
    summary = variants(partners)
    tests = adaptive_tests(partners, summary)
    assert tests.empty
    [line] = left_out_lines(left_out(summary, tests))
    assert line == (
        "study trial, bait partners (3 pairings): no static variant with 2 or more matches to test the "
        "adaptive ones against"
    )


def test_adapter_timeline_and_curves(built: tuple[Report, dict[str, Path], Path]) -> None:
    _, paths, out = built
    timeline = csv(out, "adapter")
    assert len(timeline) == 3 * len(ADAPTIVE)
    b9 = timeline[timeline["match"] == "adaptive-B9"]
    assert list(b9["frame"]) == [0, WINDOW, 200] and list(b9["partner"].fillna("")) == ["", "B9", "B9"]
    assert list(b9["policy"]) == ["S1", Table.load().best_shooter("B9")] * 1 + [
        Table.load().best_shooter("B9")
    ]
    assert b9["seconds"].iloc[1] == pytest.approx(WINDOW / 30)

    curves = csv(out, "logprob_curves")
    trial = curves["match"].iloc[0]
    role = curves["partner_role"].iloc[0]
    recording = load(paths[trial])
    assert len(curves) == FRAMES * len(library.keys(role))
    states, actions = stream(recording, role)
    key = library.keys(role)[0]
    mine = curves[curves["policy"] == key]
    direct = log_probs([networks.load(key, GameConfig(frames=FRAMES))], states, actions)[:, 0]
    assert mine["log_prob"].to_numpy() == pytest.approx(direct)
    assert mine["smoothed"].iloc[40] == pytest.approx(direct[11:41].mean())
    ends = sorted(e.frame for e in recording.events if e.kind in ("kill", "reset"))
    assert list(mine["round"]) == [sum(end < frame for end in ends) for frame in mine["frame"]]
    assert mine["round"].iloc[-1] > 0  # the trial has more than one round
    rounds = csv(out, "logprob_rounds").query("policy == @key").set_index("round")
    for number, part in mine.groupby("round"):
        assert rounds.loc[number, "frames"] == len(part)
        assert rounds.loc[number, "log_prob"] == pytest.approx(part["log_prob"].mean())


def test_figures_and_page(built: tuple[Report, dict[str, Path], Path]) -> None:
    report, _, out = built
    assert set(report.figures) == {
        "table",
        "policy_space",
        "similarity",
        "logprob_curves",
        "variants",
        "adapter",
    }
    for path in report.figures.values():
        with Image.open(path) as image:
            assert image.format == "PNG" and image.width > 300 and image.height > 200
            colours = image.convert("RGB").getcolors(maxcolors=1 << 16)
            assert colours is None or len(colours) > 20  # drawn, not blank
    page = report.html.read_text()
    assert page.count("data:image/png;base64,") == len(report.figures)
    assert "Welch" in page and "Pearson" in page
    assert "Provenance" in page and report.provenance["commit"] in page and report.provenance["table"] in page
    assert set(pd.read_csv(out / "data" / "provenance.csv")["field"]) == set(FIELDS)


def test_no_label_of_a_report_figure_overlaps_another_or_is_cut_off(
    built: tuple[Report, dict[str, Path], Path], tmp_path: Path
) -> None:
    """Every figure of the report drawn again from its data and checked as rendered: the extents of
    its texts (titles, tick and axis labels, point labels, legends) intersect nowhere and stay inside
    the figure."""
    report, _, _ = built
    d = report.data

    def draw() -> None:
        heatmap(Table.load(), tmp_path / "table.png")
        figures.policy_space(d["policy_space"], d["policy_space_variance"], tmp_path / "policy_space.png")
        figures.similarity(d["similarity"], d["correlations"], tmp_path / "similarity.png")
        figures.curves(d["logprob_curves"], 30, tmp_path / "logprob.png")
        figures.variants(d["variants"], d["adaptive_tests"], tmp_path / "variants.png")
        figures.adapter(d["adapter"], tmp_path / "adapter.png")

    checked = legibility(draw)
    assert len(checked) == 6
    assert {name: problems for name, problems in checked.items() if problems} == {}


def test_the_legibility_check_sees_overlapping_and_clipped_labels(tmp_path: Path) -> None:
    import matplotlib.pyplot as plt

    def draw() -> None:
        fig, ax = plt.subplots(figsize=(3, 2))
        ax.annotate("first label", (0.5, 0.5))
        ax.annotate("second label", (0.5, 0.5))
        fig.text(0.9, 0.5, "past the edge")
        save(fig, tmp_path / "bad.png")

    [problems] = legibility(draw).values()
    assert (
        "'second label' overlaps 'first label'" in problems
        or "'first label' overlaps 'second label'" in problems
    )
    assert "'past the edge' is cut off by the figure's edge" in problems


def test_a_report_with_nothing_usable_still_builds(tmp_path: Path) -> None:
    bad = tmp_path / "bad.tsflog"
    bad.write_bytes(b"TSFLOG1\n" + b"\xff" * 40)  # the magic, then a corrupt first record
    report = build_report([bad], tmp_path / "out")
    assert [(p.name, p.used) for p in report.problems] == [("bad", False)]
    assert "no start record" in report.problems[0].reason
    assert report.html.exists() and "bad (left out)" in report.html.read_text() and report.matches == 0
    assert csv(tmp_path / "out", "partners").empty and csv(tmp_path / "out", "variants").empty


def test_paired_test_where_every_partner_met_both() -> None:
    """Each partner met the adaptive agent and the best static one: the paired t-test on partner means."""
    kpm = {"B1": (2.0, 1.0), "B2": (5.0, 3.0), "B3": (7.0, 6.5), "B4": (3.0, 3.5)}  # adaptive, static
    rows = [
        {
            "kind": "agents only",
            "partner_role": "bait",
            "partner": partner,
            "variant": variant,
            "adaptive": variant == "adaptive-T400-cem",
            "kills_per_minute": k,
        }
        for partner, pair in kpm.items()
        for variant, k in zip(("adaptive-T400-cem", "S5"), pair, strict=True)
    ]
    group = {"kind": "agents only", "partner_role": "bait"}
    rows.append({**group, "partner": "B1", "variant": "S6", "adaptive": False, "kills_per_minute": 0.5})
    rows.append({**group, "partner": "B2", "variant": "S6", "adaptive": False, "kills_per_minute": 1.5})
    partners = pd.DataFrame(rows)
    [test] = adaptive_tests(partners, variants(partners)).itertuples()
    d = np.array([a - s for a, s in kpm.values()])
    assert (test.static, test.test, test.n_adaptive, test.n_static) == (
        "S5",
        "paired t (partner means)",
        4,
        4,
    )
    assert test.t == pytest.approx(d.mean() / (d.std(ddof=1) / math.sqrt(len(d))))
    assert test.p == pytest.approx(2 * stats.t.sf(abs(test.t), len(d) - 1))
