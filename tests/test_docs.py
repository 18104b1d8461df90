"""The pages a newcomer reads, checked against what ships, so that none goes stale again: every name
and number the README and docs/ state about the shipped table, library and results is recomputed
here from services/agent/library/table.json, docs/eval and docs/figures/report_data; the env page's
examples run; the citation validates; every relative link resolves."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from ruamel.yaml import YAML

from services.adapter.core import Payoff, initial_policy, payoff_of
from services.agent.library import NAMED
from services.population.adaptive import ADAPTIVE, SHIPPED, STRATEGIES, AdapterConfig
from services.report import figures
from services.report.analysis import reference_partner
from services.table.table import Table
from shared.plots import legibility

ROOT = Path(__file__).resolve().parent.parent
PAGES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
REPORT_DATA = ROOT / "docs" / "figures" / "report_data"


def page(name: str) -> str:
    """A page's text with its line breaks and indentation folded to single spaces, so that a claim
    is found wherever the page wraps it."""
    return re.sub(r"\s+", " ", (ROOT / name).read_text())


@pytest.fixture(scope="module")
def table() -> Table:
    return Table.load()


def grouped(text: str) -> dict[str, str]:
    """A page's 'S4 for B2, B4; S6 for B1' as {'B2': 'S4', 'B4': 'S4', 'B1': 'S6'}."""
    pairs = {}
    for part in text.split(";"):
        answer, keys = part.strip().split(" for ")
        pairs.update(dict.fromkeys((k.strip() for k in keys.split(",")), answer))
    return pairs


# --- the citation and the README's first screen --------------------------------------------------


def test_the_citation_file_is_valid_cff_and_the_readme_cites_the_same_study() -> None:
    run = subprocess.run(
        [sys.executable, "-m", "check_jsonschema", "--builtin-schema", "vendor.citation-file-format",
         str(ROOT / "CITATION.cff")],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr
    cff = YAML(typ="safe").load((ROOT / "CITATION.cff").read_text())  # check-jsonschema's reader: no extra
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    [study] = cff["references"]
    readme = page("README.md")
    assert study["title"] in readme and "arXiv:2103.04439" in readme and "CITATION.cff" in readme
    authors = ", ".join(f"{a['family-names']}, {a['given-names'][0]}." for a in study["authors"])
    assert authors in readme  # the same nine authors, in the same order
    version = re.search(r'^version = "(.+)"$', (ROOT / "pyproject.toml").read_text(), re.M)[1]
    assert cff["version"] == version


def test_the_changelog_tops_with_the_version_tsf_prints() -> None:
    """The CHANGELOG's newest version (Unreleased aside) is pyproject's, the one `tsf --version`
    prints and CITATION.cff names; each version before it is a git tag, where the checkout has tags."""
    version = re.search(r'^version = "(.+)"$', (ROOT / "pyproject.toml").read_text(), re.M)[1]
    versions = re.findall(
        r"^## \[(\d+\.\d+\.\d+)\] - \d{4}-\d{2}-\d{2}$", (ROOT / "CHANGELOG.md").read_text(), re.M
    )
    assert versions[0] == version
    assert versions == sorted(versions, key=lambda v: [int(n) for n in v.split(".")], reverse=True)
    tags = subprocess.run(["git", "tag", "-l", "v*"], capture_output=True, text=True, cwd=ROOT).stdout.split()
    if tags:  # a clone made without tags has none to check; the newest is tagged as it is released
        assert {f"v{v}" for v in versions[1:]} <= set(tags)


def test_the_readme_opens_with_a_small_animated_picture_of_a_match() -> None:
    readme = (ROOT / "README.md").read_text()
    picture = ROOT / "docs" / "figures" / "match.gif"
    first_screen = readme[: readme.index("## Two commands")]
    assert "](docs/figures/match.gif)" in first_screen and "## Your first ten minutes" in first_screen
    assert picture.stat().st_size < 2_000_000
    with Image.open(picture) as gif:
        assert gif.format == "GIF" and gif.n_frames > 100
    assert "scripts/gif docs/figures/match.gif" in readme and (ROOT / "scripts" / "gif").exists()
    assert "set -- --bait B5 --adaptive shooter" in (ROOT / "scripts" / "match").read_text()


@pytest.mark.parametrize("name", PAGES)
def test_every_relative_link_resolves(name: str) -> None:
    text = (ROOT / name).read_text()
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    missing = [link for link in links if "://" not in link and not ((ROOT / name).parent / link).exists()]
    assert missing == []


# --- the glossary and the env page ----------------------------------------------------------------


def test_the_glossary_defines_every_strategy_and_the_words_of_the_study() -> None:
    glossary = page("docs/glossary.md")
    for strategy in STRATEGIES:
        assert f"`{strategy}`" in glossary and f"`{strategy}`" in page("docs/adapter.md")
    assert f"`{AdapterConfig().name}`" in glossary and "(the default)" in glossary
    for word in ("CEM, the cross-entropy metric", "not** the cross-entropy method", "Window T", "Table P",
                 "Bait.", "Shooter.", "B1-B9, S1-S7", "Kills/min", "Lanes."):  # fmt: skip
        assert word in glossary, word
    assert "docs/glossary.md" in page("README.md")


def test_the_glossary_names_the_grown_library_and_its_partner_groups() -> None:
    """GB1 (a grown bait), G1 (a partner group) and PB01a (a population member) are easy to confuse:
    the glossary names each, with the counts the shipped groups.json has."""
    glossary = page("docs/glossary.md")
    seats = json.loads((NAMED["grown"] / "groups.json").read_text())["seats"]
    ours = {seat: seats[seat]["teammates"] for seat in seats}
    assert (
        f"**{ours['bait'][0]}-{ours['bait'][-1]}, {ours['shooter'][0]}-{ours['shooter'][-1]}.**" in glossary
    )
    for seat, partner in (("shooter", "bait"), ("bait", "shooter")):
        assert f"{partner} groups G1-G{len(seats[seat]['groups'])}" in glossary
    assert "**PB01a.., PS01a.. (population members).**" in glossary


def python_blocks(name: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / name).read_text(), re.S)


