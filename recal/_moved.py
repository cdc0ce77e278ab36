"""Old module paths, kept importable for one minor release (the deprecation policy, docs/api.md).

Before 0.2.0 every module of recal sat at the top of the package (``recal.terms``,
``recal.calibrate``, ...); issue 21 moved them into the pipeline's subpackages. Plugins, notebooks
and scripts were written against the old paths, and a user's plugin file is an API, so each old
path still imports: it is a thin module that forwards every name to the module that now defines
it and warns (``DeprecationWarning``) where the old path is used, naming the new one.

The forwarding modules are made on import by :class:`MovedFinder` from the :data:`MOVED` table
instead of 36 one-line files at the top of the package: the table is the whole record of what
moved, and removing it (and :data:`MOVED_INTO_PACKAGE`) in 0.3.0 removes the old paths. Three
old modules became packages of the same name (``recal.model``, ``recal.diagnose``,
``recal.report``); no file or finder can stand at those paths, so those packages forward the old
module's names through :func:`forward_old_names` in their ``__init__``.

Two 0.2.0 paths that only re-exported other modules went the same way (issue 38):
``recal.detect.static`` and ``recal.detect.slews`` are in :data:`MOVED` too, and the service's
``service.db`` is served by a finder of its own table (``service.moved``, :func:`install_table`).

Nothing here holds logic of the modules it forwards to; only names are looked up.
"""

from __future__ import annotations

import importlib
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from importlib.machinery import ModuleSpec
from types import ModuleType
from typing import Any

#: The release that removes the old paths (semantic versions: one minor release after 0.2.0).
REMOVED_IN = "0.3.0"

#: Old module -> the modules its names live in now, searched in order (``recal.static`` was
#: split into the detector, its noise floor and the window table; ``recal.mcs`` lost its worker
#: processes to ``recal.runtime.pool``; parts of ``recal.calibrate`` went on to the slews', the
#: prior's and the Earth-rate modules of recal.solve). From ``git log --diff-filter=R`` (commit
#: 48a3624).
#: The modules the slews' and the static detector's names live in, each before the modules that
#: import its names (the finder searches them in this order).
_SLEW_MODULES = (
    "recal.model.reference",  # first: the slew modules import its constants
    "recal.detect.slew_data",
    "recal.detect.slew_groups",
    "recal.detect.slew_collect",
    "recal.detect.quaternions",
    "recal.detect.slew_rotation",
    "recal.detect.slew_gravity",
    "recal.detect.slew_gauge",
    "recal.detect.closed_turns",
    "recal.detect.known_rotations",
)
_STATIC_MODULES = (
    "recal.detect.floor",
    "recal.detect.windows",
    "recal.detect.static_accel_only",
    "recal.detect.static_config",
    "recal.detect.static_report",
    "recal.detect.static_detector",
)

MOVED: dict[str, tuple[str, ...]] = {
    "recal.alignment": ("recal.nav.alignment",),
    "recal.calibrate": (
        "recal.solve.options",
        "recal.solve.result",
        "recal.solve.calibrate",
        "recal.solve.slew_fit",
        "recal.solve.prior",
        "recal.solve.earth_rate",
    ),
    "recal.coefficient_schema": ("recal.model.coefficient_schema",),
    "recal.coefficients": ("recal.model.coefficients",),
    "recal.consider": ("recal.solve.consider",),
    "recal.convergence": ("recal.solve.convergence",),
    "recal.drift": ("recal.diagnose.drift",),
    "recal.imucal": ("recal.model.imucal",),
    "recal.information": ("recal.diagnose.information",),
    "recal.ins_error": ("recal.nav.ins_error",),
    "recal.lm": ("recal.solve.lm",),
    "recal.mcs": ("recal.solve.mcs", "recal.runtime.pool"),
    "recal.nafsa": ("recal.solve.nafsa",),
    "recal.navigation": ("recal.nav.navigation",),
    "recal.noise": ("recal.detect.noise",),
    "recal.oafsa": ("recal.solve.oafsa",),
    "recal.observability": ("recal.solve.observability",),
    "recal.perf": ("recal.runtime.allocator",),
    "recal.phases": ("recal.solve.phases",),
    "recal.plausibility": ("recal.detect.plausibility",),
    "recal.plots": ("recal.report.plots",),
    "recal.plugins": ("recal.model.plugins",),
    "recal.positions": ("recal.model.positions",),
    "recal.problem": ("recal.solve.problem",),
    "recal.reference": ("recal.model.reference",),
    "recal.report_navigation": ("recal.report.navigation",),
    "recal.report_positions": ("recal.report.positions",),
    "recal.safsa": ("recal.solve.safsa",),
    "recal.session": ("recal.sim.session",),
    "recal.simulate": ("recal.sim.simulate",),
    "recal.slews": _SLEW_MODULES,
    "recal.static": _STATIC_MODULES,
    "recal.surrogate": ("recal.solve.surrogate",),
    "recal.swarm": ("recal.solve.swarm",),
    "recal.terms": ("recal.model.terms",),
    "recal.trajectory": ("recal.nav.trajectory",),
    # 0.2.0 paths of modules that only re-exported others (issue 38): the detector's and the
    # slews' pieces each live in a module of their own
    "recal.detect.static": _STATIC_MODULES,
    "recal.detect.slews": _SLEW_MODULES,
}

