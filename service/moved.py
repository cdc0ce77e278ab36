"""The service's deprecated module paths, served with a DeprecationWarning until 0.3.0 by
:mod:`recal._moved`'s finder (the deprecation policy, docs/api.md).

``service.db`` re-exported the Store's names, which live in :mod:`service.store` one idea a
module (issue 38): ``from service.db import Store`` still works and warns, naming the module
each name lives in now.
"""

from __future__ import annotations

from recal._moved import install_table

#: Old module -> the modules its names live in now, searched in order (a module before those
#: that import its names: the warning names where a name is defined).
MOVED: dict[str, tuple[str, ...]] = {
    "service.db": (
        "service.store.errors",
        "service.store.records",
        "service.store.rows",
        "service.store.schema",
        "service.store.repository",
    ),
}

install_table(MOVED)