@pytest.mark.parametrize("block", range(2))
def test_the_env_page_examples_run(block: int) -> None:
    blocks = python_blocks("docs/env.md")
    assert len(blocks) == 2
    exec(compile(blocks[block], f"docs/env.md block {block}", "exec"), {})  # noqa: S102 - the page's own code


def test_the_env_page_tables_are_the_envs() -> None:
    from services.agent import envs, library
    from services.sim.env import TSFParallelEnv
    from shared.game import FPS, GameConfig

    env = envs.parallel_env()
    box = env.observation_space("bait")
    text = page("docs/env.md")
    assert f"Box({box.low.min():.0f}, {box.high.max():.0f}, (64,), float32)" in text
    assert f"[{box.low.min():.0f}, {box.high.max():.0f}], float32" in text
    assert f"Discrete({env.action_space('bait').n})" in text
    assert f"`agents = {env.possible_agents}`".replace("'", '"') in text
    assert f"`{TSFParallelEnv.metadata['name']}`" in text and f"| Render FPS | {FPS} |" in text
    config = GameConfig()
    for points, event in ((config.points_kill, "a kill"), (config.points_death, "a ship dies"),
                          (config.points_shield_hit, "a shield hit")):  # fmt: skip
        assert re.search(rf"{event}[^|]*\| {re.escape(f'{points:+d}')} \|", text), event
    assert f"({config.frames:,} frames, {config.frames // FPS} s)" in text
    partners = library.DEFAULT_PARTNER
    assert f"`{partners['bait']}` for the bait seat, `{partners['shooter']}` for the shooter seat" in text


# --- claims about the shipped table and library ---------------------------------------------------


def test_the_library_page_states_the_tables_complementarity(table: Table) -> None:
    text = page("docs/library.md")
    shooters = re.search(r"The best response differs by bait: ([^(]+) \((\d) distinct best shooters\)", text)
    baits = re.search(r"with (\d) distinct best baits \(([^)]+)\)", text)
    best_shooter = {b: table.best_shooter(b) for b in table.baits}
    best_bait = {s: table.best_bait(s) for s in table.shooters}
    assert grouped(shooters[1]) == best_shooter and int(shooters[2]) == len(set(best_shooter.values()))
    assert grouped(baits[2]) == best_bait and int(baits[1]) == len(set(best_bait.values()))