#: Old modules whose path is now a package: old module -> where its names live now.
MOVED_INTO_PACKAGE: dict[str, tuple[str, ...]] = {
    "recal.diagnose": ("recal.diagnose.effects",),
    "recal.model": ("recal.model.error_model",),
    "recal.report": ("recal.report.html",),
}


def message(old: str, name: str, home: str) -> str:
    """The warning: what is deprecated (the old path, or ``old.name`` where the old path is now
    a package, which itself stays), where ``name`` lives now, and when it goes."""
    also = " (or recal)" if name in _PUBLIC else ""
    return (
        f"{old} is deprecated; import {name} from {home}{also} — it will be removed in {REMOVED_IN}"
    )


_MISSING = object()
#: The package's public names (``recal.__all__``), given by :func:`install`: the warning says
#: where a name is also importable from ``recal``.
_PUBLIC: frozenset[str] = frozenset()


def _find(name: str, homes: Sequence[str]) -> tuple[str, Any] | None:
    """(module, value) of the first of ``homes`` that defines ``name``. Modules are never
    forwarded: in a package (``recal.model``) the name is then its own submodule, which the
    import system must be left to load."""
    for home in homes:
        value = getattr(importlib.import_module(home), name, _MISSING)
        if value is not _MISSING and not isinstance(value, ModuleType):
            return home, value
    return None


def public_names(homes: Sequence[str]) -> list[str]:
    """The names ``from old import *`` gives: the homes' ``__all__``, else every public name
    they define (imported modules, functions and classes and ``__future__`` flags left out)."""
    out: dict[str, None] = {}
    for home in homes:
        module = importlib.import_module(home)
        names = getattr(module, "__all__", None)
        if names is None:
            names = [n for n, v in vars(module).items() if not n.startswith("_") and _own(v, home)]
        out.update(dict.fromkeys(names))
    return list(out)


def _own(value: Any, home: str) -> bool:
    """Whether ``value``, found in module ``home``, is defined there rather than imported."""
    if isinstance(value, ModuleType) or type(value).__module__ == "__future__":
        return False
    if isinstance(value, type) or (callable(value) and hasattr(value, "__code__")):
        return getattr(value, "__module__", home) == home
    return True


def forward_old_names(
    old: str, homes: Sequence[str], package: bool = False
) -> Callable[[str], Any]:
    """A module ``__getattr__`` that serves the names of the old module ``old`` from ``homes``
    with a DeprecationWarning at the line that asked for them: each use warns, not the first
    import only, which happens once per process (a plugin file may be loaded again). Dunder
    names are never forwarded (the import system probes ``__path__`` and friends), except
    ``__all__``: ``from old import *`` gives the old names, unless ``old`` is now a
    ``package``, whose star import stays its own (and whose warning names ``old.name``: the
    package is not deprecated, the old module's names in it are)."""

    def __getattr__(name: str) -> Any:
        if name.startswith("__"):
            if name == "__all__" and not package:
                return public_names(homes)
            raise AttributeError(f"module {old!r} has no attribute {name!r}")
        found = _find(name, homes)
        if found is None:
            raise AttributeError(f"module {old!r} has no attribute {name!r}")
        home, value = found
        subject = f"{old}.{name}" if package else old
        warnings.warn(message(subject, name, home), DeprecationWarning, stacklevel=2)
        return value

    return __getattr__


class MovedFinder:
    """Import hook (last on ``sys.meta_path``, so a real file always wins) that answers for the
    old paths of ``table`` (old module -> the modules its names live in now; :data:`MOVED` by
    default; the service passes its own, service.moved) with a forwarding module."""

    def __init__(self, table: Mapping[str, tuple[str, ...]] | None = None) -> None:
        self.table = MOVED if table is None else table

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> ModuleSpec | None:
        if fullname not in self.table:
            return None
        return ModuleSpec(fullname, self, origin=f"deprecated alias of {self.table[fullname][0]}")

    def create_module(self, spec: ModuleSpec) -> None:
        return None  # the default module object

    def exec_module(self, module: ModuleType) -> None:
        old, homes = module.__name__, self.table[module.__name__]
        module.__doc__ = (
            f"Deprecated: moved to {' and '.join(homes)}; this alias is removed in {REMOVED_IN}."
        )
        module.__getattr__ = forward_old_names(old, homes)  # type: ignore[method-assign]
        module.__dir__ = lambda: sorted(public_names(homes))  # type: ignore[method-assign]


def install(public: Sequence[str] = ()) -> None:
    """Put the finder on ``sys.meta_path`` once (``import recal`` calls it with its public
    names)."""
    global _PUBLIC
    _PUBLIC = frozenset(public)
    install_table(MOVED)


def install_table(table: Mapping[str, tuple[str, ...]]) -> None:
    """Put a finder for the old paths of ``table`` on ``sys.meta_path``, once per table."""
    if not any(isinstance(f, MovedFinder) and f.table is table for f in sys.meta_path):
        sys.meta_path.append(MovedFinder(table))
