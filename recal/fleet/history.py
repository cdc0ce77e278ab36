"""Versions of many units as flat arrays, and the changes between consecutive ones.

A :class:`VersionTable` holds the versions of every unit of one model, one row per version,
sorted by unit then time: the unit's index, the time in months of service, the coefficients by
flat name (``"gyro.scale.Kx"``, the conventions' names), their 1-sigma (NaN where the version
held or lacked a coefficient) and whether the vessel's gate accepted it (``accepted``). The
rejected ones belong in it too (issue 37): the gate rejects large jumps, so the accepted
versions alone are a censored sample of the ageing (recal.fleet.sequence says why every
version whose estimate is sound is used). :meth:`VersionTable.changes` takes the differences
between consecutive versions of the same unit in one vectorised step.

Scale factors age in proportion to their value (``relative``): their changes and sigmas are
divided by the earlier version's value, as the terms' ``relative_typical`` says.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Days in a month of service (a Julian year over 12).
MONTH_DAYS = 365.25 / 12.0


def is_relative(name: str) -> bool:
    """A scale factor (``gyro.scale.Kx``) ages relative to its value, like its term's
    ``relative_typical``."""
    parts = name.split(".")
    return len(parts) > 2 and parts[1] == "scale"


@dataclass(frozen=True)
class Changes:
    """Changes between consecutive accepted versions of the same unit, one row per change."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    unit: np.ndarray  # (C,) index into ``units``
    months: np.ndarray  # (C,) elapsed months of service
    delta: np.ndarray  # (C, P) change (relative for scale factors); NaN where unknown
    variance: np.ndarray  # (C, P) measurement variance of the change: sigma_1**2 + sigma_2**2

    def __len__(self) -> int:
        return len(self.months)

    def without(self, units: Sequence[str]) -> Changes:
        """The changes of every unit but ``units``."""
        drop = np.isin(np.asarray(self.units, dtype=object), list(units))
        keep = ~drop[self.unit]
        return Changes(self.names, self.units, self.unit[keep], self.months[keep],
                       self.delta[keep], self.variance[keep])  # fmt: skip


@dataclass(frozen=True)
class VersionTable:
    """Versions of the units of one model (rows sorted by unit, then time)."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    unit: np.ndarray  # (V,) index into ``units``
    months: np.ndarray  # (V,) time of the version, months of service from any fixed origin
    values: np.ndarray  # (V, P) coefficients
    sigma: np.ndarray  # (V, P) their 1-sigma, NaN where held or unknown
    #: (V,) bool: the vessel's gate accepted the version (None: every one, as before issue 37)
    accepted: np.ndarray | None = None

    def __post_init__(self) -> None:
        v, p = len(self.unit), len(self.names)
        if self.values.shape != (v, p) or self.sigma.shape != (v, p) or self.months.shape != (v,):
            raise ValueError(f"VersionTable: {v} versions of {p} coefficients expected")
        order = np.lexsort((self.months, self.unit))
        if np.any(order != np.arange(v)):
            raise ValueError("VersionTable: rows must be sorted by unit, then time")
        accepted = np.ones(v, bool) if self.accepted is None else np.asarray(self.accepted, bool)
        if accepted.shape != (v,):
            raise ValueError(f"VersionTable: {v} accepted flags expected")
        object.__setattr__(self, "accepted", accepted)

    def accepted_only(self) -> VersionTable:
        """The accepted versions alone (what the fleet prior learnt from before issue 37)."""
        keep = self.accepted
        return VersionTable(self.names, self.units, self.unit[keep], self.months[keep],
                            self.values[keep], self.sigma[keep], self.accepted[keep])  # fmt: skip

    def without(self, units: Sequence[str]) -> VersionTable:
        """The versions of every unit but ``units``."""
        drop = np.isin(np.asarray(self.units, dtype=object), list(units))
        keep = ~drop[self.unit]
        return VersionTable(self.names, self.units, self.unit[keep], self.months[keep],
                            self.values[keep], self.sigma[keep], self.accepted[keep])  # fmt: skip

    def changes(self) -> Changes:
        """Differences of consecutive versions of each unit (vectorised over all units): of
        every row, accepted or not (:meth:`accepted_only` first for the accepted ones')."""
        same = self.unit[1:] == self.unit[:-1]
        a, b = np.flatnonzero(same), np.flatnonzero(same) + 1
        rel = np.array([is_relative(n) for n in self.names])
        ref = np.where(rel, np.abs(self.values[a]), 1.0)
        ref = np.where(ref > 0, ref, np.nan)
        delta = (self.values[b] - self.values[a]) / ref
        variance = (self.sigma[a] ** 2 + self.sigma[b] ** 2) / ref**2
        bad = ~np.isfinite(delta) | ~np.isfinite(variance)
        delta, variance = np.where(bad, np.nan, delta), np.where(bad, np.nan, variance)
        return Changes(self.names, self.units, self.unit[a], self.months[b] - self.months[a],
                       delta, variance)  # fmt: skip

    @classmethod
    def from_histories(
        cls,
        names: Sequence[str],
        histories: Mapping[str, tuple[Any, ...]],
    ) -> VersionTable:
        """From ``{unit: (months (n,), values (n, P), sigma (n, P)[, accepted (n,)])}`` (any
        order in time; without ``accepted`` every version counts as accepted)."""
        units = tuple(histories)
        parts = [tuple(np.asarray(x, float) for x in histories[u][:3]) for u in units]
        flags = [np.asarray(histories[u][3], bool) if len(histories[u]) > 3
                 else np.ones(len(parts[i][0]), bool) for i, u in enumerate(units)]  # fmt: skip
        counts = np.array([len(p[0]) for p in parts], dtype=int)
        unit = np.repeat(np.arange(len(units)), counts)
        months = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0)
        values = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, len(names)))
        sigma = np.concatenate([p[2] for p in parts]) if parts else np.zeros((0, len(names)))
        accepted = np.concatenate(flags) if flags else np.zeros(0, bool)
        order = np.lexsort((months, unit))
        return cls(tuple(names), units, unit[order], months[order], values[order], sigma[order],
                   accepted[order])  # fmt: skip

    @classmethod
    def from_documents(
        cls,
        names: Sequence[str],
        versions: Mapping[str, Sequence[tuple[Any, ...]]],
    ) -> VersionTable:
        """From each unit's versions as the shore holds them: (time, the document a vessel's
        ``GET /coefficients/{version}`` returns[, accepted]), read by the conventions' names
        (without ``accepted``: an accepted version)."""
        histories = {}
        for unit, rows in versions.items():
            months = [row[0].timestamp() / 86400.0 / MONTH_DAYS for row in rows]
            values = [flat_section(row[1].get("coefficients") or {}, names) for row in rows]
            sigma = [flat_section(row[1].get("uncertainty") or {}, names) for row in rows]
            histories[unit] = (months, np.reshape(values, (-1, len(names))),
                               np.reshape(sigma, (-1, len(names))), _accepted(rows))  # fmt: skip
        return cls.from_histories(names, histories)

    @classmethod
    def from_flat(
        cls,
        names: Sequence[str],
        versions: Mapping[str, Sequence[tuple[Any, ...]]],
    ) -> VersionTable:
        """From each unit's versions as (time, :func:`flat_version` of the document[,
        accepted]): the same table as :meth:`from_documents` of the documents, without them."""
        histories = {}
        for unit, rows in versions.items():
            months = [row[0].timestamp() / 86400.0 / MONTH_DAYS for row in rows]
            values = [_by_name(row[1].get("coefficients"), names) for row in rows]
            sigma = [_by_name(row[1].get("uncertainty"), names) for row in rows]
            histories[unit] = (months, np.reshape(values, (-1, len(names))),
                               np.reshape(sigma, (-1, len(names))), _accepted(rows))  # fmt: skip
        return cls.from_histories(names, histories)


