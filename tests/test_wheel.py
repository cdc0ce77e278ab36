"""What the installed package carries (issue 38): the product, and no test tool.

The wheel is built from a copy of the source (pip's in-tree build leaves ``build/`` behind) and
its file list read. Every module it holds must be reachable by imports from what a user runs
(the ``recal`` command, the three packages' ``__init__``, a ``python -m`` module); a module no
product code imports is either dead or a tool for tests and benchmarks, and tools live in
``benchmarks/`` (benchmarks/fault_proxy.py) or ``tests/``.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("recal", "drivers", "service")
#: Modules loaded by name rather than by an import statement: the entry points of a user's
#: ``python -m`` (none today besides the command's) and of plugins.
ENTRY_POINTS = ("service.cli.main",)
#: Files of tools that must never ship, whatever a module graph says.
TOOLS = ("fault_proxy.py", "conftest.py")


@pytest.fixture(scope="module")
def wheel_files(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    for package in PACKAGES:
        shutil.copytree(ROOT / package, src / package,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))  # fmt: skip
    out = tmp_path_factory.mktemp("wheel")
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(src)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    (wheel,) = out.glob("*.whl")
    with zipfile.ZipFile(wheel) as z:
        return z.namelist()


def _module(name: str) -> str:
    parts = name.removesuffix(".py").split("/")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported(source: str, module: str, is_package: bool) -> set[str]:
    """Absolute names of what ``module``'s source imports (relative imports resolved), and its
    string constants: modules imported by name (``importlib``, the command's lazy table of
    subcommands, recal's table of public names) are named in one."""
    out: set[str] = set()
    base = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            out.add(node.value.partition(":")[0])
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                up = base.split(".")
                root = ".".join(up[: len(up) - node.level + 1])
                head = f"{root}.{node.module}" if node.module else root
            else:
                head = node.module or ""
            out.add(head)
            out |= {f"{head}.{a.name}" for a in node.names}
    return out


def test_the_wheel_holds_the_three_packages_and_no_test_tool(wheel_files: list[str]) -> None:
    tops = {n.split("/")[0] for n in wheel_files}
    assert {t for t in tops if not t.endswith(".dist-info")} == set(PACKAGES)
    tools = [n for n in wheel_files if n.rsplit("/", 1)[-1] in TOOLS
             or n.rsplit("/", 1)[-1].startswith("test_")]  # fmt: skip
    assert not tools, f"test tools in the wheel: {tools}"
    assert any(n.startswith("service/dashboard/static/") for n in wheel_files)


def test_every_module_in_the_wheel_is_used_by_the_product(wheel_files: list[str]) -> None:
    """A module no other shipped module imports or names (a string: ``importlib``'s, the
    command's table of subcommands, a package's table of lazy names) is dead or a tool."""
    modules = {_module(n): n for n in wheel_files if n.endswith(".py")}
    assert len(modules) > 150
    packages = {m for m, path in modules.items() if path.endswith("__init__.py")}
    # pyserial imports ``<package>.protocol_<scheme>`` for a URL of that scheme, for each
    # package the product registers in serial.protocol_handler_packages
    pyserial = {m for m, path in modules.items()
                if "protocol_handler_packages" in (ROOT / path).read_text(encoding="utf-8")}  # fmt: skip
    named: dict[str, set[str]] = {}
    for m, path in modules.items():
        for name in _imported((ROOT / path).read_text(encoding="utf-8"), m,
                              path.endswith("__init__.py")):  # fmt: skip
            named.setdefault(name, set()).add(m)

    def used(m: str) -> bool:
        if m in packages or m in ENTRY_POINTS or m.endswith(".__main__"):
            return True  # a package runs when any of its modules is imported
        if m.rpartition(".")[2].startswith("protocol_") and any(
            p.split(".")[0] == m.split(".")[0] for p in pyserial
        ):
            return True
        if "migrations" in m.split("."):  # alembic loads its env and versions by path
            return True
        by = named.get(m, set()) | named.get(m.rpartition(".")[2], set())
        return bool(by - {m})

    unused = sorted(m for m in modules if not used(m))
    assert not unused, f"modules no product code imports or names (dead, or a tool): {unused}"
