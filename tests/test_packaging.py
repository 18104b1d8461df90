"""An installed wheel carries every data file the code reads (the library, the web client, the study
configs): each one in the source tree is declared package data in pyproject.toml. Without that, a
`pip install .` outside the checkout installs a project with no library."""

import fnmatch
import re
import subprocess
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def tracked_data_files() -> list[str]:
    """The files of the packages that are not Python, as git tracks them (no run's leftovers)."""
    try:
        listed = subprocess.run(
            ["git", "ls-files", "services", "shared"], cwd=ROOT, capture_output=True, text=True, check=True
        )
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [
        f for f in listed.stdout.splitlines() if not f.endswith(".py") and not Path(f).name.startswith(".")
    ]


def test_every_data_file_of_the_packages_is_package_data():
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]

    def declared_for(path: str) -> bool:
        for package, patterns in declared.items():
            prefix = package.replace(".", "/") + "/"
            if path.startswith(prefix) and any(fnmatch.fnmatch(path[len(prefix) :], p) for p in patterns):
                return True
        return False

    files = tracked_data_files()
    assert "services/agent/library/registry.toml" in files
    assert [f for f in files if not declared_for(f)] == []


# What each extra brings that a test may import (pyproject.toml's optional dependencies, by module).
EXTRA_MODULES = {
    "train": ("stable_baselines3", "sb3_contrib", "torch", "tqdm"),
    "ray": ("ray",),
    "search": ("optuna",),
    "docs": ("mkdocs", "mkdocstrings", "jupytext", "yaml", "build", "twine"),
}
SKIP = re.compile(r"""importorskip\(\s*["']([\w.]+)["'](?:,\s*reason=["']([^"']*)["'])?""")


def test_a_test_that_needs_an_extra_skips_naming_it() -> None:
    """`scripts/test` as the README writes it installs no extra: a test that needs one skips, and its
    reason names the extra (`the `train` extra is not installed`), which is also how .ci/run finds the
    tests to run again once the extras are in."""
    extra_of = {module: extra for extra, modules in EXTRA_MODULES.items() for module in modules}
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert set(EXTRA_MODULES) <= set(extras)
    files = [  # the test files (a glob from the root would walk .venv too)
        *ROOT.glob("tests/test_*.py"),
        *ROOT.glob("services/**/*_test.py"),
        *ROOT.glob("shared/*_test.py"),
    ]
    wrong = {}
    for path in files:
        for module, reason in SKIP.findall(path.read_text()):
            extra = extra_of.get(module.split(".")[0])
            if extra and reason != f"the `{extra}` extra is not installed":
                wrong[f"{path.relative_to(ROOT)}: {module}"] = reason
    assert wrong == {}