def flat_version(document: Mapping[str, Any], names: Sequence[str]) -> dict[str, Any]:
    """What :meth:`VersionTable.from_documents` reads of one version's document, by flat name:
    ``{"coefficients": {name: value}, "uncertainty": {name: 1-sigma}}``, the finite ones only
    (plain JSON: the shore keeps it beside the document, migration 0006)."""
    out = {}
    for section in ("coefficients", "uncertainty"):
        found = document.get(section) if isinstance(document, Mapping) else None
        flat = flat_section(found if isinstance(found, Mapping) else {}, names)
        out[section] = {n: v for n, v in zip(names, flat, strict=True) if np.isfinite(v)}
    return out


def _accepted(rows: Sequence[tuple[Any, ...]]) -> list[bool]:
    """The optional third item of each (time, document[, accepted]) row (default: accepted)."""
    return [bool(row[2]) if len(row) > 2 else True for row in rows]


def _by_name(section: Any, names: Sequence[str]) -> list[float]:
    """A :func:`flat_version` section by ``names`` (NaN where absent)."""
    section = section if isinstance(section, Mapping) else {}
    return [float(section.get(n, np.nan)) for n in names]


def flat_section(section: Mapping[str, Any], names: Sequence[str]) -> list[float]:
    """Section 5 layout (``{"gyro": {"scale": [..], "misalignment": {..}}}``) by flat name; NaN
    where a name is absent or its value is not a finite number. A document off that layout (a
    vessel's bug, or a crafted batch: ``{"gyro": 5}``) gives NaN, never an exception: the shore
    reads what units send."""
    axis = {"x": 0, "y": 1, "z": 2}
    out = []
    for name in names:
        sensor, key, param = name.split(".", 2)
        group = section.get(sensor)
        entry = group.get(key) if isinstance(group, Mapping) else None
        leaf = None
        if isinstance(entry, Mapping):
            leaf = entry.get(param)
        elif isinstance(entry, list | tuple) and param[-1:] in axis and len(entry) == 3:
            leaf = entry[axis[param[-1]]]
        out.append(_number(leaf))
    return out


def _number(value: Any) -> float:
    """A JSON number as a finite float, else NaN (a boolean is no number; an integer beyond a
    double's range overflows to NaN, not an error)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return np.nan
    try:
        out = float(value)
    except OverflowError:
        return np.nan
    return out if math.isfinite(out) else np.nan