def test_the_pages_name_the_shipped_tables_best_responses(table: Table) -> None:
    shooter, bait = AdapterConfig(role="shooter"), AdapterConfig(role="bait")
    best_shooter = {b: table.best_shooter(b) for b in table.baits}
    best_bait = {s: table.best_bait(s) for s in table.shooters}
    start = initial_policy(shooter)
    circle = json.loads((NAMED["grown"] / "members.json").read_text())["GB1"]  # the picture's bait
    tuned = payoff_of("shooter", "groups")  # the default: the compose match's adaptive shooter
    grown = Payoff.from_groups("shooter", NAMED["grown"] / "groups.json")  # the picture's (the previous)
    default = SHIPPED

    def chosen(payoff: Payoff, partner: str) -> tuple[str, str]:
        """The group the agent over `payoff` places `partner` in, and the member it plays for it."""
        answers = np.argmax(payoff.trust(AdapterConfig().window) @ payoff.type_values, axis=1)
        group = payoff.types[payoff.group[payoff.partners.index(partner)]]
        return group, payoff.ours[answers[payoff.types.index(group)]]

    b5, b5_choice = chosen(tuned, "B5")
    tuned_gb1, tuned_gb1_choice = chosen(tuned, circle)
    gb1, gb1_choice = chosen(grown, circle)
    claims = {
        "README.md": [
            f"which starts as {grown.initial(default)} (the best on average)",
            f"takes its partner for group {gb1} after about six seconds and switches to {gb1_choice}, "
            "that group's best teammate",
            f"`partner like {b5}`: it has placed its partner in bait group {b5}, "
            f"whose best member is {b5_choice}",
            f"placed in group {tuned_gb1}, whose best member is {tuned_gb1_choice} as well",
            f"places GB1 in group {gb1} and switches to {gb1_choice}",
            f"the table's best shooter for it, {best_shooter['B3']}, not {start}",
            f"a shooter agent that starts with `{tuned.initial(default)}` "
            "(the tuned library's member best on average)",
            f"(`B5` is in group {b5}, whose best is `{b5_choice}` itself)",
            f"`{default.strategy}`, window {default.window}, identifying the bait's partner group",
        ],
        "docs/adapter.md": [
            f"{start} for the shooter seat, {initial_policy(bait)} for the bait seat with the shipped table",
            f"falls back to the best static policy ({start} with the shipped table)",
        ],
        "docs/report.md": [
            f"({reference_partner(table, 'bait')} for baits, "
            f"{reference_partner(table, 'shooter')} for shooters)",
            f"starting as {start}, the best average in the table",
            f"({', '.join(best_shooter.values())} for B1-B9)",
            f"For every shooter here, the table's best bait is {best_bait['S4']}",
        ],
    }
    assert best_bait["S4"] == best_bait["S5"] == best_bait["S6"]  # "for every shooter here"
    missing = {name: [c for c in texts if c not in page(name)] for name, texts in claims.items()}
    assert {name: c for name, c in missing.items() if c} == {}


def test_the_adapter_page_reports_the_shipped_evaluation() -> None:
    comparison = json.loads((ROOT / "docs" / "eval" / "comparison.json").read_text())
    text = page("docs/adapter.md")
    best = comparison["best_static"]
    agents = comparison["agents"]
    assert f"best static {best}, {agents[best]['mean']:.3f} ± {agents[best]['stderr']:.3f}" in text
    rows = re.findall(r"^\| \**(adaptive-[A-Za-z0-9-]+)\** [^|]*\| \**([+-][0-9.]+) ± ([0-9.]+)\**", (
        ROOT / "docs" / "adapter.md").read_text(), re.M)  # fmt: skip
    memory = f"{AdapterConfig().name}-memory"  # plays single games as the default does; the page says so
    assert {name for name, _, _ in rows} == set(comparison["tests"]) - {memory}
    for name, difference, stderr in rows:
        test = comparison["tests"][name]
        assert (float(difference), float(stderr)) == (
            round(test["mean_difference"], 3),
            round(test["stderr"], 3),
        ), name
    assert f"**{AdapterConfig().name}** (the default strategy)" in text
    summary = page("docs/eval/summary.md")
    assert f"Best static policy: **{best}**" in summary


