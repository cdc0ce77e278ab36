"""Calibration coefficients as a typed, versioned object (docs/reference.md#coefficients).

A :class:`CoefficientSet` maps term names (``"gyro.scale"``, ``"accel.misalignment"``, catalogue
effects...) to parameter arrays. It converts to and from the JSON layout users script against:

    {"gyro":  {"scale": [Kx, Ky, Kz], "bias": [bx, by, bz],
               "misalignment": {"Exz": .., "Exy": .., "Eyz": .., "Eyx": .., "Ezy": .., "Ezx": ..}},
     "accel": {"scale": [...], "bias": [...], "misalignment": {...}, "quadratic": [...]},
     "effects": {"gyro.bias_temperature": {"kTx": .., ...}}, "t0_c": 25.0, "schema": ...}

The same layout with other leaf types carries status strings ("estimated"/"held") and 1-sigma
uncertainties (see :func:`layout_like`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficient_schema import SCHEMA, coefficients_block, parse_json, upgrade
from recal.model.error_model import ParameterLayout
from recal.model.terms import MISALIGNMENT_NAMES, Term

__all__ = ["SCHEMA", "CoefficientSet", "layout_like", "read_coefficients"]
#: Seed categories stored under the sensor key; everything else goes under "effects".
_SEED_KEYS = {"scale": "list", "bias": "list", "misalignment": "dict", "quadratic": "list"}

#: Seed 000 Table 2: the preset FOG coefficients of the paper (K in counts per deg/h,
#: b in deg/h, E dimensionless; Table 2 prints I + E with a "deg" label that the values do not
#: support, docs/reference.md#models reads them as rad).
SEED_000_TABLE2: dict[str, np.ndarray] = {
    "gyro.scale": np.array([643.50373651, 645.62852456, 645.17583651]),
    "gyro.bias": np.array([0.01562779, 0.03213767, 0.02793626]),
    "gyro.misalignment": np.array(
        [0.00099183, 0.00010717, -0.00037044, 0.00014048, 0.00010505, -0.00041586]
    ),
}
#: Representative navigation-grade accelerometer triad (output in g-equivalent units). Seed 002's
#: Table 2 values did not survive in the text, so these are the project's stand-in.
DEFAULT_ACCEL: dict[str, np.ndarray] = {
    "accel.scale": np.array([1.000210, 0.999870, 1.000120]),
    "accel.bias": np.array([2.1e-4, -1.4e-4, 3.2e-4]),
    "accel.misalignment": np.array([4.0e-4, -2.5e-4, 1.2e-4, 3.1e-4, -1.8e-4, 2.2e-4]),
    "accel.quadratic": np.array([1.5e-5, -1.0e-5, 2.0e-5]),
}


@dataclass
class CoefficientSet:
    """Coefficients keyed by term name; ``metadata`` carries provenance (version, source, ...)."""

    values: dict[str, np.ndarray] = field(default_factory=dict)
    t0_c: float = 25.0
    metadata: dict[str, Any] = field(default_factory=dict)
    #: 1-sigma per term, same shapes as ``values`` (NaN where unknown); read from a file's
    #: ``"uncertainty"``: what the coefficients held at this prior add to a new fit's uncertainty
    uncertainty: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def seed_truth(cls) -> CoefficientSet:
        """Seed 000 Table 2 for the gyro plus the project's accelerometer stand-in."""
        vals = {k: v.copy() for k, v in {**SEED_000_TABLE2, **DEFAULT_ACCEL}.items()}
        return cls(vals, metadata={"source": "seed 000 Table 2 + project accel stand-in"})

    def get(self, name: str) -> np.ndarray | None:
        v = self.values.get(name)
        return None if v is None else np.asarray(v, float)

    def copy(self) -> CoefficientSet:
        return CoefficientSet(
            {k: np.array(v, float) for k, v in self.values.items()},
            self.t0_c,
            dict(self.metadata),
            {k: np.array(v, float) for k, v in self.uncertainty.items()},
        )

    # ---- flat vectors ---------------------------------------------------------------------
    def to_vector(
        self, layout: ParameterLayout, fallback: Mapping[str, np.ndarray] | None = None
    ) -> np.ndarray:
        """Flat vector for ``layout``; missing terms take ``fallback`` or the term's neutral value."""
        parts = []
        for m in layout.models:
            for t in m.terms:
                v = self.values.get(t.name)
                if v is None and fallback is not None:
                    v = fallback.get(t.name)
                parts.append(np.asarray(t.neutral if v is None else v, float).reshape(t.size))
        return np.concatenate(parts)

    @classmethod
    def from_vector(
        cls, layout: ParameterLayout, theta: np.ndarray, t0_c: float = 25.0, **metadata: Any
    ) -> CoefficientSet:
        vals = {}
        for name, sl in layout.term_slices().items():
            vals[name] = np.array(theta[sl], float)
        return cls(vals, t0_c, dict(metadata))

    # ---- JSON -----------------------------------------------------------------------------
    def to_json_dict(self, terms: Mapping[str, Term] | None = None) -> dict[str, Any]:
        out = layout_like(self.values, lambda v: float(v), terms)
        out["t0_c"] = self.t0_c
        out["schema"] = SCHEMA
        if self.uncertainty:
            out["uncertainty"] = layout_like(
                self.uncertainty, lambda v: float(v) if np.isfinite(v) else None, terms
            )
        if self.metadata:
            out["metadata"] = _jsonable(self.metadata)
        return out

    @classmethod
    def from_json_dict(
        cls, data: Mapping[str, Any], terms: Mapping[str, Term] | None = None, source: str = "JSON"
    ) -> CoefficientSet:
        """Parse the section 5 layout; its ``schema`` is checked and an older version migrated
        (recal.model.coefficient_schema). Unknown sensors or malformed entries are input errors."""
        data = upgrade(data, source)
        vals = _parse_layout(data, terms, source, _finite)
        if not vals:
            raise RecalInputError(f"{source}: no coefficients found (expected 'gyro' or 'accel')")
        sigma: dict[str, np.ndarray] = {}
        if data.get("uncertainty") is not None:
            if not isinstance(data["uncertainty"], Mapping):
                raise RecalInputError(f"{source}: 'uncertainty' must be an object")
            sigma = _parse_layout(data["uncertainty"], terms, f"{source} uncertainty", _sigma)
        meta = data.get("metadata") or {}
        if not isinstance(meta, Mapping):
            raise RecalInputError(f"{source}: 'metadata' must be an object")
        t0_c = _finite(data.get("t0_c", 25.0), "t0_c", source, size=1)[0]
        return cls(vals, float(t0_c), dict(meta), sigma)


