"""The fleet prior: how fast each coefficient of a model ages, as a versioned file.

A :class:`FleetPrior` is computed on shore (:func:`recal.fleet.compute.fleet_prior`) and sent
back to the vessels, where it replaces the datasheet's typical change in the acceptance gate and
in the held coefficients' 1-sigma with the fleet's figure for the months since the current
version (docs/fleet.md, "The fleet prior"). Like a coefficients file it is checked when read:
``format`` first (a newer format is refused with the reason), then every figure.

This module turns objects into JSON-ready dictionaries and back; it opens no file.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recal.errors import RecalInputError

#: The file layout's name and the newest version this recal reads and writes.
FORMAT_NAME = "recal.fleet_prior"
FORMAT_VERSION = 1
#: The ageing law of format 1: a random walk, rate per sqrt(month) (recal.fleet.estimate).
LAW = "random_walk"


@dataclass(frozen=True)
class CoefficientAgeing:
    """One coefficient's figure: ``rate`` is the 1-sigma change after one month of service
    (a fraction of the value when ``relative``: scale factors); after ``dt`` months it is
    ``rate * sqrt(dt)``."""

    rate: float
    rate_sigma: float  # 1-sigma of the rate itself
    relative: bool
    units: int  # units behind the figure
    changes: int  # changes (pairs of consecutive versions) behind it
    #: of those changes, how many end in a version the vessel's gate rejected (issue 37: they
    #: are used, as the accepted ones are; absent from files before it: 0)
    rejected: int = 0


@dataclass(frozen=True)
class FleetOutlier:
    """A unit whose changes are outliers for its model (recal.fleet.outliers)."""

    unit: str
    statistic: float  # sum of squared normalised changes
    dof: int
    p_value: float


@dataclass(frozen=True)
class FleetPrior:
    """The fleet's ageing figures for one model (format ``recal.fleet_prior/1``)."""

    model: str
    version: int
    created_at: str  # ISO 8601 UTC
    coefficients: Mapping[str, CoefficientAgeing]
    false_alarm: float = 0.01  # of the outlier test
    outliers: tuple[FleetOutlier, ...] = ()
    law: str = LAW
    metadata: Mapping[str, Any] = field(default_factory=dict)

    @property
    def format(self) -> str:
        return f"{FORMAT_NAME}/{FORMAT_VERSION}"

    def label(self) -> str:
        return f"fleet prior {self.model} v{self.version} ({self.created_at})"

    def rates(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """(rate, relative) per flat name; NaN rate where the fleet has no figure."""
        rate = np.array([self.coefficients[n].rate if n in self.coefficients else np.nan
                         for n in names], float)  # fmt: skip
        rel = np.array([n in self.coefficients and self.coefficients[n].relative for n in names])
        return rate, rel

    def typical_change(
        self, names: Sequence[str], months: float, values: np.ndarray | None = None
    ) -> np.ndarray:
        """(P,) the 1-sigma change of each coefficient after ``months`` of service, in the
        coefficient's units (relative figures times ``|values|``); NaN where the fleet has none."""
        rate, rel = self.rates(names)
        change = rate * math.sqrt(max(float(months), 0.0))
        if values is not None:
            change = np.where(rel, change * np.abs(np.asarray(values, float)), change)
        elif np.any(rel & np.isfinite(rate)):
            raise ValueError("typical_change: relative figures need the coefficients' values")
        return change

    # ---- the file ----------------------------------------------------------------------
    def to_json_dict(self, brief: bool = False) -> dict[str, Any]:
        """The file's object; ``brief``: only which prior it is (format, version, model,
        created_at), as a calibration records the prior it used."""
        if brief:
            return {"format": self.format, "version": self.version, "model": self.model,
                    "created_at": self.created_at}  # fmt: skip
        return {
            "format": self.format,
            "version": self.version,
            "model": self.model,
            "created_at": self.created_at,
            "law": self.law,
            "time_unit": "month",
            "false_alarm": self.false_alarm,
            "coefficients": {
                n: {
                    "rate": _num(c.rate),
                    "rate_sigma": _num(c.rate_sigma),
                    "relative": c.relative,
                    "units": c.units,
                    "changes": c.changes,
                    "rejected": c.rejected,
                }
                for n, c in self.coefficients.items()
            },  # fmt: skip
            "outliers": [
                {"unit": o.unit, "statistic": o.statistic, "dof": o.dof, "p_value": o.p_value}
                for o in self.outliers
            ],
            "metadata": dict(self.metadata),
        }

    @classmethod
    def from_json_dict(cls, obj: Any, source: str = "fleet prior") -> FleetPrior:
        """Check and read a parsed file; a bad one is a RecalInputError naming ``source``."""
        if not isinstance(obj, Mapping):
            raise RecalInputError(f"{source}: not a fleet prior (a JSON object expected)")
        fmt = obj.get("format")
        m = re.fullmatch(rf"{re.escape(FORMAT_NAME)}/(\d+)", str(fmt)) if fmt else None
        if m is None:
            raise RecalInputError(
                f"{source}: format {fmt!r} is not a fleet prior (expected "
                f"{FORMAT_NAME}/N, N up to {FORMAT_VERSION})"
            )
        if int(m.group(1)) > FORMAT_VERSION:
            raise RecalInputError(
                f"{source}: format {fmt} is newer than this recal reads (up to "
                f"/{FORMAT_VERSION}); upgrade recal"
            )
        try:
            if obj.get("law", LAW) != LAW or obj.get("time_unit", "month") != "month":
                raise ValueError(f"law {obj.get('law')!r} per {obj.get('time_unit')!r} is not "
                                 f"{LAW} per month")  # fmt: skip
            coefficients = {str(n): _ageing(c) for n, c in obj["coefficients"].items()}
            outliers = tuple(
                FleetOutlier(
                    str(o["unit"]), float(o["statistic"]), int(o["dof"]), float(o["p_value"])
                )  # fmt: skip
                for o in obj.get("outliers") or ()
            )
            return cls(
                model=str(obj["model"]),
                version=int(obj["version"]),
                created_at=str(obj["created_at"]),
                coefficients=coefficients,
                false_alarm=float(obj.get("false_alarm", 0.01)),
                outliers=outliers,
                metadata=dict(obj.get("metadata") or {}),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise RecalInputError(f"{source}: malformed fleet prior: {exc!s}") from None


def read_fleet_prior(text: str | Mapping[str, Any], source: str = "fleet prior") -> FleetPrior:
    """A fleet prior from its JSON text or parsed object (no file I/O)."""
    import json

    if isinstance(text, str | bytes):
        try:
            text = json.loads(text)
        except ValueError as exc:
            raise RecalInputError(f"{source}: not JSON ({exc})") from None
    return FleetPrior.from_json_dict(text, source)


def _ageing(c: Mapping[str, Any]) -> CoefficientAgeing:
    rate = float(c["rate"]) if c.get("rate") is not None else math.nan
    if not (math.isnan(rate) or rate >= 0):
        raise ValueError(f"a rate must be >= 0, not {rate}")
    sd = c.get("rate_sigma")
    return CoefficientAgeing(rate, math.nan if sd is None else float(sd), bool(c["relative"]),
                             int(c["units"]), int(c["changes"]),
                             int(c.get("rejected", 0)))  # fmt: skip


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None
