"""recal.solve.wander's names from before its split (issue 38) still import from the old path,
with a DeprecationWarning naming where each lives now, and are the same objects."""

from __future__ import annotations

import importlib

import pytest

import recal.solve.wander as wander


@pytest.mark.parametrize("name", sorted(wander._MOVED))
def test_an_old_wander_name_warns_and_is_the_same_object(name: str) -> None:
    target = wander._MOVED[name]
    with pytest.warns(DeprecationWarning, match=f"moved to {target}.{name}"):
        old = getattr(wander, name)
    assert old is getattr(importlib.import_module(target), name)


def test_an_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError):
        wander.no_such_name  # noqa: B018
