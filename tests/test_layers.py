"""The package's architecture, checked: one-way imports between layers, no import circles, and
modules and functions small enough to read.

The layers, lowest first (each may import only the layers before it; ``factors`` only the
model and the front end's maths):

    model -> io -> frontend -> calibration -> simulation -> factors -> estimation
          -> evaluation -> apcc_graph (the lazy facade) -> bench -> plots -> cli

Every import counts, including those inside functions and under ``TYPE_CHECKING``: a lazy
import hides a circle from the interpreter, not from a reader. The facade's lazy exports
(``apcc_graph._EXPORTS``) count as imports of the facade.
"""

from __future__ import annotations

import ast
import io
import tokenize
from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Folders of the repository and the package each installs as: ``factors/`` stays at the top of
#: the repository and installs as ``apcc_graph.factors`` (``apcc_graph/factors`` links to it).
PACKAGES = (("apcc_graph", "apcc_graph"), ("factors", "apcc_graph.factors"))

#: The layers, lowest first: (name, module prefixes). A module belongs to the layer of its
#: longest matching prefix.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("model", ("apcc_graph.model",)),
    ("io", ("apcc_graph.io",)),
    ("frontend", ("apcc_graph.frontend",)),
    ("calibration", ("apcc_graph.calibration",)),
    ("simulation", ("apcc_graph.simulation",)),
    ("factors", ("apcc_graph.factors",)),
    ("estimation", ("apcc_graph.estimation",)),
    ("evaluation", ("apcc_graph.evaluation",)),
    ("facade", ("apcc_graph",)),
    ("bench", ("apcc_graph.bench",)),
    ("plots", ("apcc_graph.plots",)),
    ("cli", ("apcc_graph.cli",)),
)

#: Layers whose imports are narrower than "everything below".
ONLY: Mapping[str, frozenset[str]] = {"factors": frozenset({"model", "frontend"})}

#: Size limits: lines per module, and lines per function without its docstring. A longer
#: function says why in a ``# Long:`` comment among its first lines.
MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 60


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the package, by dotted name (a package by its own name)."""
    found = {}
    for folder, package in PACKAGES:
        for path in sorted((root / folder).rglob("*.py")):
            if (root / "apcc_graph" / "factors") in path.parents and folder == "apcc_graph":
                continue  # the link to factors/, walked as its own folder
            parts = path.relative_to(root / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join((package, *parts))] = path
    return found


def _imported(node: ast.Import | ast.ImportFrom, module: str, is_package: bool) -> list[str]:
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - node.level + 1]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    # ``from package import name``: the submodule ``package.name`` if there is one, else the
    # package (the caller keeps the longest prefix that is a module).
    return [f"{target}.{alias.name}" for alias in node.names]


def _facade_exports(tree: ast.Module) -> list[str]:
    for node in tree.body:
        if (isinstance(node, ast.AnnAssign | ast.Assign) and isinstance(node.value, ast.Dict)
                and "_EXPORTS" in ast.unparse(node)):
            return [ast.literal_eval(value) for value in node.value.values]
    return []


def import_graph(files: Mapping[str, Path]) -> dict[str, set[str]]:
    """Module -> the package modules it imports (the longest existing prefix of each name)."""
    graph: dict[str, set[str]] = {}
    for module, path in files.items():
        tree = ast.parse(path.read_text(), str(path))
        names = _facade_exports(tree) if module == "apcc_graph" else []
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                names += _imported(node, module, path.name == "__init__.py")
        targets = set()
        for name in names:
            while name and name not in files:
                name = name.rpartition(".")[0]
            if name and name != module:
                targets.add(name)
        graph[module] = targets
    return graph


def layer_of(module: str) -> int:
    """Index in :data:`LAYERS` of the module's layer (the longest matching prefix)."""
    best, best_length = -1, -1
    for index, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_length:
                best, best_length = index, len(prefix)
    if best < 0:
        raise AssertionError(f"{module} belongs to no layer: add it to LAYERS")
    return best


def layer_violations(graph: Mapping[str, Iterable[str]]) -> list[str]:
    """Imports of a higher layer, or outside a layer's narrower allowance."""
    bad = []
    for module, targets in graph.items():
        own = layer_of(module)
        name = LAYERS[own][0]
        for target in targets:
            other = layer_of(target)
            if other == own:
                continue
            allowed = other < own and (name not in ONLY or LAYERS[other][0] in ONLY[name])
            if not allowed:
                bad.append(f"{module} ({name}) imports {target} ({LAYERS[other][0]})")
    return sorted(bad)


