"""The packages form one pipeline, and its layers hold (issue 21): drivers -> recal -> service.

Checked on the source with the ast module (every import, module level or inside a function):

* drivers imports neither recal nor service; recal never imports service;
* the numerics core (recal outside recal.report) imports no plotting or document library, no
  process pool, and writes no files;
* recal.report is imported only by the command line, the service and the report package;
* no module of service outside service/cli imports the command line.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Modules the numerics core must not import (drawing, documents, processes, networks).
CORE_FORBIDDEN = ("matplotlib", "plotly", "jinja2", "concurrent", "multiprocessing",
                  "subprocess", "socket", "sqlalchemy", "fastapi", "serial")  # fmt: skip
#: Calls and methods that write files.
WRITERS = {"write_text", "write_bytes", "savefig", "savez", "savez_compressed", "save", "tofile",
           "mkdir", "unlink", "rename", "replace_file"}  # fmt: skip


def _modules(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def _imports(path: Path) -> list[str]:
    """Every module named by an import in ``path`` (absolute names)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append(node.module)
            out += [f"{node.module}.{a.name}" for a in node.names]
    return out


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _core() -> list[Path]:
    return [
        p for p in _modules("recal") if not _rel(p).startswith(("recal/report/", "recal/runtime/"))
    ]


def test_the_layers_import_only_downwards() -> None:
    bad = [(_rel(p), m) for p in _modules("drivers") for m in _imports(p)
           if m.split(".")[0] in ("recal", "service")]  # fmt: skip
    bad += [(_rel(p), m) for p in _modules("recal") for m in _imports(p)
            if m.split(".")[0] == "service"]  # fmt: skip
    assert not bad, bad


def test_the_numerics_core_draws_nothing_starts_no_process_and_writes_no_file() -> None:
    assert len(_core()) > 30
    bad = [(_rel(p), m) for p in _core() for m in _imports(p)
           if m.split(".")[0] in CORE_FORBIDDEN or m.startswith("recal.report")]  # fmt: skip
    assert not bad, bad
    writes = []
    for p in _core():
        tree = ast.parse(p.read_text(encoding="utf-8"))
        buffers = {  # names bound to an in-memory buffer: saving into one writes no file
            t.id for node in ast.walk(tree) if isinstance(node, ast.Assign)
            and isinstance(node.value, ast.Call) and _name(node.value.func) == "BytesIO"
            for t in node.targets if isinstance(t, ast.Name)
        }  # fmt: skip
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            name = _name(node.func)
            into_buffer = bool(node.args) and getattr(node.args[0], "id", None) in buffers
            if (name in WRITERS and not into_buffer) or (name == "open" and _for_writing(node)):
                writes.append((_rel(p), node.lineno, name))
    assert not writes, writes


def _name(func: ast.expr) -> str:
    return func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")


def _for_writing(call: ast.Call) -> bool:
    modes = list(call.args[1:2]) + [k.value for k in call.keywords if k.arg == "mode"]
    return any(isinstance(m, ast.Constant) and set(str(m.value)) & set("wax+") for m in modes)


@pytest.mark.parametrize("package", ["recal", "drivers", "service"])
def test_reports_are_imported_only_by_the_command_line_and_the_service(package: str) -> None:
    allowed = ("recal/report/", "service/")
    bad = [(_rel(p), m) for p in _modules(package) for m in _imports(p)
           if m.startswith("recal.report") and not _rel(p).startswith(allowed)]  # fmt: skip
    assert not bad, bad


def test_the_service_core_does_not_import_the_command_line() -> None:
    core = [p for p in _modules("service") if not _rel(p).startswith("service/cli/")]
    assert len(core) > 15
    bad = [(_rel(p), m) for p in core for m in _imports(p) if m.startswith("service.cli")]
    assert not bad, bad


# ---- no circles, no private names across modules (issue 38) -----------------------------------

#: Where the project's modules live: the three packages, and the benchmarks' scripts, which are
#: read by the next engineer as much as the packages are.
PACKAGES = ("drivers", "recal", "service")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _project_modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in _modules(pkg)}


def _edges(path: Path, modules: dict[str, Path]) -> tuple[set[str], list[tuple[str, str]]]:
    """The project modules ``path`` imports (anywhere in the file: module level, in functions,
    under TYPE_CHECKING), and the private names it takes from another module as (module,
    name)."""
    me = (
        _module_name(path)
        if path.is_relative_to(ROOT / "drivers")
        or any(path.is_relative_to(ROOT / p) for p in PACKAGES)
        else ""
    )
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    targets: set[str] = set()
    private: list[tuple[str, str]] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets |= {a.name for a in node.names if a.name in modules}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*up, *([node.module] if node.module else [])])
            for alias in node.names:
                if f"{base}.{alias.name}" in modules:  # a submodule
                    targets.add(f"{base}.{alias.name}")
                elif base in modules:
                    targets.add(base)
                    dunder = alias.name.startswith("__")
                    if alias.name.startswith("_") and not dunder and base != me:
                        private.append((base, alias.name))
    return targets - {me}, private


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def test_no_module_imports_itself_in_a_circle() -> None:
    """Every import counts, TYPE_CHECKING and function-level ones included: a circle hidden
    behind a late import is still two modules that cannot be read, or changed, apart."""
    modules = _project_modules()
    assert len(modules) > 100
    graph = {m: _edges(p, modules)[0] for m, p in modules.items()}
    assert not _cycles(graph)


def test_the_cycle_finder_finds_a_circle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_private_name_is_imported_from_another_module() -> None:
    """A name with a leading underscore is its module's own; one that another module needs is
    part of an interface and is named as one. The benchmarks are held to it too."""
    modules = _project_modules()
    scripts = sorted((ROOT / "benchmarks").glob("*.py"))
    bad = [(_rel(p), f"{m}.{n}") for p in [*modules.values(), *scripts]
           for m, n in _edges(p, modules)[1]]  # fmt: skip
    assert not bad, bad