@pytest.mark.parametrize("seat", ["shooter", "bait"])
def test_the_adapter_page_opens_with_the_shipped_results_at_a_glance(seat: str) -> None:
    """The figures at the top of the page are the shipped held-out evaluation's: the effect in
    percent with its Holm p, partners better / equal / worse, the members' and the stand-ins'
    effects, and the known-partner headroom with the share realised; and the partners are said to
    be simulated."""
    comparison = json.loads((ROOT / "docs" / "eval" / "held-out" / seat / "comparison.json").read_text())
    default = SHIPPED.name
    test, best = comparison["tests"][default], comparison["best_static"]
    base, mean = comparison["agents"][best]["mean"], comparison["agents"][default]["mean"]
    text = (ROOT / "docs" / "adapter.md").read_text()
    glance = text[text.index("## Results at a glance") : text.index("## The grown library's agent")]
    said = re.sub(r"\s+", " ", glance)
    assert "Every partner in these figures is simulated" in said and "no data from people" in said
    [row] = [line for line in glance.splitlines() if line.startswith(f"| {seat}: {comparison['partners']} ")]
    percent = f"**{100 * test['mean_difference'] / base:+.1f} %**"
    assert f"{percent}: {mean:.3f} against {best}'s {base:.3f}" in row
    assert f"({test['mean_difference']:+.3f} ± {test['stderr']:.3f})" in row
    assert f"| {test['p_holm']:.1g} |" in row
    counts = test["per_partner"]
    assert f"| {counts['better']} / {counts['equal']} / {counts['worse']} |" in row
    members, people = (comparison["by_subset"][k][default] for k in ("members", "stand-ins"))
    assert f"{members['percent']:+.1f} %" in row and f"{people['percent']:+.1f} %" in row
    room = comparison["known_partner"]["all"]["percent"]
    assert f"{room:+.1f} %, {100 * test['headroom_realised']:.0f} % of it" in row
    assert percent.replace("*", "") in page("docs/index.md")
    readme = page("README.md")
    first_screen = readme[: readme.index("## Your first ten minutes")]  # the result in one sentence
    assert percent.replace("*", "") in first_screen and "every partner is simulated" in first_screen


def said_help(command: str) -> str:
    """`tsf COMMAND --help` as one line of text (the boxes' rules and the wrapping folded away)."""
    from typer.testing import CliRunner

    from services.commands.app import app

    return re.sub(r"[\s│]+", " ", CliRunner().invoke(app, [command, "--help"]).output)


