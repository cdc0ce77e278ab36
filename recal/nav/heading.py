"""The gyrocompass heading error a calibration leaves, in the units a navigator uses.

A gyrocompass, and the alignment of an INS at rest (:mod:`recal.nav.alignment`), finds north as
the direction of the horizontal Earth rate, Omega_ie cos(latitude). A gyro error along east
(``b_east``, deg/h) turns that direction, and the heading with it, by::

    heading error = b_east / (Omega_ie cos latitude)        (rad; Omega_ie = 15.04107 deg/h)

0.01 deg/h at 45 deg latitude: 0.054 deg (3.2 arcmin); shared/spec/vessel.md.

**Hull-fixed unit.** Which body direction points east depends on the heading, and a hull-fixed
IMU turns with the vessel: ``b_east(h) = e(h) . b`` with ``e(h)`` a unit vector of the body's
horizontal plane (perpendicular to the vertical axis ``u``) that turns with the heading ``h``.
With ``C`` the 2 x 2 covariance of the horizontal bias (the 3 x 3 gyro bias covariance projected
on that plane), the east bias's variance at heading ``h`` is ``e(h)' C e(h)``, so over all
headings:

* **worst case**: ``sqrt(largest eigenvalue of C)``, the heading that looks along the worst
  determined horizontal direction;
* **RMS over headings**: ``sqrt(trace(C) / 2)``.

Both are 1-sigma figures (the bias's uncertainty, not a bias estimate). Only the gyro biases are
counted: a scale or misalignment error ``d`` (rad, relative) adds of order ``d`` (plus
``d tan(latitude)`` from the vertical rate), e.g. 100 ppm -> 0.006 deg, and varies with the
heading in a way a bias does not.

The vertical axis is given in body coordinates (either sign: z down or z up give the same
horizontal plane). By default the unit is level (``u = z``); :func:`vertical_from_specific_force`
takes it from the windows' mean gravity direction instead.

Near the poles the horizontal Earth rate vanishes and a gyrocompass does not settle: beyond
:data:`MAX_LATITUDE_DEG` the figure is refused (:class:`recal.errors.RecalInputError`).

Pure numerics: arrays in, figures out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.reference import OMEGA_IE_DEG_H

#: Beyond this latitude (deg, either hemisphere) the horizontal Earth rate is under 9 % of the
#: equator's and every 0.01 deg/h is 0.6 deg of heading or more: no gyrocompass figure is given.
MAX_LATITUDE_DEG = 85.0
#: The level mounting (z down or z up): the default vertical axis in body coordinates.
LEVEL = (0.0, 0.0, 1.0)


def horizontal_earth_rate_deg_h(latitude_deg: float) -> float:
    """Omega_ie cos(latitude) in deg/h; refuses |latitude| beyond :data:`MAX_LATITUDE_DEG`."""
    lat = float(latitude_deg)
    if not math.isfinite(lat) or abs(lat) > 90.0:
        raise RecalInputError(f"latitude {latitude_deg} deg is outside [-90, 90]")
    if abs(lat) > MAX_LATITUDE_DEG:
        rate = OMEGA_IE_DEG_H * math.cos(math.radians(lat))
        raise RecalInputError(
            f"latitude {lat:g} deg: the horizontal Earth rate is only {rate:.2g} deg/h there, so "
            f"a gyrocompass does not settle and no heading error figure is given beyond "
            f"+-{MAX_LATITUDE_DEG:g} deg"
        )
    return OMEGA_IE_DEG_H * math.cos(math.radians(lat))


def heading_error_deg(east_bias_deg_h: float | np.ndarray, latitude_deg: float) -> Any:
    """Gyrocompass heading error (deg) an east gyro bias (deg/h) leaves at ``latitude_deg``."""
    rate = horizontal_earth_rate_deg_h(latitude_deg)
    return np.degrees(np.asarray(east_bias_deg_h, float) / rate)


def unit_vertical(vertical: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
    """The vertical axis in body coordinates as a unit vector (None: level, z)."""
    u = np.asarray(LEVEL if vertical is None else vertical, float).reshape(-1)
    norm = float(np.linalg.norm(u)) if u.size == 3 else 0.0
    if not (math.isfinite(norm) and norm > 0):
        raise RecalInputError(f"the vertical axis must be a non-zero 3-vector, not {vertical!r}")
    return u / norm


def vertical_from_specific_force(specific_force: np.ndarray) -> np.ndarray:
    """The vertical axis (unit, body coordinates, pointing up) from the windows' mean specific
    force ``(M, 3)`` (any units): the mean of the per-window directions, so a few long windows
    do not outweigh the rest."""
    f = np.asarray(specific_force, float).reshape(-1, 3)
    norms = np.linalg.norm(f, axis=1)
    good = np.isfinite(norms) & (norms > 0)
    if not good.any():
        raise RecalInputError("no window with a specific force to take the vertical from")
    mean = (f[good] / norms[good, None]).mean(axis=0)
    return unit_vertical(mean)


def horizontal_basis(vertical: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
    """(3, 2): two orthonormal body vectors spanning the plane perpendicular to ``vertical``."""
    u = unit_vertical(vertical)
    seed = np.eye(3)[int(np.argmin(np.abs(u)))]  # the body axis farthest from the vertical
    e1 = seed - u * (seed @ u)
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(u, e1)])


@dataclass(frozen=True)
class HeadingError:
    """1-sigma gyrocompass heading error over all headings of a hull-fixed unit, and the east
    gyro bias behind it."""

    latitude_deg: float
    worst_deg: float
    rms_deg: float
    east_bias_worst_deg_h: float
    east_bias_rms_deg_h: float

    def to_json_dict(self) -> dict[str, float]:
        return {
            "heading_error_deg_worst": self.worst_deg,
            "heading_error_deg_rms": self.rms_deg,
            "east_bias_deg_h_worst": self.east_bias_worst_deg_h,
            "east_bias_deg_h_rms": self.east_bias_rms_deg_h,
        }


def heading_error(
    bias_covariance_deg_h2: np.ndarray,
    latitude_deg: float,
    vertical: Sequence[float] | np.ndarray | None = None,
) -> HeadingError:
    """The heading error the gyro biases' uncertainty leaves (module doc).

    ``bias_covariance_deg_h2``: (3, 3) covariance of the gyro biases x, y, z ((deg/h)^2), or
    (3,) 1-sigmas (deg/h, independent); ``vertical``: the vertical axis in body coordinates
    (None: level).
    """
    c = np.asarray(bias_covariance_deg_h2, float)
    if c.shape == (3,):
        c = np.diag(c * c)
    if c.shape != (3, 3) or not np.all(np.isfinite(c)):
        raise RecalInputError(
            f"the gyro bias covariance must be 3 x 3 (or 3 sigmas) and finite, not {c.shape}"
        )
    rate = horizontal_earth_rate_deg_h(latitude_deg)
    E = horizontal_basis(vertical)
    ch = E.T @ (0.5 * (c + c.T)) @ E
    worst = math.sqrt(max(float(np.linalg.eigvalsh(ch)[-1]), 0.0))
    rms = math.sqrt(max(float(np.trace(ch)) / 2.0, 0.0))
    return HeadingError(
        float(latitude_deg), math.degrees(worst / rate), math.degrees(rms / rate), worst, rms
    )


def bias_covariance(term_slices: Mapping[str, slice], covariance: np.ndarray) -> np.ndarray:
    """The (3, 3) ``gyro.bias`` block of a fit's flat covariance (``layout.term_slices()``)."""
    sl = term_slices.get("gyro.bias")
    if sl is None:
        raise RecalInputError("no gyro biases in this calibration: no heading error figure")
    cov = np.asarray(covariance, float)
    return cov[sl, sl]


