"""The layer map of docs/architecture.md, checked for every file of services/ and shared/.

The table is read from that page, so the page and the check cannot drift apart. Every import
counts, at any depth: an import inside a function goes to the same or a lower layer like any
other, no modules import each other in a circle, and outside the command line an import inside a
function is one of the reasoned ones below (a heavy or optional package), never a way to hide a
circle. The pure cores import no bus code. Tests (`*_test.py`) may cross layers.
"""

import ast
import re
from fnmatch import fnmatch
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs/architecture.md"
PURE_CORES = (
    "services/sim/engine.py",
    "services/sim/observation.py",
    "services/sim/match.py",
    "services/sim/play.py",
    "services/agent/player.py",
    "services/agent/gate.py",
    "services/adapter/core.py",
    "services/human/core.py",
    "services/study/core.py",
    "services/table/table.py",
    "services/jobs/core.py",
)
BUS = ("zenoh", "shared.bus")
COMMAND_LINE = "command line"  # the layer that imports inside functions freely: a command loads what it runs
LAZY_PACKAGES = {  # outside the command line, the packages an import inside a function may load, and why
    "numba": "compiled code loads only when something is compiled (services/sim/jit.py)",
    "torch": "the `train` extra",
    "stable_baselines3": "the `train` extra: reading an SB3 .zip",
    "ray": "the `ray` extra",
    "optuna": "the `search` extra: only the growth's search asks it (services/growth/search.py)",
    "docker": "the Docker SDK: only `tsf workers` needs it",
    "matplotlib": "figures: seconds to import, and only a figure needs it",
    "scipy": "statistics: slow to import, and only the evaluation's tests need it",
    "PIL": "video and GIF replays only",
    "imageio_ffmpeg": "video replays only",
    "gymnasium": "gymnasium imports agent/envs.py as its plug-in while it imports itself (a circle not ours)",
    "pettingzoo": "the multi-agent env only",
}
BULK = "bulk play only: numba loads with it"
MADE_ENV = "gymnasium loads agent/envs.py as its plug-in: only a made env loads policies and the engine"
LAZY_MODULES = {  # (file, project module): an import inside a function outside the command line, and why
    ("services/evaluation/evaluate.py", "services.sim.batch"): BULK,
    ("services/evaluation/evaluate.py", "services.sim.batch_play"): BULK,
    ("services/table/table.py", "services.sim.batch_play"): BULK + " (the table's readers never load it)",
    ("services/agent/envs.py", "services.agent.library"): MADE_ENV,
    ("services/agent/envs.py", "services.agent.seats"): MADE_ENV,
    ("services/agent/envs.py", "services.sim.env"): MADE_ENV,
    ("services/agent/envs.py", "services.sim.vec_env"): MADE_ENV,
    ("services/proxy/__init__.py", "services.proxy.train"): "the `train` extra (torch), one line if missing",
}


def layer_table() -> list[tuple[str, list[str]]]:
    """(layer, file patterns) of the page's table, top first."""
    text = DOC.read_text().split("## Layers", 1)[1].split("\n## ", 1)[0]
    rows = [line.split("|") for line in text.splitlines() if line.startswith("| ") and "`" in line]
    return [(cells[1].strip(), re.findall(r"`([^`]+)`", cells[2])) for cells in rows]


TABLE = layer_table()
LAYERS = [name for name, _ in TABLE]


def files() -> list[Path]:
    paths = [*(ROOT / "services").rglob("*.py"), *(ROOT / "shared").rglob("*.py")]
    return sorted(p for p in paths if not p.name.endswith("_test.py"))


def relative(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def layer_of(path: str) -> str | None:
    """The highest layer one of whose patterns matches (`*` within one folder)."""
    for name, patterns in TABLE:
        if any(fnmatch(path, pattern) and pattern.count("/") == path.count("/") for pattern in patterns):
            return name
    return None


def module_file(name: str) -> str | None:
    """The project file a dotted module name is, or None (an attribute, or not the project's)."""
    base = ROOT.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return relative(path)
    return None


def imports(path: Path) -> list[tuple[str, bool]]:
    """(module name, inside a function) of every import of a file, at any depth; `from P import m`
    imports the module P.m where m is one, else P."""
    tree = ast.parse(path.read_text(), str(path))
    local = {
        id(node)
        for function in ast.walk(tree)
        if isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef)
        for node in ast.walk(function)
    }
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, id(node) in local) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            subs = [f"{node.module}.{alias.name}" for alias in node.names]
            modules = [name for name in subs if module_file(name)]
            found += [(name, id(node) in local) for name in modules or [node.module]]
    return found


