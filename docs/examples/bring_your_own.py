"""Bring your own policy, all the way to the adaptive teammate: a bait of your own becomes a library
key, gets its row of the self-play table and its out-of-library thresholds, and the adaptive
shooter then recognises it in a live match and plays the table's best response to it.

    python docs/examples/bring_your_own.py WORKDIR [--steps 2048] [--games 2] [--seeds 1] [--duration 20]

Each step is the `tsf` command you would type (printed before it runs), with TSF_LIBRARY naming
your library; everything is written under WORKDIR, nothing into the checkout. The defaults are
small so that it runs in about a minute on 2 idle cores (tests/test_bring_your_own.py runs it); a
real policy trains for millions of steps, a real table takes 20 games a pair (`--games 20`) and
the thresholds 2 (`--seeds 2`). Needs the
`train` extra (Stable-Baselines3) for step 1 only: a model of yours from elsewhere works as well.

1. train:     a PPO bait against S5 on the registered env (`tsf/Role-v0`), saved as a .zip
2. add:       `tsf library add MYBAIT my_bait.zip --role bait --library WORKDIR/mylib`
3. refused:   an adaptive match now stops with one line: with `--strategy cem`, `StaleTable: ...`
              (the shipped table was measured without MYBAIT), with the default strategy the
              missing thresholds; each line names the command to run
4. sweep:     `tsf sweep --out WORKDIR/mylib/table.json`: the table with MYBAIT's row
5. calibrate: `tsf calibrate-adapter --out WORKDIR/mylib/calibration.json`: the thresholds for the
              default strategy's out-of-library test
6. match:     `tsf match --bait MYBAIT --adaptive shooter --partners library`: the study
              library's adaptive agent, which knows the libraries in use through their table,
              names MYBAIT and plays the best shooter for it from the new table (the default
              agent, `--partners groups`, knows the grown library's partner groups instead)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

KEY = "MYBAIT"


def tsf(*args: str, library: Path | None, check: bool = True) -> subprocess.CompletedProcess:
    """Run `tsf ARGS` (this interpreter's) with TSF_LIBRARY=library, showing the command and its output."""
    env = dict(os.environ)
    if library is not None:
        env["TSF_LIBRARY"] = str(library)
    shown = (f"TSF_LIBRARY={library} " if library else "") + "tsf " + " ".join(args)
    print(f"\n$ {shown}", flush=True)
    done = subprocess.run(
        [sys.executable, "-m", "services.commands", *args],
        env=env,
        text=True,
        capture_output=True,
        stdin=subprocess.DEVNULL,
    )
    print((done.stdout + done.stderr).rstrip(), flush=True)
    if check and done.returncode != 0:
        raise SystemExit(f"step failed (exit {done.returncode}): {shown}")
    return done


def train(path: Path, steps: int) -> None:
    """Step 1: a bait of your own. Any SB3 feed-forward actor-critic trained on tsf/Role-v0 will do."""
    import gymnasium

    from services.agent import envs  # noqa: F401 - registers tsf/Role-v0
    from shared.errors import missing_extra

    try:
        from stable_baselines3 import PPO
    except ModuleNotFoundError as error:  # one line that says what to install, not a traceback
        raise SystemExit(f"step 1 (train) {missing_extra(error) or error}") from None

    print(f"\n# train: PPO bait against S5, {steps} steps -> {path}", flush=True)
    env = gymnasium.make("tsf/Role-v0", role="bait", partner="S5")
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=64, n_epochs=2, seed=0, device="cpu")
    model.learn(total_timesteps=steps)
    model.save(path)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workdir", type=Path)
    parser.add_argument("--steps", type=int, default=2048, help="PPO steps for the bait")
    parser.add_argument("--games", type=int, default=2, help="games per pair in the table")
    parser.add_argument("--duration", type=int, default=20, help="seconds of the adaptive match")
    parser.add_argument("--seeds", type=int, default=1, help="games per pair for the thresholds (2 shipped)")
    parser.add_argument("--workers", type=int, default=2, help="worker processes for sweep and calibration")
    args = parser.parse_args()
    work = args.workdir.resolve()
    work.mkdir(parents=True, exist_ok=True)
    mylib, model = work / "mylib", work / "my_bait.zip"

    train(model, args.steps)
    tsf(
        "library",
        "add",
        KEY,
        str(model),
        "--role",
        "bait",
        "--library",
        str(mylib),
        "--games",
        "1",
        library=None,
    )

    for strategy in ("cem", "bayes-dwell-ood-guard"):  # the study's, then the default (with -ood)
        match = [
            "match",
            "--lockstep",
            "--duration",
            "5",
            "--bait",
            KEY,
            "--adaptive",
            "shooter",
            "--partners",
            "library",
        ]
        refused = tsf(
            *match, "--strategy", strategy, "--out", str(work / "recordings"), library=mylib, check=False
        )
        if refused.returncode == 0:
            raise SystemExit("an adaptive match ran on a table or thresholds measured without the new policy")
    print("# refused, as it should be: the next two steps are the commands those lines name")

    workers = str(args.workers)
    tsf(
        "sweep",
        "--games",
        str(args.games),
        "--workers",
        workers,
        "--out",
        str(mylib / "table.json"),
        library=mylib,
    )
    tsf("calibrate-adapter", "--seeds", str(args.seeds), "--workers", workers,
        "--out", str(mylib / "calibration.json"), library=mylib)  # fmt: skip

    recordings = work / "recordings"
    tsf("match", "--lockstep", "--duration", str(args.duration), "--seed", "1", "--bait", KEY, "--adaptive",
        "shooter", "--partners", "library", "--match", "byo", "--out", str(recordings), "--overwrite",
        library=mylib)  # fmt: skip
    return report(mylib / "table.json", recordings / "byo.tsflog")


def report(table_path: Path, recording_path: Path) -> int:
    """What the adapter made of the new partner, from the recording: exit 1 if it never named it."""
    from services.recorder.recording import load

    table = json.loads(table_path.read_text())
    best = max(table["shooters"], key=lambda s: table["mean"][KEY][s])
    named = [status for status in load(recording_path).adapter if status.partner == KEY]
    print(f"\n# the new table's best shooter for {KEY}: {best}")
    if not named:
        print(f"# the adapter never took its partner for {KEY}: see {recording_path}")
        return 1
    print(
        f"# the adapter took its partner for {KEY} from frame {named[0].frame} and played {named[-1].policy}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
