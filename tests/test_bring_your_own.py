"""docs/examples/bring_your_own.py, run as a reader would: a PPO bait of one's own, added to a
library of one's own, refused by the adaptive agent until its table row and thresholds are
measured, then recognised in a live match on the bus, where the adaptive shooter plays the new
table's best response to it. Real processes, real zenoh, real files; small numbers (2 games a
pair, 1 calibration seed, a 20 s match) keep it to about 90 s on 2 cores: marked slow to keep the
default run under ten minutes, and run by CI as a step of its own (.ci/run)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3", reason="the `train` extra is not installed")
pytestmark = pytest.mark.slow

from services.agent import library  # noqa: E402
from services.recorder.recording import load  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
KEY = "MYBAIT"


def test_a_policy_of_ones_own_reaches_the_adaptive_teammate(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    env.pop("TSF_LIBRARY", None)
    run = subprocess.run(
        [sys.executable, str(ROOT / "docs" / "examples" / "bring_your_own.py"), str(tmp_path / "work")],
        capture_output=True, text=True, timeout=900, env=env, cwd=tmp_path, stdin=subprocess.DEVNULL,
    )  # fmt: skip
    out = run.stdout + run.stderr
    assert run.returncode == 0, out[-4000:]
    mylib = tmp_path / "work" / "mylib"
    # the refusals name the step to take, one line each
    assert "StaleTable:" in out and f"tsf sweep --out {mylib / 'table.json'}" in out
    assert f"tsf calibrate-adapter --out {mylib / 'calibration.json'}" in out
    monkeypatch.setenv("TSF_LIBRARY", str(mylib))
    assert library.keys("bait")[-1] == KEY
    table = json.loads((mylib / "table.json").read_text())
    calibration = json.loads((mylib / "calibration.json").read_text())
    assert table["baits"][-1] == KEY and table["library"] == calibration["library"] == library.manifest_hash()
    assert calibration["seeds"] == [0]
    best = max(table["shooters"], key=lambda s: table["mean"][KEY][s])
    recording = load(tmp_path / "work" / "recordings" / "byo.tsflog")
    assert recording.start.policies == {"bait": KEY, "shooter": "adaptive-T400-bayes-dwell-ood-guard"}
    named = [status for status in recording.adapter if status.partner == KEY]
    assert named and not any(status.out_of_library for status in named)
    assert any(status.policy == best for status in named)
    assert f"the adapter took its partner for {KEY} from frame {named[0].frame}" in out
    assert not list(ROOT.glob("tsf-*")) and not (ROOT / "recordings").exists()  # nothing into the checkout