def read_coefficients(
    data: str | Mapping[str, Any], terms: Mapping[str, Term] | None = None, source: str = "JSON"
) -> CoefficientSet:
    """A coefficients file's content (JSON text or the parsed object), or a ``calibrate --json``
    document / stored version, as a :class:`CoefficientSet`: schema checked, older versions
    migrated, the document's uncertainty used when its coefficients carry none. No file I/O:
    the caller opens the file and passes its text."""
    obj = parse_json(data, source) if isinstance(data, str) else data
    block = coefficients_block(obj, source)
    cs = CoefficientSet.from_json_dict(block, terms, source)
    cs.metadata["source"] = source
    return cs


def _parse_layout(
    data: Mapping[str, Any],
    terms: Mapping[str, Term] | None,
    source: str,
    number: Callable[..., np.ndarray],
) -> dict[str, np.ndarray]:
    """Per-term arrays from the section 5 layout, each leaf list read by ``number``."""
    vals: dict[str, np.ndarray] = {}
    for sensor in ("gyro", "accel"):
        block = data.get(sensor)
        if block is None:
            continue
        if not isinstance(block, Mapping):
            raise RecalInputError(f"{source}: '{sensor}' must be an object")
        for key, kind in _SEED_KEYS.items():
            if key not in block:
                continue
            name = f"{sensor}.{key}"
            if kind == "dict":
                entry = block[key]
                if not isinstance(entry, Mapping) or set(entry) != set(MISALIGNMENT_NAMES):
                    raise RecalInputError(
                        f"{source}: {name} must have exactly {', '.join(MISALIGNMENT_NAMES)}"
                    )
                vals[name] = number([entry[n] for n in MISALIGNMENT_NAMES], name, source)
            else:
                vals[name] = number(block[key], name, source, size=3)
    for name, entry in (data.get("effects") or {}).items():
        term = (terms or {}).get(name)
        if isinstance(entry, Mapping):
            order = list(term.params) if term else list(entry)
            missing = [p for p in order if p not in entry]
            if missing:
                raise RecalInputError(f"{source}: effect {name} lacks {', '.join(missing)}")
            vals[name] = number([entry[p] for p in order], name, source)
        else:
            vals[name] = number(entry, name, source)
    return vals


def _sigma(value: Any, name: str, source: str, size: int | None = None) -> np.ndarray:
    """A 1-sigma leaf list: numbers >= 0, or null (unknown, NaN)."""
    items = value if isinstance(value, list | tuple) else [value]
    arr = _finite([np.nan if v is None else v for v in items], name, source, size, allow_nan=True)
    if np.any(arr < 0):
        raise RecalInputError(f"{source}: {name} must not be negative")
    return arr


def layout_like(
    values: Mapping[str, Any],
    leaf: Callable[[Any], Any],
    terms: Mapping[str, Term] | None = None,
) -> dict[str, Any]:
    """Arrange per-term arrays (or arrays of strings) in the section 5 layout via ``leaf``."""
    out: dict[str, Any] = {}
    for name, arr in values.items():
        sensor, key = name.split(".", 1)
        items = list(np.asarray(arr).reshape(-1))
        if key in _SEED_KEYS:
            block = out.setdefault(sensor, {})
            if _SEED_KEYS[key] == "dict":
                block[key] = {n: leaf(v) for n, v in zip(MISALIGNMENT_NAMES, items, strict=True)}
            else:
                block[key] = [leaf(v) for v in items]
        else:
            term = (terms or {}).get(name)
            params = term.params if term else tuple(f"p{i}" for i in range(len(items)))
            out.setdefault("effects", {})[name] = {
                p: leaf(v) for p, v in zip(params, items, strict=True)
            }
    return out


def _finite(
    value: Any, name: str, source: str, size: int | None = None, allow_nan: bool = False
) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise RecalInputError(f"{source}: {name} must be numbers, got {value!r}") from None
    if size is not None and arr.size != size:
        raise RecalInputError(f"{source}: {name} must have {size} values, got {arr.size}")
    if np.any(np.isinf(arr)) or (not allow_nan and np.any(np.isnan(arr))):
        raise RecalInputError(f"{source}: {name} contains NaN or infinity")
    return arr


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