def edges() -> dict[str, set[str]]:
    """Every project file's project imports, as files."""
    out = {}
    for path in files():
        targets = {module_file(name) for name, _ in imports(path)}
        out[relative(path)] = {t for t in targets if t and t != relative(path)}
    return out


def test_every_file_is_on_a_layer():
    assert LAYERS[0] == COMMAND_LINE and len(LAYERS) == len(set(LAYERS)) >= 8
    assert [relative(p) for p in files() if layer_of(relative(p)) is None] == []


def test_each_layer_is_folders_not_files():
    """A row names folders (`services/adapter/*`) or a family of files (`services/*.py`), never
    one file: a file placed on another layer than its folder's is a folder that is not one layer."""
    single = [
        pattern for _, patterns in TABLE for pattern in patterns if not any(c in pattern for c in "*?[")
    ]
    assert single == []


def test_no_file_imports_from_a_layer_above_its_own():
    upward = [
        f"{source} ({layer_of(source)}) imports {target} ({layer_of(target)})"
        for source, targets in edges().items()
        for target in sorted(targets)
        if LAYERS.index(layer_of(target)) < LAYERS.index(layer_of(source))
    ]
    assert upward == []


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one file (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_no_modules_import_each_other_in_a_circle():
    assert circles(edges()) == []


def folder(path: str) -> str:
    """A file's folder as the layer table names it: `services/adapter`, `shared`, `services`."""
    return path.rsplit("/", 1)[0]


def folder_edges() -> dict[str, set[str]]:
    """The import graph folder by folder: an arrow from one folder to another where a file of the
    first imports a file of the second."""
    out: dict[str, set[str]] = {}
    for source, targets in edges().items():
        out.setdefault(folder(source), set()).update(
            folder(t) for t in targets if folder(t) != folder(source)
        )
    return out


@pytest.mark.slow
@pytest.mark.long  # 15 s or more in the full run: kept out of the default run
def test_folders_import_only_downward_and_never_each_other():
    """The house drawn folder by folder: each folder is on one layer, no arrow runs back up, no two
    folders import each other, and there is no circle of folders however long."""
    graph = folder_edges()
    spread = {f: {layer_of(p) for p in edges() if folder(p) == f} for f in graph}
    assert {f: layers for f, layers in spread.items() if len(layers) != 1} == {}
    rank = {f: LAYERS.index(layers.pop()) for f, layers in spread.items()}
    upward = [f"{a} -> {b}" for a, targets in graph.items() for b in sorted(targets) if rank[b] < rank[a]]
    mutual = sorted(
        {tuple(sorted((a, b))) for a, targets in graph.items() for b in targets if a in graph.get(b, ())}
    )
    assert (upward, mutual, circles(graph)) == ([], [], [])


def test_imports_inside_functions_have_a_reason():
    unexplained = []
    for path in files():
        source = relative(path)
        if layer_of(source) == COMMAND_LINE:
            continue
        for name, inside in imports(path):
            if not inside:
                continue
            if module_file(name):
                explained = any(
                    source == f and (name == m or name.startswith(m + ".")) for f, m in LAZY_MODULES
                )
            else:
                explained = name.split(".")[0] in LAZY_PACKAGES
            if not explained:
                unexplained.append(f"{source} imports {name} inside a function")
    assert unexplained == []


@pytest.mark.parametrize("core", PURE_CORES)
def test_pure_cores_import_no_bus_code(core):
    names = [name for name, _ in imports(ROOT / core)]
    assert [n for n in names if any(n == b or n.startswith(b + ".") for b in BUS)] == []


def test_the_checks_see_imports_inside_functions_and_circles(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("def f():\n    from services.agent import library\n    import numba\n")
    assert imports(sample) == [("services.agent.library", True), ("numba", True)]
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert (
        layer_of("services/commands/adapter.py") == COMMAND_LINE
        and layer_of("services/adapter/core.py") == "adapter"
    )


MOST_LINES = 80  # a function a reader takes in at once; a Typer command's options are types (Annotated)


def long_functions(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    return [
        f"{relative(path)}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and node.end_lineno - node.lineno + 1 > MOST_LINES
    ]


def test_no_function_is_longer_than_a_reader_takes_in():
    assert [long for path in files() for long in long_functions(path)] == []