@dataclass(frozen=True)
class HeadingChange:
    """The heading error before (the prior's uncertainty) and after (the result's)."""

    after: HeadingError
    before: HeadingError | None
    vertical: tuple[float, float, float]

    def sentence(self) -> str:
        a = self.after
        text = (
            f"gyrocompass heading error (1 sigma, from the horizontal gyro biases) "
            f"{a.rms_deg:.3g} deg RMS over headings, {a.worst_deg:.3g} deg at the worst heading, "
            f"at {a.latitude_deg:.1f} deg latitude"
        )
        if self.before is not None:
            b = self.before
            text += f" (before: {b.rms_deg:.3g} deg RMS, {b.worst_deg:.3g} deg worst)"
        return text


def heading_change(
    term_slices: Mapping[str, slice],
    covariance: np.ndarray,
    prior_sigma: np.ndarray | None,
    latitude_deg: float,
    vertical: Sequence[float] | np.ndarray | None = None,
) -> HeadingChange:
    """After: from the fit's covariance (the held part included); before: from the prior's
    1-sigma per flat parameter ``prior_sigma`` (D,), taken as independent (None: unknown)."""
    u = unit_vertical(vertical)
    after = heading_error(bias_covariance(term_slices, covariance), latitude_deg, u)
    before = None
    if prior_sigma is not None:
        s = np.asarray(prior_sigma, float)[term_slices["gyro.bias"]]
        if np.all(np.isfinite(s)):
            before = heading_error(s, latitude_deg, u)
    return HeadingChange(after, before, (float(u[0]), float(u[1]), float(u[2])))
