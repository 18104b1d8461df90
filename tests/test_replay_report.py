"""Replay and report on recordings of real bus matches (every service in its own process): `tsf
replay` checks them, `--live` puts one back on the bus for a watcher, `tsf report` builds from them
and names a truncated copy."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from PIL import Image

from services.population.adaptive import AdapterConfig
from services.population.seat import SeatSpec
from services.recorder.recording import load
from services.recorder.replay import republish
from services.runtime.launch import MatchPlan, run_match
from shared.messages import GameEvent, Start, State, Summary

FRAMES = 300
PAIRS = [("B9", "S5", 1), ("B2", "S4", 2)]  # a strong and a weak pair, so performance varies
SPEED = 10.0
ADAPTIVE, WINDOW = "rr-adaptive", 100  # a match whose shooter is the adaptive agent


@pytest.fixture(scope="module")
def matches(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Summary, Path]]:
    directory = tmp_path_factory.mktemp("bus-recordings")
    out = {}
    for bait, shooter, seed in PAIRS:
        seats = SeatSpec.parse(bait), SeatSpec.parse(shooter)
        plan = MatchPlan(f"rr-{bait}-{shooter}", seed, FRAMES, "lockstep", *seats, directory)
        out[plan.match] = run_match(plan)
    adaptive = MatchPlan(
        ADAPTIVE,
        3,
        FRAMES,
        "lockstep",
        SeatSpec.parse("B5"),
        SeatSpec.adaptive_agent(AdapterConfig("shooter", WINDOW, "cem", seed=3)),
        directory,
    )
    out[adaptive.match] = run_match(adaptive)
    return out


def tsf(*args: str) -> subprocess.CompletedProcess:
    """Run the CLI; wide columns, so that rich does not wrap what the test reads."""
    env = {**os.environ, "COLUMNS": "400"}
    return subprocess.run(
        [sys.executable, "-m", "services.commands", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_replay_checks_every_hash(matches: dict[str, tuple[Summary, Path]], tmp_path: Path) -> None:
    _, path = next(iter(matches.values()))
    run = tsf("replay", str(path), "--video", str(tmp_path / "m.gif"), "--scale", "0.25", "--every", "10")
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"all {FRAMES + 1} states reproduce their hashes" in run.stdout
    with Image.open(tmp_path / "m.gif") as gif:
        assert gif.n_frames == FRAMES // 10 + 1


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_live_replay_reaches_a_watcher(matches, bus, tap, background, wait_until) -> None:  # noqa: ANN001
    _, path = next(iter(matches.values()))
    recording = load(path)
    watcher = tap(bus.open(listen=True), "watch")
    sent = background(republish, bus.config(), path, "watch", SPEED, 1.0)
    assert sent.result(timeout=30) > FRAMES
    assert wait_until(lambda: watcher.of(Summary), timeout=5)
    states = watcher.timed(State)
    assert [s.hash for _, s in states] == [s.hash for s in recording.states]
    assert all(s.match == "watch" for _, s in states)
    assert len(watcher.of(Start)) == 1 and len(watcher.of(GameEvent)) == len(recording.events)
    seconds = states[-1][0] - states[0][0]
    assert seconds == pytest.approx(FRAMES / 30 / SPEED, rel=0.25)  # the game's pace, sped up


@pytest.mark.slow
@pytest.mark.long  # 11 s alone: kept out of the default run
def test_report_from_bus_recordings(matches: dict[str, tuple[Summary, Path]], tmp_path: Path) -> None:
    paths = [path for _, path in matches.values()]
    truncated = tmp_path / "cut.tsflog"
    shutil.copy(paths[0], truncated)
    with truncated.open("r+b") as f:
        f.truncate(truncated.stat().st_size * 6 // 10)
    out = tmp_path / "report"
    run = tsf("report", *map(str, paths), str(truncated), "--out", str(out), "--reference-games", "1")
    assert run.returncode == 0, run.stdout + run.stderr
    assert "cut: no summary" in run.stdout
    # one match of each variant: nothing to test, and the command says so rather than run a test
    assert (
        "not compared: agents only, bait partners (3 pairings): no static variant with 2 or more matches"
        in run.stdout
    )
    assert (
        "not compared: agents only, shooter partners (2 pairings): no adaptive variant to test" in run.stdout
    )
    assert pd.read_csv(out / "data" / "adaptive_tests.csv").empty
    partners = pd.read_csv(out / "data" / "partners.csv")
    assert len(partners) == 2 * len(PAIRS) + 1  # agent-agent: each seat is the other's partner
    for name, (summary, _) in matches.items():
        mine = partners[partners["match"] == name]
        assert list(mine["kills_per_minute"]) == pytest.approx([summary.kills_per_minute] * len(mine))
        assert (mine["frames"] >= FRAMES - 1).all()
    [adaptive] = partners[partners["match"] == ADAPTIVE].itertuples()
    assert (adaptive.partner_role, adaptive.partner, adaptive.variant) == (
        "bait",
        "B5",
        f"adaptive-T{WINDOW}-cem",
    )
    statuses = load(matches[ADAPTIVE][1]).adapter
    timeline = pd.read_csv(out / "data" / "adapter.csv", keep_default_na=False)
    assert statuses and list(timeline["frame"]) == [a.frame for a in statuses]
    assert list(timeline["policy"]) == [a.policy for a in statuses]
    assert pd.read_csv(out / "data" / "problems.csv")["name"].tolist() == ["cut"]
    for figure in ("table", "policy_space", "similarity", "logprob", "variants", "adapter"):
        with Image.open(out / "figures" / f"{figure}.png") as image:
            assert image.width > 300 and image.height > 200
    assert time.time() - (out / "report.html").stat().st_mtime < 300
