"""Orientation coverage of the stored windows, and which orientations would show what is held.

Where gravity points in the body frame comes from each window's mean accelerometer output (the
specific force at rest points up, so gravity is its opposite). The advice reuses the engine's own
observability analysis (:func:`recal.solve.observability.analyze`): the current version's held or
weakly seen coefficients are re-judged with one more window in each candidate orientation (a
body axis pointing down), predicted from the current coefficients by the error model itself.
Nothing here decides observability by its own numerics.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from recal.model.coefficients import CoefficientSet
from recal.model.error_model import ParameterLayout
from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H, normal_gravity_g
from recal.solve.calibrate import build_models
from recal.solve.observability import analyze
from recal.solve.problem import Problem

#: A parameter counts as fully seen above this share of it in the observable subspace
#: (the share ``recal.solve.observability`` reports as ``partially_held`` below it).
SEEN_SHARE = 0.99
#: Candidate windows: gravity along each body axis, both ways.
CANDIDATES: tuple[tuple[str, tuple[float, float, float]], ...] = tuple(
    (f"{axis} {way}", tuple(float(s if i == k else 0.0) for i in range(3)))
    for k, axis in enumerate("xyz")
    for way, s in (("down", 1.0), ("up", -1.0))
)  # fmt: skip
_STATIC_COLUMNS = ("start_s", "end_s", "samples", "temperature_c", "temperature_rate_c_per_h")


def gravity_directions(accel: np.ndarray) -> np.ndarray:
    """Unit vectors (M, 3) of gravity in the body frame from mean accel outputs (M, 3)."""
    norm = np.linalg.norm(accel, axis=1, keepdims=True)
    return -accel / np.where(norm > 0, norm, 1.0)


def azimuth_elevation(down: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth in the body x-y plane (from +x towards +y) and elevation towards +z, deg."""
    az = np.degrees(np.arctan2(down[:, 1], down[:, 0]))
    el = np.degrees(np.arcsin(np.clip(down[:, 2], -1.0, 1.0)))
    return az, el


def windows(positions: Positions, ids: list[int]) -> list[dict[str, Any]]:
    """One row per window: id, time, temperature and gravity direction (when accel is there)."""
    cols = positions.columns
    rows: list[dict[str, Any]] = [{"id": i} for i in ids]
    for name in ("start_s", "end_s", "temperature_c"):
        if name in cols:
            for row, v in zip(rows, cols[name]):
                row[name] = float(v) if math.isfinite(v) else None
    if positions.has_accel:
        accel = np.column_stack([cols[f"accel_{a}"] for a in "xyz"])
        down = gravity_directions(accel)
        az, el = azimuth_elevation(down)
        for row, d, a, e in zip(rows, down, az, el):
            row |= {"gravity": [float(x) for x in d], "azimuth_deg": float(a),
                    "elevation_deg": float(e)}  # fmt: skip
    return rows


def _flat_status(status: dict[str, Any]) -> dict[str, str]:
    """The document's ``status`` as layout names (``gyro.scale.Kx`` ...)."""
    out: dict[str, str] = {}
    for sensor, block in status.items():
        if not isinstance(block, dict):
            continue
        for key, value in block.items():
            prefix = {"scale": "K", "bias": "b", "quadratic": "K2"}.get(key)
            if isinstance(value, list) and prefix:
                out |= {f"{sensor}.{key}.{prefix}{a}": v for a, v in zip("xyz", value)}
            elif isinstance(value, dict):
                out |= {f"{sensor}.{key}.{n}": v for n, v in value.items()}
    return out


