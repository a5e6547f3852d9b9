"""The package's import graph (issue 23, item 5): no import circle between modules, lazy imports
inside functions included; between top-level subpackages, the circles left are listed here and
may only shrink.

The graph is read from the source with ``ast``: every ``import`` and ``from ... import`` of
``sonarsim`` anywhere in a module (at its top or inside a function) is an edge to the module it
names (``from pkg import name`` is an edge to ``pkg.name`` where that is a module, else to
``pkg``).
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "sonarsim"

#: Subpackages that still reach each other (strongly connected components of the subpackage
#: graph): none. The last circle (paths, renderer, trace) was closed by trace.embree ->
#: renderer._kernels; Embree's raw answer is converted by its own extension, trace._hits, since.
#: Gone before it: io <-> plot, config <-> image, scene <-> trace, config <-> scene, paths ->
#: renderer (see git history). A change that makes one fails.
KNOWN_SUBPACKAGE_CIRCLES: list[set[str]] = []


def _modules() -> dict[str, Path]:
    """Every module by dotted name: the Python files, and the compiled extensions (``.pyx``: they
    import nothing of the package at run time, so they are leaves of the graph)."""
    out = {}
    for p in [*SRC.rglob("*.py"), *SRC.rglob("*.pyx")]:
        parts = list(p.relative_to(SRC.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
        deps: set[str] = set()
        if path.suffix == ".pyx":  # Cython, not Python: its cimports are compile-time only
            graph[name] = deps
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in mods else mod for a in node.names]
            for t in targets:
                while t not in mods and "." in t:
                    t = t.rsplit(".", 1)[0]
                if t in mods and t != name and t.startswith("sonarsim"):
                    deps.add(t)
        graph[name] = deps
    return graph


def _circles(graph: dict[str, set[str]]) -> list[set[str]]:
    """Strongly connected components of more than one node (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[set[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = set()
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.add(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(comp)
    return out


def test_the_circle_finder_finds_a_known_circle():
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert _circles(g) == [{"a", "b", "c"}]
    assert _circles({"a": {"b"}, "b": set()}) == []


def test_no_module_imports_itself_back():
    circles = _circles(_graph())
    assert not circles, "import circles between modules: " + "; ".join(" -> ".join(sorted(c)) for c in circles)


def test_core_and_the_data_types_sit_at_the_bottom():
    g = _graph()
    for name, deps in g.items():
        if name.startswith("sonarsim.core"):
            assert {d for d in deps if not d.startswith("sonarsim.core")} <= {"sonarsim.errors"}, name
        if name.startswith("sonarsim.image"):
            bad = {d for d in deps
                   if d.split(".")[1] in ("plot", "analysis", "renderer", "io", "cli", "dataset", "config")}
            assert not bad, (name, bad)


def test_io_imports_nothing_that_draws():
    # The recordings show themselves through their frames (image.display's hooks), not plot.
    for name, deps in _graph().items():
        if name.startswith("sonarsim.io"):
            bad = {d for d in deps if d.split(".")[1:2] in (["plot"], ["cli"])}
            assert not bad, (name, bad)


def test_scene_imports_nothing_of_the_engines():
    # The meshes and textures sit below the ray casters built from them (trace imports scene).
    for name, deps in _graph().items():
        if name.startswith("sonarsim.scene"):
            bad = {d for d in deps if d.split(".")[1:2] in (["trace"], ["renderer"], ["paths"])}
            assert not bad, (name, bad)


def test_config_imports_nothing_of_the_scene():
    # The specs and the mesh files they name are read and checked below the scene's geometry.
    for name, deps in _graph().items():
        if name.startswith("sonarsim.config"):
            bad = {d for d in deps if d.split(".")[1:2] in (["scene"], ["trace"], ["paths"], ["renderer"])}
            assert not bad, (name, bad)


def test_the_search_imports_nothing_of_the_renderer():
    # paths sits below renderer: image formation's splatting, which both use, lives in core.splat.
    for name, deps in _graph().items():
        if name.startswith("sonarsim.paths"):
            bad = {d for d in deps if d.split(".")[1:2] == ["renderer"]}
            assert not bad, (name, bad)


def test_subpackage_circles_only_shrink():
    g = _graph()
    top: dict[str, set[str]] = {}
    for name, deps in g.items():
        a = name.split(".")[1] if name.count(".") else ""
        for d in deps:
            b = d.split(".")[1] if d.count(".") else ""
            if a and b and a != b:
                top.setdefault(a, set()).add(b)
            top.setdefault(a, set())
    circles = _circles(top)
    for c in circles:
        assert any(c <= known for known in KNOWN_SUBPACKAGE_CIRCLES), f"a new circle between subpackages: {sorted(c)}"
