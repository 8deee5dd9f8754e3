"""The package's structure stays as issue 34 left it: no import cycles, no wide public signatures.

Read from the source with :mod:`ast` (nothing imported; a second or so for the package):

- Import cycles between ``hhra_phys`` modules. Every ``import``/``from ... import`` counts,
  wherever it stands: at module level, inside a function (a lazy import still closes a cycle
  when the function runs) or under ``try``. Only ``if TYPE_CHECKING:`` blocks are left out, as
  they never run. ``from hhra_phys.a import b`` is an edge to the module ``hhra_phys.a.b`` if
  there is one, else to ``hhra_phys.a``; the implicit import of a module's parent packages is
  not an edge (every package would otherwise close a cycle with its own modules), nor is
  ``importlib.import_module`` with a computed name (it cannot be read from the source).
- Public functions and methods (no name on the path starting with ``_``) with more than
  :data:`MAX_PARAMETERS` named parameters; ``self``/``cls`` and the catch-alls ``*args``/
  ``**kwargs`` are not counted. The data loaders ``hhra_phys.data.load*`` are exempt: one
  keyword per column, unit and label of a file (``docs/data.md``).

Complexity is guarded by ruff (C901, max 10, ``pyproject.toml``), which ``.ci/run`` runs as part
of the README's test command (checked here too). One test imports the package, in a
subprocess: ``import hhra_phys`` loads no scipy (nor the other heavy optional libraries) and
offers the top-level names.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "hhra_phys"
MAX_PARAMETERS = 12
#: (module prefix, function name prefix) exempt from the width limit.
WIDE_EXEMPT = (("hhra_phys.data", "load"),)


def modules(root: Path = ROOT) -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is a package) for every module of the package."""
    out = {}
    for path in sorted((root / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        out[".".join(parts)] = (path, is_package)
    return out


def _is_type_checking(node: ast.AST) -> bool:
    test = node.test if isinstance(node, ast.If) else None
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(nodes: list[ast.AST]) -> Iterator[ast.Import | ast.ImportFrom]:
    """Every import statement in ``nodes`` and under them, but not TYPE_CHECKING's."""
    for node in nodes:
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        elif _is_type_checking(node):
            yield from _imports(node.orelse)  # the `else:` of `if TYPE_CHECKING:` does run
        else:
            yield from _imports(list(ast.iter_child_nodes(node)))


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module -> the package's modules it imports (anywhere in its file)."""
    mods = modules(root)

    def known(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for name, (path, is_package) in mods.items():
        targets: set[str] = set()
        for node in _imports([ast.parse(path.read_text(), filename=str(path))]):
            if isinstance(node, ast.Import):
                targets.update(known(alias.name) for alias in node.names)
                continue
            base = node.module or ""
            if node.level:
                here = name.split(".") if is_package else name.split(".")[:-1]
                here = here[: len(here) - (node.level - 1)]
                base = ".".join(here + ([node.module] if node.module else []))
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                targets.add(sub if sub in mods else known(base))
        targets.discard(None)
        targets.discard(name)
        graph[name] = targets  # type: ignore[assignment]
    return graph


def _reachable(graph: dict[str, set[str]], start: str) -> set[str]:
    seen: set[str] = set()
    todo = list(graph.get(start, ()))
    while todo:
        node = todo.pop()
        if node not in seen:
            seen.add(node)
            todo.extend(graph.get(node, ()))
    return seen


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The groups of modules that import each other, directly or through others."""
    reach = {node: _reachable(graph, node) for node in graph}
    groups = {
        tuple(sorted({node} | {other for other in reach[node] if node in reach.get(other, ())}))
        for node in graph
        if node in reach[node]
    }
    return sorted(list(group) for group in groups)


def _public_functions(tree: ast.Module) -> Iterator[tuple[str, ast.FunctionDef, bool]]:
    """(qualified name, node, is a method) of the public functions and methods of a module."""
    stack: list[tuple[list[ast.stmt], str, bool]] = [(tree.body, "", False)]
    while stack:
        body, prefix, in_class = stack.pop()
        for node in body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                stack.append((node.body, f"{prefix}{node.name}.", True))
            elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and (
                not node.name.startswith("_") or node.name.endswith("__")  # __init__ too
            ):
                yield f"{prefix}{node.name}", node, in_class  # type: ignore[misc]


def _width(node: ast.FunctionDef, method: bool) -> int:
    """Named parameters, without self/cls and the catch-alls *args/**kwargs."""
    args = node.args
    named = [a.arg for a in (*args.posonlyargs, *args.args, *args.kwonlyargs)]
    return len(named) - (method and named[:1] in (["self"], ["cls"]))


def wide_signatures(root: Path = ROOT, limit: int = MAX_PARAMETERS) -> list[str]:
    """``module:qualname (n parameters)`` for each public function over ``limit``."""
    found = []
    for name, (path, _) in modules(root).items():
        if any(part.startswith("_") for part in name.split(".")[1:]):
            continue  # a private module
        tree = ast.parse(path.read_text(), filename=str(path))
        for qualname, node, method in _public_functions(tree):
            exempt = any(name.startswith(m) and qualname.startswith(f) for m, f in WIDE_EXEMPT)
            if not exempt and _width(node, method) > limit:
                found.append(f"{name}:{qualname} ({_width(node, method)} parameters)")
    return sorted(found)


def test_no_import_cycle_between_the_package_modules():
    graph = import_graph()
    assert len(graph) > 50 and "hhra_phys.simulate" in graph["hhra_phys"]
    found = cycles(graph)
    assert found == [], f"import cycles (lazy imports count): {found}"


#: Modules outside the model packages that may name the HHRA: the package's top level (it
#: exports ``HHRAModel``), the CLI (the HHRA's defaults for a record, the simulated rig) and
#: ``control``'s closed-form transfer function of the HHRA (``control.tf``).
HHRA_ALLOWED = ("hhra_phys", "hhra_phys.cli", "hhra_phys.control")


def test_the_core_imports_no_particular_model():
    graph = import_graph()
    naming = sorted(
        m for m, deps in graph.items()
        if not m.startswith("hhra_phys.models")
        and not any(m == a or m.startswith(a + ".") for a in HHRA_ALLOWED if a != "hhra_phys")
        and m != "hhra_phys"
        and any(d.startswith("hhra_phys.models.hhra") for d in deps))
    assert naming == [], f"core modules that import the HHRA (use hhra_phys.defaults): {naming}"
    # the fit and the loop reach the HHRA only through the registered default
    assert not any(d.startswith("hhra_phys.models") for d in graph["hhra_phys.fit"])
    assert not any(d.startswith("hhra_phys.models")
                   for d in graph["hhra_phys.diagnosis.engine"])


def test_no_public_signature_over_twelve_parameters():
    wide = wide_signatures()
    assert wide == [], f"over {MAX_PARAMETERS} parameters, group them in an options object: {wide}"


def test_ci_runs_the_readme_test_command_with_ruff():
    # .ci/run runs the README's test command verbatim, and that command runs ruff (C901) first.
    readme = [line for line in (ROOT / "README.md").read_text().splitlines()
              if line.startswith('python -m pip install ".[test]"')]
    assert len(readme) == 1, readme
    assert readme[0] in (ROOT / ".ci" / "run").read_text().splitlines()
    assert "&& ruff check . &&" in readme[0] and readme[0].endswith("python -m pytest -q")


def test_import_loads_no_scipy_and_has_the_top_level_names():
    # `import hhra_phys` stays light (scipy.signal was most of its second: docs/performance.md,
    # "Import time"); FitResult is loaded on first use, and is fit's own.
    code = (
        "import sys, hhra_phys\n"
        "heavy = sorted({'.'.join(m.split('.')[:2]) for m in sys.modules if m.split('.')[0] in "
        "('scipy', 'matplotlib', 'control', 'nlopt', 'pandas', 'dask')})\n"
        "assert not heavy and 'hhra_phys.result' not in sys.modules, heavy\n"
        "import hhra_phys.data, hhra_phys.fit\n"
        "assert hhra_phys.FitResult is hhra_phys.fit.FitResult\n"
        "assert (hhra_phys.load, hhra_phys.Dataset) == (hhra_phys.data.load, "
        "hhra_phys.data.Dataset)\n"
        "assert callable(hhra_phys.__dict__['fit'].fit)  # the submodule, not rebound\n"
    )
    path = [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path)}
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]


def _package(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = root / PACKAGE / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_the_checks_see_a_lazy_cycle_and_a_wide_signature(tmp_path):
    # The detectors on a made-up package: a cycle closed by an import inside a function,
    # a type-only import (no cycle), a wide public function, method and constructor.
    wide = ", ".join(f"p{i}" for i in range(MAX_PARAMETERS + 1))
    ok = ", ".join(f"p{i}" for i in range(MAX_PARAMETERS))
    root = _package(tmp_path, {
        "__init__.py": "from hhra_phys.a import f\n",
        "a.py": "from hhra_phys import b\n\ndef f():\n    return b\n",
        "b.py": "def g():\n    from hhra_phys.a import f\n    return f\n",
        "c.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import hhra_phys.d\n",
        "d.py": "import hhra_phys.c\n",
        "e.py": (f"def wide({wide}): pass\ndef fine({ok}, *args, **kwargs): pass\n"
                 f"def _private({wide}): pass\n"
                 f"class K:\n    def __init__(self, {wide}): pass\n"
                 f"    def m(self, {ok}): pass\n    @classmethod\n"
                 f"    def n(cls, {wide}): pass\n"),
        "data/__init__.py": f"def load_csv({wide}): pass\n",
    })
    graph = import_graph(root)
    assert graph["hhra_phys.b"] == {"hhra_phys.a"} and graph["hhra_phys.c"] == set()
    assert cycles(graph) == [["hhra_phys.a", "hhra_phys.b"]]
    assert wide_signatures(root) == [
        f"hhra_phys.e:K.__init__ ({MAX_PARAMETERS + 1} parameters)",
        f"hhra_phys.e:K.n ({MAX_PARAMETERS + 1} parameters)",
        f"hhra_phys.e:wide ({MAX_PARAMETERS + 1} parameters)",
    ]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e", "d"}}) == [
        ["a", "b", "c"], ["e"]]