def _candidate_row(
    positions: Positions, models: tuple[Any, ...], theta: np.ndarray, layout: ParameterLayout,
    down: np.ndarray, latitude_deg: float, height_m: float,
) -> dict[str, np.ndarray]:  # fmt: skip
    """One window with gravity along ``down``, its outputs predicted by the error model at the
    current coefficients, its noise the stored windows' median."""
    lat = math.radians(latitude_deg)
    up = -down
    north = np.roll(up, 1)  # any horizontal axis: the heading does not change what norms show
    w = OMEGA_IE_DEG_H * (math.cos(lat) * north + math.sin(lat) * up)
    inputs = {"gyro": w, "accel": normal_gravity_g(latitude_deg, height_m) * up}
    cols = positions.columns
    row = {n: np.array([np.median(cols[n])]) for n in _STATIC_COLUMNS if n in cols}
    ctx = {"temperature_c": row.get("temperature_c", np.array([25.0])),
           "temperature_rate_c_per_h": np.zeros(1), "time_h": np.zeros(1),
           "specific_force_g": inputs["accel"][None]}  # fmt: skip
    slices = layout.model_slices()
    for model in models:
        s = model.sensor
        out = model.forward(theta[slices[s]][None], inputs[s][None], ctx)[0, 0]
        for i, a in enumerate("xyz"):
            row[f"{s}_{a}"] = np.array([out[i]])
            for kind in ("std", "sem"):
                if f"{s}_{a}_{kind}" in cols:
                    row[f"{s}_{a}_{kind}"] = np.array([np.median(cols[f"{s}_{a}_{kind}"])])
    return row


def _shares(
    positions: Positions, models: tuple[Any, ...], theta: np.ndarray, lat: float, h: float
) -> np.ndarray:
    layout = ParameterLayout(models)
    problem = Problem.build(positions, models, lat, h, theta)
    info_min = 1.0 if problem.noise_known else 0.0  # structural rank only without the noise
    return analyze(problem, theta, layout.typical(theta), info_min=info_min).share


def orientation_advice(positions: Positions, document: dict[str, Any]) -> dict[str, Any]:
    """What the current version holds or sees weakly, and which window orientation would pin it.

    ``{"unseeable": [{"direction", "reason"}], "weak": [names], "suggestions": [{"orientation",
    "pins": [names]}], "unresolved": [names]}``: rotations of a frame no orientation can show;
    the other held or partly held coefficients, re-judged on the static windows plus one
    candidate window each.
    """
    obs = document.get("observability") or {}
    unseeable = [
        h for h in obs.get("held", []) if isinstance(h, dict) and "rotation" in h.get("reason", "")
    ]
    rotation_names = {
        word.split("*", 1)[1] for h in unseeable for word in h.get("direction", "").split()
        if "*" in word
    }  # fmt: skip
    held = [n for n, s in _flat_status(document.get("status") or {}).items() if s == "held"]
    partial = [n for n in obs.get("partially_held", []) if isinstance(n, str)]
    weak = [n for n in dict.fromkeys(held + partial) if n not in rotation_names]
    out: dict[str, Any] = {"unseeable": unseeable, "weak": weak, "suggestions": [],
                           "unresolved": list(weak)}  # fmt: skip
    if not weak or not positions.has_accel:
        return out
    coeffs = CoefficientSet.from_json_dict(document.get("coefficients") or {})
    sensors = tuple(s for s in ("gyro", "accel") if getattr(positions, f"has_{s}")
                    and coeffs.values.get(f"{s}.scale") is not None)  # fmt: skip
    models = build_models(sensors, (), (), float(coeffs.t0_c))
    layout = ParameterLayout(models)
    names = layout.names
    theta = coeffs.to_vector(layout)
    lat, h = float(document.get("latitude_deg", 45.0)), float(document.get("height_m", 0.0))
    targets = [names.index(n) for n in weak if n in names]
    base = _shares(positions, models, theta, lat, h)
    cols = positions.columns
    pinned: set[str] = set()
    for label, down in CANDIDATES:
        row = _candidate_row(positions, models, theta, layout, np.array(down), lat, h)
        extended = Positions.from_columns(
            {n: np.concatenate([cols[n], row[n]]) for n in row}, source="candidate"
        )
        share = _shares(extended, models, theta, lat, h)
        pins = [names[i] for i in targets if share[i] >= SEEN_SHARE > base[i]]
        if pins:
            out["suggestions"].append({"orientation": label, "pins": pins})
            pinned.update(pins)
    out["unresolved"] = [n for n in weak if n not in pinned]
    return out
