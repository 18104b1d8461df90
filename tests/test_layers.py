"""The layer rule of docs/architecture.md, checked by walking every module's imports.

shared/game.py (the game's vocabulary) imports nothing of the project; shared/ (the contract)
imports no service; the engine's package, services/sim, imports no other service; the pure cores
import no bus code. Tests may cross layers to test them together, so `*_test.py` files are exempt.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PURE_CORES = (
    "services/sim/engine.py",
    "services/sim/observation.py",
    "services/sim/match.py",
    "services/sim/play.py",
    "services/agent/player.py",
    "services/adapter/core.py",
    "services/human/core.py",
    "services/study/core.py",
    "services/table/table.py",
    "services/jobs/core.py",
)
BUS = ("zenoh", "shared.bus")


def modules(folder: str) -> list[Path]:
    return sorted(p for p in (ROOT / folder).rglob("*.py") if not p.name.endswith("_test.py"))


def imports(path: Path) -> set[str]:
    """Every module name a file imports, at any depth (function-local imports included)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def under(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def offending(paths: list[Path], forbidden) -> list[str]:
    return [
        f"{path.relative_to(ROOT)} imports {name}"
        for path in paths
        for name in sorted(imports(path))
        if forbidden(name)
    ]


def test_the_vocabulary_imports_nothing_of_the_project():
    project = ("services", "shared", "bench", "tests")
    assert offending([ROOT / "shared/game.py"], lambda n: any(under(n, p) for p in project)) == []


def test_the_contract_imports_no_service():
    assert offending(modules("shared"), lambda n: under(n, "services")) == []


def test_the_engine_imports_no_other_service():
    def elsewhere(name: str) -> bool:
        return under(name, "services") and not under(name, "services.sim")

    assert offending(modules("services/sim"), elsewhere) == []


@pytest.mark.parametrize("core", PURE_CORES)
def test_pure_cores_import_no_bus_code(core):
    assert offending([ROOT / core], lambda n: any(under(n, b) for b in BUS)) == []


def test_the_walker_sees_imports_inside_functions(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("def f():\n    from services.agent import library\n")
    assert "services.agent" in imports(sample) and "services.agent.library" in imports(sample)