def import_circles(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(circles)


def _comments(source: str) -> dict[int, str]:
    tokens = tokenize.generate_tokens(io.StringIO(source).readline)
    return {tok.start[0]: tok.string for tok in tokens if tok.type == tokenize.COMMENT}


def long_functions(path: Path, limit: int = MAX_FUNCTION_LINES,
                   root: Path = ROOT) -> list[tuple[str, int]]:
    """Functions of ``path`` longer than ``limit`` lines (docstring excluded) with no
    ``# Long:`` reason among their first lines, as ``(name:line, length)``."""
    source = path.read_text()
    comments = _comments(source)
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        length = node.end_lineno - node.lineno + 1
        body = node.body
        if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
            length -= body[0].end_lineno - body[0].lineno + 1
        reason = any(comments.get(line, "").startswith("# Long:")
                     for line in range(node.lineno, body[0].lineno + 4))
        if length > limit and not reason:
            found.append((f"{path.relative_to(root)}:{node.lineno} {node.name}", length))
    return found


FILES = module_files()
GRAPH = import_graph(FILES)


def test_every_module_has_a_layer_and_every_subpackage_says_what_it_may_import() -> None:
    for module, path in FILES.items():
        layer_of(module)
        if path.name == "__init__.py" and module != "apcc_graph":
            doc = ast.get_docstring(ast.parse(path.read_text())) or ""
            assert "import" in doc.lower(), f"{path}: the docstring must say what it may import"


def test_no_import_circles() -> None:
    assert import_circles(GRAPH) == []


def test_imports_run_one_way_down_the_layers() -> None:
    assert layer_violations(GRAPH) == []


def test_the_checks_fail_on_an_upward_import_and_on_a_circle() -> None:
    graph = {module: set(targets) for module, targets in GRAPH.items()}
    graph["apcc_graph.model.segment"].add("apcc_graph.estimation.batch")
    assert sorted(set(layer_violations(graph)) - set(layer_violations(GRAPH))) == [
        "apcc_graph.model.segment (model) imports apcc_graph.estimation.batch (estimation)"]
    assert any("apcc_graph.model.segment" in circle for circle in import_circles(graph))
    graph = {module: set(targets) for module, targets in GRAPH.items()}
    graph["apcc_graph.factors.projection"].add("apcc_graph.simulation.simulator")
    assert sorted(set(layer_violations(graph)) - set(layer_violations(GRAPH))) == [
        "apcc_graph.factors.projection (factors) imports apcc_graph.simulation.simulator "
        "(simulation)"]


def test_the_import_reader_sees_lazy_relative_and_facade_imports(tmp_path: Path) -> None:
    (tmp_path / "apcc_graph" / "model").mkdir(parents=True)
    (tmp_path / "factors").mkdir()
    facade = '_EXPORTS = {"Segment": "apcc_graph.model.a"}\n'
    (tmp_path / "apcc_graph" / "__init__.py").write_text(facade)
    (tmp_path / "apcc_graph" / "model" / "__init__.py").write_text("from . import a\n")
    (tmp_path / "apcc_graph" / "model" / "a.py").write_text("def f():\n    from .b import g\n")
    (tmp_path / "apcc_graph" / "model" / "b.py").write_text("import apcc_graph.factors.c\n")
    (tmp_path / "factors" / "__init__.py").write_text("")
    (tmp_path / "factors" / "c.py").write_text("from apcc_graph.model import a\n")
    graph = import_graph(module_files(tmp_path))
    assert graph["apcc_graph"] == {"apcc_graph.model.a"}
    assert graph["apcc_graph.model"] == {"apcc_graph.model.a"}
    assert graph["apcc_graph.model.a"] == {"apcc_graph.model.b"}
    assert graph["apcc_graph.model.b"] == {"apcc_graph.factors.c"}
    assert graph["apcc_graph.factors.c"] == {"apcc_graph.model.a"}
    assert import_circles(graph) == [["apcc_graph.factors.c", "apcc_graph.model.a",
                                     "apcc_graph.model.b"]]


@pytest.mark.parametrize("module", sorted(FILES))
def test_module_size(module: str) -> None:
    lines = FILES[module].read_text().count("\n")
    assert lines <= MAX_MODULE_LINES, f"{FILES[module]}: {lines} lines (at most {MAX_MODULE_LINES})"


@pytest.mark.parametrize("module", sorted(FILES))
def test_function_size(module: str) -> None:
    assert long_functions(FILES[module]) == []


def test_the_function_size_check_counts_code_not_docstrings(tmp_path: Path) -> None:
    body = "".join(f"    x{i} = {i}\n" for i in range(61))
    doc = '    """' + "\n" * 30 + '    """\n'
    (tmp_path / "m.py").write_text(f"def long():\n{doc}{body}\ndef short():\n{doc}    return 1\n"
                                   f"def excused():\n    # Long: a table of cases\n{body}")
    # 62 lines of code: the ``def`` line and 61 statements; the docstring does not count.
    assert long_functions(tmp_path / "m.py", root=tmp_path) == [("m.py:1 long", 62)]


def summary() -> str:
    """The figures of the layout: modules per subpackage, the largest module and function, and
    the number of import circles (``python tests/test_layers.py``)."""
    counts: dict[str, int] = {}
    for module in FILES:
        parts = module.split(".")
        package = ".".join(parts[:2]) if parts[0] == "apcc_graph" and len(parts) > 2 else (
            module if FILES[module].name == "__init__.py" else ".".join(parts[:-1]) or module)
        counts[package] = counts.get(package, 0) + 1
    sizes = {module: path.read_text().count("\n") for module, path in FILES.items()}
    largest = max(sizes, key=sizes.__getitem__)
    functions = [row for path in FILES.values() for row in long_functions(path, limit=0)]
    name, length = max(functions, key=lambda row: row[1])
    lines = [f"{package:28s} {count:3d} modules" for package, count in sorted(counts.items())]
    lines += [f"largest module: {largest} ({sizes[largest]} lines)",
              f"largest function: {name} ({length} lines without its docstring)",
              f"import circles: {len(import_circles(GRAPH))}",
              f"upward imports: {len(layer_violations(GRAPH))}"]
    return "\n".join(lines)


if __name__ == "__main__":
    print(summary())
