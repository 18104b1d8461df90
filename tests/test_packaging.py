"""An installed wheel carries every data file the code reads (the library, the web client, the study
configs): each one in the source tree is declared package data in pyproject.toml. Without that, a
`pip install .` outside the checkout installs a project with no library."""

import fnmatch
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
