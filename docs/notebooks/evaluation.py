# %% [markdown]
# # An evaluation re-analysed
#
# The shipped evaluation of the adaptive shooter (`docs/eval/team.csv`: every game of 64 bait
# partners with each of 16 shooters, 64 seeds each) analysed again without playing a game:
# `tsf eval --games` reads the games and writes the comparison with the best static shooter, per
# partner and per group, as `tsf eval` does after playing them. Then one figure of our own: where
# the study library's agent (`adaptive-T400-bayes-dwell-ood-guard`: the default strategy, choosing
# among the study's shooters by the table P) gains over the best static one, partner by partner.
# The shipped default agent, the grown library's (`--partners groups`), is measured on held-out
# partners in `docs/eval/held-out` (docs/adapter.md, "Results at a glance").

# %%
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

import services

tsf = str(Path(sys.executable).with_name("tsf"))  # the `tsf` command of this environment
games = Path(services.__file__).parent.parent / "docs" / "eval" / "team.csv"  # the checkout's copy
out = Path(tempfile.mkdtemp(prefix="tsf-notebook-")) / "eval"
analysis = [tsf, "eval", "--role", "shooter", "--games", str(games), "--out", str(out)]
subprocess.run(analysis, check=True, capture_output=True)
sorted(p.name for p in out.iterdir())

# %% [markdown]
# `comparison.json` holds the test of each adaptive variant against the best static shooter
# (here S4), paired by partner and seed:

# %%
comparison = json.loads((out / "comparison.json").read_text())
tests = pd.DataFrame(comparison["tests"]).T
tests[["mean_difference", "stderr", "d_z", "p_holm", "partners_better", "partners"]].round(4)

# %% [markdown]
# ## One figure of our own
#
# `per_partner.csv` has every agent's mean kills per minute with each partner. The study library's
# adaptive shooter minus the best static one (S4), partner by partner, coloured by the partner's kind:

# %%
per_partner = pd.read_csv(out / "per_partner.csv")
wide = per_partner.pivot(index="partner", columns="agent", values="kills_per_minute")
group = per_partner.drop_duplicates("partner").set_index("partner")["kind"]
gain = (wide["adaptive-T400-bayes-dwell-ood-guard"] - wide["S4"]).sort_values()

colours = dict(zip(sorted(group.unique()), plt.cm.tab10.colors, strict=False))
fig, ax = plt.subplots(figsize=(7, 9))
ax.barh(range(len(gain)), gain, color=[colours[group[p]] for p in gain.index])
ax.set_yticks(range(len(gain)), gain.index, fontsize=6)
ax.axvline(0, color="black", linewidth=0.8)
ax.set(xlabel="kills/min, the study library's agent minus S4", title="Where the adaptive shooter gains")
ax.legend(handles=[plt.Rectangle((0, 0), 1, 1, color=c) for c in colours.values()], labels=list(colours))
plt.tight_layout()
plt.show()

# %%
built_on_b3 = gain.index.str.contains(r"\bB3\b")
pd.Series(
    {
        "partners better / equal / worse": f"{(gain > 0).sum()} / {(gain == 0).sum()} / {(gain < 0).sum()}",
        "mean gain (kills/min)": round(gain.mean(), 3),
        "share of the gain from the partners built on B3": f"{gain[built_on_b3].sum() / gain.sum():.0%}",
        "mean gain without them": round(gain[~built_on_b3].mean(), 3),
    }
)
