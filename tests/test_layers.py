"""The package's layers point down (docs/development.md#layers): a module imports modules of its
own layer or of the layers below, never above, and no group of modules imports itself
around a cycle. Every import counts, the ones inside functions too (a lazy import is still
a dependency); imports under ``if TYPE_CHECKING:`` do not (they never run).

The few imports that still break the rules are listed below, each with why it is there:
a new one fails the test, and removing one fails it too, until it is taken off the list."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "strauss_fit"

#: The layers, bottom to top, and the modules of each (by dotted prefix inside the
#: package; the longest matching prefix decides). "" is the package's face.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "core",
        (
            "_version",
            "_environment",
            "_escaping",
            "_host_methods",
            "errors",
            "numerics",
            "precision",
            "color",
            "io.files",
            "io.images",
            "io.table_formats",
            "engine",
            "export_cache",
            "runtime",
        ),
    ),
    ("models", ("models",)),
    ("scene", ("scene", "capture", "io")),
    ("render", ("rendering",)),
    ("stats", ("stats",)),
    ("fit", ("fitting",)),
    ("inference", ("inference",)),
    ("top", ("study", "reporting", "convert")),
    ("face", ("",)),
)

#: Imports that point up today, and why they are still there (none).
KNOWN_UPWARD: set[tuple[str, str]] = set()
#: Import cycles today, and why (none).
KNOWN_CYCLES: set[tuple[str, ...]] = set()


def _modules() -> dict[str, Path]:
    found = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    skipped = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for statement in node.body:
                skipped.update(id(inner) for inner in ast.walk(statement))
    return skipped


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The package's modules that module ``name`` imports (names relative to the package)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skipped = _type_checking_nodes(tree)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    package = [p for p in package if p]
    found = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            elif node.module and (node.module == "strauss_fit" or node.module.startswith("strauss_fit.")):
                target = node.module[len("strauss_fit") :].lstrip(".")
            else:
                continue
            for alias in node.names:
                candidate = f"{target}.{alias.name}".lstrip(".")
                found.add(candidate if candidate in modules else target)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "strauss_fit" or alias.name.startswith("strauss_fit."):
                    found.add(alias.name[len("strauss_fit") :].lstrip("."))
    return {m for m in found if m in modules and m != name}


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def layer_of(module: str) -> int:
    best = None
    for index, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if module == prefix or module.startswith(prefix + ".") or (prefix == "" and module == ""):
                if best is None or len(prefix) > best[1]:
                    best = (index, len(prefix))
    assert best is not None, f"strauss_fit.{module} belongs to no layer: add it to LAYERS"
    return best[0]


def _cycles(graph: dict[str, set[str]]) -> set[tuple[str, ...]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: set[tuple[str, ...]] = set()

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for successor in graph[node]:
            if successor not in index:
                visit(successor)
                low[node] = min(low[node], low[successor])
            elif successor in on_stack:
                low[node] = min(low[node], index[successor])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.add(tuple(sorted(component)))

    for node in graph:
        if node not in index:
            visit(node)
    return found


def test_the_import_graph_is_read_correctly():
    """The reader finds imports of every form: relative, absolute, lazy, aliased."""
    graph = _graph()
    assert "fitting.problem" in graph["fitting.solvers"]  # from .problem import ...
    assert "engine" in graph["fitting.solvers"]  # from ..engine import ...
    assert "io.table_formats" in graph["io.material_tables"]
    assert "fitting.batch" in graph["fitting.executors"]
    assert (
        layer_of("inference.sampler")
        > layer_of("fitting.api")
        > layer_of("stats.laplace")
        > layer_of("rendering.strauss")
        > layer_of("errors")
    )


def test_imports_point_down_the_layers():
    graph = _graph()
    upward = {
        (module, target)
        for module, targets in graph.items()
        for target in targets
        if layer_of(target) > layer_of(module)
    }
    named = {LAYERS[layer_of(m)][0] + " -> " + LAYERS[layer_of(t)][0] + f": {m} -> {t}" for m, t in upward}
    assert upward - KNOWN_UPWARD == set(), f"imports pointing up the layers: {sorted(named)}"
    assert KNOWN_UPWARD - upward == set(), f"no longer pointing up, take off KNOWN_UPWARD: {KNOWN_UPWARD - upward}"


def test_no_import_cycles():
    cycles = _cycles(_graph())
    assert cycles - KNOWN_CYCLES == set(), f"import cycles: {sorted(cycles - KNOWN_CYCLES)}"
    assert KNOWN_CYCLES - cycles == set(), f"gone, take off KNOWN_CYCLES: {KNOWN_CYCLES - cycles}"
