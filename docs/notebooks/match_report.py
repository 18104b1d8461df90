# %% [markdown]
# # A match to its report
#
# Two 20-second lockstep matches on the zenoh bus with the library bait B5: one with the adaptive
# shooter, one with the static S4. Each match writes a recording and its tables as Parquet; `tsf
# report` turns the recordings into the original study's figures and numbers, and the Parquet tables
# make any other figure a few lines of pandas. Everything is written to a temporary folder.

# %%
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd
from IPython.display import Image

tsf = str(Path(sys.executable).with_name("tsf"))  # the `tsf` command of this environment
work = Path(tempfile.mkdtemp(prefix="tsf-notebook-"))
plain = {**os.environ, "NO_COLOR": "1", "COLUMNS": "150"}  # the commands' lines as they would be in a log
for shooter in (["--adaptive", "shooter"], ["--shooter", "S4"]):
    match = subprocess.run(
        [tsf, "match", "--lockstep", "--duration", "20", "--seed", "1", "--bait", "B5", *shooter]
        + ["--out", str(work / "recordings")],
        check=True, capture_output=True, text=True, env=plain,
    )  # fmt: skip
    lines = match.stdout.splitlines()  # the scoreboard's updates, then the summary
    print(*lines[next(i for i, line in enumerate(lines) if "kills/min" in line) :], sep="\n")
recordings = sorted((work / "recordings").glob("*.tsflog"))
[r.name for r in recordings]

# %% [markdown]
# ## The report
#
# `tsf report` replays each recording (every state hash checked), then writes `report.html`, its
# figures and the data behind them. The variants' table compares the two shooters:

# %%
report = [tsf, "report", *map(str, recordings), "--out", str(work / "report")]
subprocess.run(report, check=True, capture_output=True)
pd.read_csv(work / "report" / "data" / "variants.csv")

# %%
Image(filename=str(work / "report" / "figures" / "adapter.png"), width=700)

# %% [markdown]
# ## A figure of your own from the Parquet tables
#
# Each match's tables sit beside its recording (`<match>.tables/<match>.<table>.parquet`); every
# table has a `match` column, so a folder of matches reads as one table. The team's kills over time
# in each match, and what the adaptive shooter played:

# %%
tables = work / "recordings"
states = pd.concat(pd.read_parquet(p) for p in sorted(tables.glob("*.tables/*.states.parquet")))
matches = pd.concat(pd.read_parquet(p) for p in sorted(tables.glob("*.tables/*.match.parquet")))
shooter = dict(zip(matches["match"], matches["policies"].map(lambda p: p["shooter"]), strict=True))

fig, ax = plt.subplots(figsize=(7, 3.5))
for match, frames in states.groupby("match"):
    ax.step(frames["frame"] / 30, frames["kills"], where="post", label=f"B5 with {shooter[match]}")
ax.set(xlabel="game time (s)", ylabel="kills", title="Kills over the match")
ax.legend()
plt.show()

# %%
switches = pd.concat(pd.read_parquet(p) for p in sorted(tables.glob("*.tables/*.switches.parquet")))
switches.assign(second=switches["frame"] / 30)[["match", "second", "role", "policy", "reason"]]
