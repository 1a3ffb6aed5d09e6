"""The shape of the code base: layers, no import cycles, functions a reader can hold in mind.

Layers (DESIGN.md §5): a module may import only modules of its own or a lower layer, at
module level or inside a function, without exception. Within a layer the import graph of
the modules has no cycle either (strongly connected components, Tarjan).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "transcalib"

#: Layer of each top-level module or package of transcalib (lower imports nothing higher).
LAYERS = {
    "errors": 0,
    "geometry": 1,
    "types": 2, "validate": 2,
    "estimate": 3,
    "check": 4,
    "synth": 5, "images": 5, "handeye": 5, "planning": 6,
    "pipeline": 6, "dense": 6,
    "io": 7, "report": 7,
    "cli": 8, "__main__": 8, "__init__": 8,
}
MAX_BODY_LINES = 80


def _modules():
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC)
        yield path, rel.parts[0].removesuffix(".py"), ".".join(("transcalib",) + rel.with_suffix("").parts)


def _imports(path: Path, dotted: str):
    """Absolute names of the transcalib modules imported by ``path`` (anywhere in it)."""
    package = dotted if path.name == "__init__.py" else dotted.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if name.startswith("transcalib"):
                yield name, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("transcalib"):
                    yield a.name, []


def _top(name: str) -> str:
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_module_has_a_layer():
    missing = {top for _, top, _ in _modules()} - set(LAYERS)
    assert not missing, f"add these to LAYERS: {missing}"


def test_lower_layers_never_import_higher_ones():
    bad = []
    for path, top, dotted in _modules():
        for name, names in _imports(path, dotted):
            targets = [_top(name)] if _top(name) != "__init__" else [n for n in names if n in LAYERS] or ["__init__"]
            for target in targets:
                if target in LAYERS and LAYERS[target] > LAYERS[top]:
                    bad.append(f"{dotted} imports {name}")
    assert not bad, "\n".join(bad)


def _import_graph() -> dict[str, set[str]]:
    """Module -> the transcalib modules it imports anywhere (a package is its ``__init__``;
    ``from pkg import name`` names ``pkg.name`` when that is a submodule, else ``pkg``)."""
    modules = {dotted: path for path, _, dotted in _modules()}
    package_of = {dotted.removesuffix(".__init__"): dotted for dotted in modules}
    graph = {}
    for dotted, path in modules.items():
        edges = set()
        for name, names in _imports(path, dotted.removesuffix(".__init__")
                                    if path.name == "__init__.py" else dotted):
            subs = [f"{name}.{n}" for n in names if f"{name}.{n}" in package_of]
            edges.update(subs if len(subs) == len(names) and names else subs + [name])
        graph[dotted.removesuffix(".__init__")] = {e for e in edges if e in package_of}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: every strongly connected component of more than one
    node, and every node that imports itself (Tarjan's algorithm, iterative), each sorted."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root), on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while not component or component[-1] != node:
                        component.append(stack.pop())
                        on_stack.discard(component[-1])
                    if len(component) > 1 or node in graph[node]:
                        found.append(sorted(component))
            elif child not in index:
                index[child] = low[child] = len(index)
                stack.append(child), on_stack.add(child)
                work.append((child, iter(sorted(graph.get(child, ())))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return sorted(found)


def test_cycle_finder_finds_cycles():
    toy = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": {"e"}, "e": set(), "f": {"f"}, "g": {"a"}}
    assert _cycles(toy) == [["a", "b", "c"], ["f"]]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert _cycles({"a": {"b", "c"}, "b": {"a"}, "c": {"d"}, "d": {"c"}}) == [["a", "b"], ["c", "d"]]


def test_import_graph_sees_every_kind_of_import():
    graph = _import_graph()
    assert "transcalib.io.files" in graph["transcalib.io"]  # from .files import ... in a package
    assert "transcalib.geometry.camera" in graph["transcalib.types"]  # relative, module level
    assert "transcalib.report.figures" in graph["transcalib.report"]  # from . import figures, in a function


def test_no_import_cycles():
    cycles = _cycles(_import_graph())
    assert not cycles, "import cycles (break each by importing from the defining module or moving code down):\n" + \
        "\n".join(" <-> ".join(c) for c in cycles)


def test_no_function_body_over_80_lines():
    long = []
    for path, _, dotted in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                body = node.body
                first = body[1] if (len(body) > 1 and isinstance(body[0], ast.Expr)
                                    and isinstance(body[0].value, ast.Constant)) else body[0]
                n = node.end_lineno - first.lineno + 1
                if n > MAX_BODY_LINES:
                    long.append(f"{dotted}.{node.name}: {n} lines")
    assert not long, "\n".join(long)


def test_every_module_opens_with_a_docstring():
    missing = [dotted for path, _, dotted in _modules() if path.stat().st_size and ast.get_docstring(
        ast.parse(path.read_text())) is None]
    assert not missing, missing


@pytest.mark.parametrize("heavy", ["cv2", "scipy", "matplotlib", "transcalib.estimate", "transcalib.synth"])
def test_import_transcalib_is_light(heavy):
    """``import transcalib`` loads neither OpenCV nor the estimators (they load on use)."""
    code = f"import sys, transcalib; print({heavy!r} in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
