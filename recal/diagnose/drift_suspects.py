"""After an alarm, which coefficient the step looks like and how large it is (the suspects,
docs/drift.md), described in the units a reader expects ("gyro x scale, about +600 ppm")."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from recal.diagnose.drift_glr import score


def suspects(
    names: Sequence[str],
    theta: np.ndarray,
    S: np.ndarray,
    F: np.ndarray,
    Lp: np.ndarray,
    n: int,
    tau: int,
    seen: np.ndarray,
    top: int = 3,
) -> list[dict[str, Any]]:
    """The coefficients (flat ``names``, accepted values ``theta``) a step at ``tau`` seen at
    window ``n`` looks like, best first; "alike"
    marks those whose ratio is within 10 % of the best (the windows cannot tell them apart)."""
    z, info = score(S, F, Lp, n, np.array([tau]))
    z, info = z[0], info[0]
    ok = seen & (info > 1e-12 * max(info.max(), 1e-300))
    ratio = np.where(ok, z * z / np.where(ok, info, 1.0), 0.0)
    out = []
    for j in np.argsort(-ratio)[:top]:
        if not ok[j]:
            continue
        size = z[j] / info[j]
        out.append({
            "coefficient": names[j],
            "statistic": float(ratio[j]),
            "change": float(size),
            "sigma": float(1.0 / np.sqrt(info[j])),
            "change_window": int(tau),
            "description": describe_change(names[j], size, theta[j]),
            "alike": bool(ratio[j] >= 0.9 * ratio.max()),
            "window": int(n),
        })  # fmt: skip
    return out


def describe_change(name: str, change: float, value: float) -> str:
    """'gyro x scale, about +600 ppm' for a step ``change`` of flat coefficient ``name``."""
    sensor, term, param = (name.split(".") + ["", ""])[:3]
    axis = param[-1] if param[-1:] in "xyz" else ""
    if term == "scale":
        return f"{sensor} {axis} scale, about {change / value * 1e6:+.3g} ppm"
    if term == "bias" and sensor == "accel":
        return f"accel {axis} bias, about {change * 1e6:+.3g} micro-g"
    if term == "bias":
        return f"gyro {axis} bias, about {change:+.3g} deg/h"
    if term == "misalignment":
        return f"{sensor} misalignment {param}, about {change * 1e6:+.3g} micro-rad"
    if term == "quadratic":
        return f"accel {axis} quadratic, about {change * 1e6:+.3g} micro-g/g^2"
    return f"{name}, about {change:+.3g}"
