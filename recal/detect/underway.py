"""Underway: a window taken while the ship moves over the Earth, and what its motion costs.

A ship under way carries its navigation frame over the Earth's surface, so even a hull held
perfectly steady turns in space at the transport rate (shared/spec/vessel.md, "At anchor and
underway"):

    w_en = (v_E / R, -v_N / R, -v_E tan(lat) / R)        (north, east, down; R = 6.378e6 m)

At 1 kn (0.514 m/s) its size is 8.1e-8 rad/s = 0.0166 deg/h, times up to 1 + |tan lat|
(0.033 deg/h at 45 deg, 0.045 at 60): about the white noise of a 5-minute window of a KVH
1750-class FOG (ARW 0.012 deg/sqrt(h): 0.046 deg/h through the hull detector's weights). At
10 kn it is ten times that, larger than the biases a navigation-grade FOG is calibrated to;
the Coriolis and Eotvos accelerations (2 Omega v: up to 7.7 ug per knot) and the ship's small speed
and heading changes reach the accelerometers too. So:

* a window whose mean speed over ground exceeds ``max_sog_kn`` (:data:`DEFAULT_MAX_SOG_KN`,
  1 kn: well above what a moored or anchored ship's receiver reads, a few tenths of a knot of
  swing and noise) is rejected with the reason :data:`UNDERWAY`;
* below it, the transport rate the window's *net displacement* implies, |d| / (R T) (1 +
  |tan lat|) rad/s, is added in quadrature to each axis of the window's gyro standard error, in
  the gyro's output units (the axis it falls on is unknown: every axis carries the bound). A
  ship swinging at anchor moves at tenths of a knot but ends a window close to where it began:
  its net displacement, not its speed, is what the window's mean rate holds.

:func:`underway_rule` is the rule (pure numpy), used by the daemon and ``recal positions
--nmea`` alike; :func:`ship_columns` writes its result into a positions table. A window's ship
state is anything with ``latitude_deg``, ``sog_kn``, ``heading_deg``, ``displacement_m`` and
``duration_s`` (the service's ``drivers.nmea.NavWindow``); None where the ship's sensors did not
cover the window (no columns, no rejection, no inflation).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from recal.model.positions import GYRO_SEM_COLUMNS, SHIP_COLUMNS

#: The rejection reason of a window taken under way (counted like the rest check's reasons).
UNDERWAY = "underway"
#: Default largest mean speed over ground of a window, kn (see the module docstring).
DEFAULT_MAX_SOG_KN = 1.0
#: Earth's radius in the transport rate, m (WGS-84 semi-major axis; the spec's R = 6.38e6 m).
EARTH_RADIUS_M = 6378137.0
#: The latitude the tan(lat) factor is evaluated at most (a ship at the pole has no east).
MAX_LATITUDE_DEG = 89.0
_RAD_S_TO_DEG_H = math.degrees(1.0) * 3600.0


class ShipOverWindow(Protocol):
    """What the rule needs to know of the ship over one window (means; metres; seconds)."""

    latitude_deg: float
    sog_kn: float
    heading_deg: float
    duration_s: float

    @property
    def displacement_m(self) -> float: ...


@dataclass(frozen=True, eq=False)
class UnderwayRule:
    """The rule's verdict on n windows: ``reasons`` (n,) ``"underway"`` or ``""`` (kept, or
    no ship state); ``transport_dph`` (n,) the bound on the transport rate (deg/h, 0 without a
    ship state); ``gyro_sem_out`` (n, 3) that bound per axis in the gyro's output units, to add
    in quadrature; ``max_sog_kn`` the threshold used."""

    reasons: np.ndarray
    transport_dph: np.ndarray
    gyro_sem_out: np.ndarray
    max_sog_kn: float

    @property
    def kept(self) -> np.ndarray:
        return self.reasons == ""

    @property
    def rejected(self) -> int:
        return int(np.sum(self.reasons == UNDERWAY))


def transport_rate_bound_dph(
    displacement_m: float, duration_s: float, latitude_deg: float
) -> float:
    """|d| / (R T) (1 + |tan lat|) in deg/h: the largest transport rate a net displacement of
    ``displacement_m`` over ``duration_s`` gives on any axis (0 for a window of no length)."""
    if not (duration_s > 0 and math.isfinite(displacement_m)):
        return 0.0
    lat = (
        math.radians(min(abs(latitude_deg), MAX_LATITUDE_DEG))
        if math.isfinite(latitude_deg)
        else 0.0
    )
    rate = abs(displacement_m) / (EARTH_RADIUS_M * duration_s) * (1.0 + math.tan(lat))
    return rate * _RAD_S_TO_DEG_H


def underway_rule(
    ships: Sequence[ShipOverWindow | None],
    max_sog_kn: float = DEFAULT_MAX_SOG_KN,
    gyro_units_per_dph: Any = 1.0,
) -> UnderwayRule:
    """Judge each window by its ship state (see the module docstring): ``underway`` where the
    mean speed over ground exceeds ``max_sog_kn``; elsewhere the transport-rate bound of its
    net displacement, per axis in output units (``gyro_units_per_dph``: the gyro's scale K,
    scalar or (3,), output units per deg/h; 1 for a unit that outputs deg/h)."""
    n = len(ships)
    reasons = np.full(n, "", dtype=object)
    transport = np.zeros(n)
    for i, ship in enumerate(ships):  # a loop over windows (tens a day), not samples
        if ship is None:
            continue
        sog = float(ship.sog_kn)
        if math.isfinite(sog) and sog > max_sog_kn:
            reasons[i] = UNDERWAY
            continue
        transport[i] = transport_rate_bound_dph(
            float(ship.displacement_m), float(ship.duration_s), float(ship.latitude_deg)
        )
    scale = np.abs(np.broadcast_to(np.asarray(gyro_units_per_dph, dtype=float), (3,)))
    return UnderwayRule(reasons, transport, transport[:, None] * scale[None, :], float(max_sog_kn))


def ship_columns(
    columns: dict[str, np.ndarray],
    ships: Sequence[ShipOverWindow | None],
    rule: UnderwayRule,
) -> dict[str, np.ndarray]:
    """``columns`` (a positions table of the windows ``ships`` describe, in order) with the
    ship's columns (:data:`recal.model.positions.SHIP_COLUMNS`, NaN where a window has no ship
    state; none at all when no window has one) and the gyro standard errors grown by the
    transport-rate bound in quadrature (a new dict; the arrays given are not changed)."""
    out = dict(columns)
    if not any(s is not None for s in ships):
        return out
    for name in SHIP_COLUMNS:
        out[name] = np.array(
            [math.nan if s is None else float(getattr(s, name)) for s in ships], dtype=float
        )
    if all(c in out for c in GYRO_SEM_COLUMNS):
        for j, name in enumerate(GYRO_SEM_COLUMNS):
            out[name] = np.hypot(np.asarray(out[name], dtype=float), rule.gyro_sem_out[:, j])
    return out


def count_rejections(report: Any, windows: Sequence[Any], reasons: Sequence[str]) -> None:
    """Count the windows the rule rejected in a detector's report, as its other reasons: the
    static detector's (``add_rest_rejections``) or the hull detector's (``rejected`` counter,
    ``rejected_stretches``, ``kept``)."""
    rejected = [(w, r) for w, r in zip(windows, reasons, strict=True) if r]
    if not rejected or report is None:
        return
    if hasattr(report, "add_rest_rejections"):
        report.add_rest_rejections(windows, list(reasons))
        return
    for w, r in rejected:
        report.rejected[r] += 1
        report.rejected_stretches.append((w.start_s, w.end_s, str(r)))
    report.kept -= len(rejected)
