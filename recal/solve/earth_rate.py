"""Whether a gyro can see Earth rate in its still windows: the contrast of its outputs between
positions against the window-mean noise (:data:`MIN_EARTH_RATE_CONTRAST`), why not and what
would be needed (:func:`earth_rate_invisible`), and the noise that pins its scale factors
(:func:`scale_noise_needed`). :func:`recal.solve.calibrate` leaves a gyro out, or calibrates it
from the slews, when it cannot."""

from __future__ import annotations

import numpy as np

from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H

#: Position-to-position spread of the gyro outputs, in window-noise units, below which Earth
#: rate is not visible (a navigation FOG shows thousands, a KVH-class FOG hundreds; the MEMS
#: recording in ../shared shows 25, from bias instability, not Earth rate).
MIN_EARTH_RATE_CONTRAST = 50.0


def scale_noise_needed(n_positions: int, relative: float = 1e-3) -> float:
    """Window-mean gyro noise, deg/h, that pins each scale factor to ``relative`` from
    ``n_positions`` random orientations.

    d|w|/d(ln K_i) = -Omega u_i^2; for uniform directions the information matrix
    (Omega / sigma)^2 sum u_i^2 u_j^2 has an inverse diagonal of 6 / M, so
    sd(ln K_i) ~ sigma / Omega * sqrt(6 / M). Estimating bias and misalignment alongside costs
    about a factor 2 (checked against :func:`recal.solve.observability.analyze`), hence sqrt(M / 24).
    """
    return relative * OMEGA_IE_DEG_H * np.sqrt(n_positions / 24.0)


def earth_rate_invisible(positions: Positions, scale: np.ndarray | None = None) -> str | None:
    """Why Earth rate cannot calibrate this gyro, or None: the outputs must change with
    orientation well beyond the window-mean noise.

    The reason names the cause -- the contrast, the noise and the hold length -- and what would
    be needed: the noise of a window mean falls as 1/sqrt(hold) (white noise), so the contrast
    grows as sqrt(hold). ``scale`` (output units per deg/h, e.g. from the prior) expresses the
    noise in deg/h and gives the hold that pins the scale factors to their typical change;
    without it the noise stays in output units.
    """
    seen = positions.gyro_contrast()
    if seen is None:
        return None
    contrast, axis = seen
    sem = np.maximum(np.median(positions.std_of_mean("gyro"), axis=0), 1e-300)
    if contrast >= MIN_EARTH_RATE_CONTRAST:
        return None
    gain = 1.0 if scale is None else abs(float(np.asarray(scale, float)[axis]))
    unit = "output units" if scale is None else "deg/h"
    noise_in = sem[axis] / gain
    cols = positions.columns
    hold = (
        float(np.median(cols["end_s"] - cols["start_s"]))
        if "start_s" in cols and "end_s" in cols
        else None
    )

    def holds_for(factor: float) -> str:  # white noise: sigma ~ 1/sqrt(hold)
        return (
            f"holds about {factor:.3g}x longer"
            if hold is None
            else f"holds of about {hold * factor:.3g} s"
        )

    M = len(positions)
    pinned = scale_noise_needed(M)
    visible = holds_for((MIN_EARTH_RATE_CONTRAST / contrast) ** 2)
    then = f"pinning the scale factors to 1000 ppm from {M} positions then needs a window-mean noise of about {pinned:.2g} deg/h"
    if scale is not None:
        then += f" ({holds_for((noise_in / pinned) ** 2)})"
    caveat = (
        " if the noise averages down" if positions.noise_source("gyro") == "sem columns" else ""
    )
    return (
        f"gyro outputs differ between positions by only {contrast:.3g}x the window-mean noise "
        f"({noise_in:.3g} {unit}" + ("" if hold is None else f" from {hold:.3g} s holds") + "): "
        f"Earth rate ({OMEGA_IE_DEG_H:.5f} deg/h) is not visible; it needs "
        f"{MIN_EARTH_RATE_CONTRAST:.0f}x: {visible} at this noise{caveat}; {then}"
    )