def test_every_text_that_names_the_default_agent_names_the_shipped_one() -> None:
    """The default is the agent the command line plays (SHIPPED, the grown library's), never the
    study library's agent that was the default before it ("the default strategy" is both's); and no
    help text says adapting a seat does not pay, which the shipped agent's results contradict."""
    notebooks = [str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.py")]
    texts = {name: page(name) for name in [*PAGES, *notebooks]}
    texts |= {f"tsf {c} --help": said_help(c) for c in ("match", "play", "eval", "adapter", "keys")}
    default = re.compile(r"`?\**(adaptive-[\w.-]+)\**`?,? \(?(?:is )?the (?:shipped )?default\b(?! strategy)")
    named = {name: default.findall(text) for name, text in texts.items()}
    assert {name: wrong for name, names in named.items() if (wrong := set(names) - {SHIPPED.name})} == {}
    assert "does not pay" not in texts["tsf match --help"]


@pytest.mark.parametrize("seat", ["shooter", "bait"])
def test_the_held_out_figures_mark_the_shipped_agent_as_the_default(seat: str, tmp_path: Path) -> None:
    from services.evaluation import figures
    from services.evaluation.results import Comparison
    from shared.plots import drawn

    record = json.loads((ROOT / "docs" / "eval" / "held-out" / seat / "comparison.json").read_text())
    [fig] = drawn(lambda: figures.adaptive_vs_static(Comparison.of(record), tmp_path / "figure.png"))
    labels = [label.get_text() for label in fig.axes[0].get_yticklabels()]
    marked = SHIPPED.name.removeprefix(ADAPTIVE) + " (default)"
    assert [label for label in labels if "(default)" in label] == [marked]


def test_no_page_names_an_issue() -> None:
    """The pages speak the project's words: an issue number or 'the issue's bar' means nothing to a
    reader (an upstream project's issue, named with its project, is a reference)."""
    pages = [*PAGES, "CHANGELOG.md", *(str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.py"))]
    named = {
        name: re.findall(r"(?<!zenoh )\bissues? (?:\d+|'s)|\bthe issue\b", page(name), re.I) for name in pages
    }
    assert {name: found for name, found in named.items() if found} == {}


# --- the report's worked example ----------------------------------------------------------------------


def report_data(name: str) -> pd.DataFrame:
    return pd.read_csv(REPORT_DATA / f"{name}.csv", keep_default_na=False, na_values=[""])


def test_the_report_example_states_the_numbers_of_its_data(table: Table) -> None:
    text = page("docs/report.md")
    variants = report_data("variants")
    assert set(variants["kind"]) == {"agents only"} and set(variants["partner_role"]) == {"bait"}
    for row in variants.itertuples():
        assert f"| {row.variant} | {row.n} | {row.mean:.2f} ± {row.stderr:.2f} |" in text, row.variant
    [test] = report_data("adaptive_tests").itertuples()
    assert (
        f"the best static shooter, {test.static} (paired t = {test.t:.2f}, p = {test.p:.2g}, 9 partners)"
        in text
    )
    assert f"{test.mean_adaptive - test.mean_static:.1f} kills/min more" in text
    assert report_data("left_out").empty and "`data/left_out.csv` is empty" in text
    correlation = report_data("correlations").set_index(["kind", "partner_role"]).loc[("agents only", "bait")]
    p = re.sub(r"e-0(\d)", r"e-\1", f"{correlation.p:.1e}")  # as the page writes it: 2.5e-5
    assert f"r = {correlation.r:.2f}, p = {p}, n = {int(correlation.n)}" in text
    assert set(report_data("similarity")["optimal"]) == {table.best_bait("S4")}
    variance = report_data("policy_space_variance").set_index("role").loc["bait"]
    assert (
        f"PC1 explains {100 * variance.pc1:.0f} % of the variance and PC2 {100 * variance.pc2:.0f} %" in text
    )
    adapter = report_data("adapter")
    settled = adapter.groupby("match")["policy"].last()
    picks = [settled[f"st-B{i}-ad"] for i in range(1, 10)]
    assert f"({', '.join(picks)} for B1-B9)" in text
    assert picks == [table.best_shooter(f"B{i}") for i in range(1, 10)]


def test_the_report_figures_of_the_example_are_legible(tmp_path: Path) -> None:
    """The report's figures drawn from the example's data (45 points, nine partners in four matches
    each): no label overlaps another or is cut off."""

    def draw() -> None:
        figures.policy_space(report_data("policy_space"), report_data("policy_space_variance"),
                             tmp_path / "report_policy_space.png")  # fmt: skip
        figures.similarity(
            report_data("similarity"), report_data("correlations"), tmp_path / "report_similarity.png"
        )
        figures.variants(
            report_data("variants"), report_data("adaptive_tests"), tmp_path / "report_variants.png"
        )

    checked = legibility(draw)
    assert len(checked) == 3 and {name: p for name, p in checked.items() if p} == {}
    for name in checked:  # the shipped PNGs are these figures
        with Image.open(ROOT / "docs" / "figures" / name) as shipped, Image.open(tmp_path / name) as fresh:
            assert shipped.size == fresh.size


def test_the_library_page_states_the_search_s_measured_figures() -> None:
    """The search's table (docs/library.md) says what its records in docs/eval/search hold."""
    text = page("docs/library.md")
    for stem, row in (("shooter", "shooter"), ("bait", "bait"), ("bait-orbit", "bait, orbit")):
        measured = json.loads((ROOT / "docs" / "eval" / "search" / f"measured-{stem}.json").read_text())
        best = measured["best"]["all"]["name"]
        both = measured["measured"]["teammates"]["all"]["both"]
        assert f"| {row} | `{best}` |" in text
        assert f"{both['kills']:.2f} vs " in text and f"**{both['against'][0]['percent']:+.1f} %**" in text


# --- every block a reader is told to run ----------------------------------------------------------

# Every fenced bash or Python block of the README and docs/*.md, by its page and first line, is run
# here or by a named test, or says why it is not run (another machine, a person, hours of CPU). A new
# block fails test_every_block_is_run_or_says_why until it is placed here.
RUN_HERE = "run here"
ELSEWHERE = {  # run, as written or with fewer steps, by another test
    ("docs/env.md", "from services.agent import envs"): "test_the_env_page_examples_run",
    ("docs/env.md", "import gymnasium"): "test_the_env_page_examples_run",
    ("docs/library.md", "import gymnasium"): "services/agent/outside_test.py (fewer steps)",
    ("docs/library.md", "tsf game --bait my_bait.zip"): "tests/test_bring_your_own.py",
    ("docs/library.md", "TSF_LIBRARY=mylib tsf sweep"): "tests/test_bring_your_own.py",
    (
        "README.md",
        "scripts/match",
    ): ".ci/run (scripts/test, its first step); scripts/match: test_the_main_job_runs",
    ("README.md", "tsf sim --match m1"): "tests/test_match_processes.py",
    ("README.md", "docker compose up"): "tests/test_compose.py (CI's containers step)",
    ("README.md", "docker/install-engine"): "tests/test_compose.py (CI's containers step)",
    ("docs/recording.md", "import duckdb"): "services/recorder/export_test.py",
    ("docs/recording.md", "from pathlib import Path"): "services/recorder/export_test.py",
}
NOT_RUN = {
    ("README.md", ".venv/bin/python bench/engine.py"): "benchmarks: minutes each, figures for the pages",
    ("docs/human.md", "tsf play --role bait"): "waits for a person in a browser (tests/test_human_*.py)",
    ("docs/human.md", "tsf study services/study/configs/static.toml"): "serves people until stopped",
    ("docs/human.md", "openssl rand -hex 24 > dashboard.token"): "serves people until stopped",
    ("docs/humans.md", "tsf humans fit study/*.tsflog"): "needs a study's recordings of people",
    ("docs/jobs.md", "tsf sweep --workers 2"): "the whole table and evaluation: an hour; other machines",
    ("docs/jobs.md", "tsf workers up --count 8"): "needs Docker engines on other machines",
    ("docs/jobs.md", "ray start --head --port 6379"): "needs a Ray cluster (tests/test_ray.py)",
    ("docs/library.md", "tsf library grow --out tsf-grown"): "grows a library: hours of CPU",
    ("docs/library.md", "tsf sweep --workers 0 --connect"): "needs a router and other machines",
    ("docs/proxies.md", "tsf proxy train study/*.tsflog"): "needs a study's recordings of people",
    ("docs/proxies.md", "tsf eval --partners-from study/"): "needs a study's recordings of people",
    ("docs/proxies.md", "python bench/proxies.py"): "a benchmark: hours of CPU",
    ("docs/report.md", "i=0; for b in B1 B2 B3 B4 B5 B6 B7 B8 B9"): "36 one-minute matches: 6 minutes",
}
HERE = {
    ("README.md", "from services.sim.engine import Game"),
    ("README.md", "import gymnasium"),
    ("README.md", "from services.sim.batch import BatchGame"),
    ("docs/index.md", "scripts/match"),
    ("docs/adapter.md", "# my_lab/partners.py"),
}
# What a Python block takes as given (the README's sketches name the actions and policies they play).
GIVEN = {
    "from services.sim.engine import Game": "bait_action = shooter_action = 2\n",
    "from services.sim.batch import BatchGame": (
        "import numpy as np\nfrom services.agent.seats import policy_for\n"
        "bait_actions = shooter_actions = np.full(1024, 2)\n"
        "bait_policy, shooter_policy = policy_for('B5', 'bait'), policy_for('S5', 'shooter')\n"
        "partner_policy = shooter_policy\n"
    ),
}


def blocks() -> dict[tuple[str, str], tuple[str, str]]:
    """Every fenced bash or Python block of the pages: (page, first line) -> (language, text)."""
    found = {}
    for name in PAGES:
        for language, text in re.findall(r"```(bash|python)\n(.*?)```", (ROOT / name).read_text(), re.S):
            text = textwrap.dedent(text)
            first = re.sub(r"\s+#.*", "", text.strip().splitlines()[0]).strip() or text.splitlines()[0]
            found[(name, first)] = (language, text)
    return found


def placed(block: tuple[str, str]) -> bool:
    return block in HERE or any(block[0] == p and block[1].startswith(f) for p, f in (*ELSEWHERE, *NOT_RUN))


def test_every_block_is_run_or_says_why() -> None:
    assert [block for block in blocks() if not placed(block)] == []
    assert [block for block in HERE if block not in blocks()] == []  # the pages still show them
    elsewhere = {where.split(" ")[0] for where in ELSEWHERE.values() if "/" in where.split(" ")[0]}
    assert [path for path in elsewhere if not (ROOT / path).exists()] == []


@pytest.mark.parametrize("block", sorted(b for b in HERE if b[1] in GIVEN or b[1] == "import gymnasium"))
def test_the_readmes_python_runs(
    block: tuple[str, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    _, text = blocks()[block]
    exec(compile(GIVEN.get(block[1], "") + text, f"{block[0]}: {block[1]}", "exec"), {})  # noqa: S102


def tsf_command(line: str) -> list[str]:
    """A documented command as this environment runs it: `.venv/bin/tsf` is this Python's `tsf`."""
    return [str(Path(sys.executable).with_name("tsf")), *line.split()[1:]]


def test_the_start_here_commands_run() -> None:
    """docs/index.md's `tsf --help` and `tsf --version`; its first line, scripts/match, is the
    README's too and plays a one-minute match: test_the_main_job_runs (long)."""
    _, text = blocks()[("docs/index.md", "scripts/match")]
    lines = [re.sub(r"\s+#.*", "", line).strip() for line in text.strip().splitlines()]
    assert lines[0] == "scripts/match" and all(line.startswith(".venv/bin/tsf ") for line in lines[1:])
    for line in lines[1:]:
        run = subprocess.run(tsf_command(line), capture_output=True, text=True, timeout=120)
        assert run.returncode == 0 and run.stdout, line


@pytest.mark.slow
@pytest.mark.long
def test_the_main_job_runs(tmp_path: Path) -> None:
    """scripts/match as it runs after its set-up: the one-minute adaptive match of B5 with the
    adaptive shooter (its default arguments, read from the script)."""
    script = (ROOT / "scripts" / "match").read_text()
    arguments = re.search(r"set -- (.+)", script)[1]
    assert 'tsf match "$@"' in script
    run = subprocess.run(
        tsf_command(f"tsf match {arguments}"), capture_output=True, text=True, timeout=300, cwd=tmp_path
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "kills" in run.stdout and list((tmp_path / "recordings").glob("*.tsflog"))


def bring_your_own_partner(tmp_path: Path) -> str:
    """The adapter page's partner written where the page says (`my_lab/partners.py` in the directory
    where `tsf` runs); the key its command names."""
    _, code = blocks()[("docs/adapter.md", "# my_lab/partners.py")]
    (tmp_path / "my_lab").mkdir()
    (tmp_path / "my_lab" / "partners.py").write_text(code)
    [key] = re.findall(r"`tsf eval --partner (my_lab\S+)`", page("docs/adapter.md"))
    return key


def test_the_bring_your_own_partner_loads_by_the_key_the_page_names(tmp_path: Path) -> None:
    key = bring_your_own_partner(tmp_path)
    run = subprocess.run(
        tsf_command(f"tsf game --bait {key} --shooter S5 --games 1 --duration 5"),
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr


@pytest.mark.slow
@pytest.mark.long
def test_the_bring_your_own_partner_is_evaluated_as_documented(tmp_path: Path) -> None:
    """`tsf eval --partner my_lab.partners:Alice`, as the page writes it (one seed, no identification,
    to keep it short): a table and a figure."""
    key = bring_your_own_partner(tmp_path)
    command = f"tsf eval --partner {key} --seeds 1 --no-identify --workers 1 --out eval"
    run = subprocess.run(tsf_command(command), capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    assert (tmp_path / "eval" / "team.csv").exists() and (
        tmp_path / "eval" / "adaptive_vs_static.png"
    ).exists()
    summary = (tmp_path / "eval" / "summary.md").read_text()  # Alice scores with no one: a result
    assert "No agent scores with 1 of the 1 partners" in summary and "not defined" in summary


def test_the_docs_site_works_from_a_file_and_serves_on_a_port_of_its_own() -> None:
    """Opened as the file the build prints, a link lands on a page, not a directory listing; search
    works offline; `scripts/docs serve` takes none of the ports `tsf play` and `tsf study` take and
    shows the notebooks unexecuted (the build, and CI, execute them); a notebook links its source."""
    from services.human.gateway import Web

    config = (ROOT / "mkdocs.yml").read_text()
    assert "\nuse_directory_urls: false\n" in config and "\n  - offline\n" in config
    assert "execute: !ENV [TSF_DOCS_EXECUTE, true]" in config and "include_source: true" in config
    script = (ROOT / "scripts" / "docs").read_text()
    port = int(re.search(r"--dev-addr \"127.0.0.1:\$\{TSF_DOCS_PORT:-(\d+)\}\"", script)[1])
    assert port != Web().port and "export TSF_DOCS_EXECUTE=false" in script
    assert "page.nb_url" in (ROOT / "docs" / "overrides" / "main.html").read_text()
