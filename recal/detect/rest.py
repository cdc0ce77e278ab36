"""At rest in physics: what a still unit must read, and whether a window's means agree.

A moving-variance test cannot see a steady turn (the rate is constant) or a slow swing; physics
can. At rest the gyro triad measures Earth's rate and the accelerometer triad local gravity,
whatever the orientation (docs/reference.md#rest). A window is at rest only if the norm of its
mean rate is Earth's rate, and the norm of its mean specific force is gravity, within

* the window's own noise (``k_sigma`` standard errors of the norm), and
* the plausible range of the unit's coefficients: ``k_coeff`` times the prior's 1-sigma (or the
  sensor class's default, :data:`recal.solve.consider.DEFAULT_PRIOR_SIGMA`), applied to the
  norm: a scale error moves it by s |w|, a bias by up to sqrt(3) b, a misalignment by E |w|.

A window that fails is rejected with a reason of its own (:data:`REST_REASONS`): ``turning`` (the
excess rate lies mostly along gravity: a heading change), ``swinging`` (about a horizontal axis:
a net roll or pitch change), ``rate_low`` (less than Earth's rate: no motion does that; a unit or
rate setting is wrong, or the window is not what it seems), ``accelerating`` (the specific force
is not gravity: heave, surge, a crane, a vehicle). Pure numpy; used by the static detector
(:mod:`recal.detect.static_detector`) and the hull detector (:mod:`recal.detect.hull`) alike, so
``recal positions`` and the daemon share the one rule.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from recal.detect.windows import Window
from recal.model.coefficients import CoefficientSet
from recal.model.reference import OMEGA_IE_DEG_H, normal_gravity_g

#: Rejection reasons a rest check can give, in the order the reports list them.
REST_REASONS = ("turning", "swinging", "rate_low", "accelerating")

#: A navigation-class unit in service without a prior, 1-sigma: relative scale, gyro bias deg/h,
#: misalignment rad, accel bias g. recal.solve.consider's "navigation" class, except the gyro
#: bias: its 0.05 deg/h is how far a held bias moves between two calibrations, while a unit of
#: unknown history (a KVH 1750's turn-on bias, a simulated kvh_like_truth: up to 0.5 deg/h) can
#: sit further from zero. The check's bound, five times these, is then 4.3 deg/h on the rate norm:
#: a turn is at least 360 deg/h.
_NAV_SCALE, _NAV_GYRO_BIAS_DPH, _NAV_MISALIGNMENT, _NAV_ACCEL_BIAS_G = 1e-3, 0.5, 1e-3, 1e-3


@dataclass(frozen=True)
class RestReference:
    """What a still unit reads and how far its coefficients may be off.

    gyro_scale / accel_scale: (3,) output units per deg/h and per g (K); gyro_bias_dph /
    accel_bias_g: (3,) the biases b in input units. The ``*_sigma`` fields are 1-sigma: relative
    for the scales, deg/h and g for the biases, rad for the misalignments. earth_rate_dph and
    gravity_g are the references at the latitude and height.
    """

    earth_rate_dph: float
    gravity_g: float
    gyro_scale: np.ndarray
    gyro_bias_dph: np.ndarray
    accel_scale: np.ndarray
    accel_bias_g: np.ndarray
    scale_sigma: float = _NAV_SCALE
    gyro_bias_sigma_dph: float = _NAV_GYRO_BIAS_DPH
    accel_bias_sigma_g: float = _NAV_ACCEL_BIAS_G
    misalignment_sigma: float = _NAV_MISALIGNMENT
    source: str = "navigation-class defaults"
    #: how far gravity itself may be off gravity_g (g): the latitude is not known
    gravity_unknown_g: float = 0.0
    k_coeff: float = 5.0
    k_sigma: float = 5.0
    #: where the unit is (deg), for the vertical and horizontal parts of Earth's rate; None:
    #: unknown (the rest check then judges the rate's norm only)
    latitude_deg: float | None = None

    @classmethod
    def nominal(
        cls,
        latitude_deg: float,
        height_m: float = 0.0,
        gyro_units_per_dph: float = 1.0,
        accel_units_per_g: float = 1.0,
    ) -> RestReference:
        """A unit that outputs physical units (a KVH: deg/h and g), no prior: K nominal, b = 0,
        the navigation class's 1-sigma."""
        return cls(
            earth_rate_dph=OMEGA_IE_DEG_H,
            gravity_g=normal_gravity_g(latitude_deg, height_m),
            gyro_scale=np.full(3, float(gyro_units_per_dph)),
            gyro_bias_dph=np.zeros(3),
            accel_scale=np.full(3, float(accel_units_per_g)),
            accel_bias_g=np.zeros(3),
            latitude_deg=float(latitude_deg),
        )

    @classmethod
    def from_coefficients(
        cls, coeffs: CoefficientSet, latitude_deg: float, height_m: float = 0.0
    ) -> RestReference:
        """From a prior (a previous calibration) and its ``uncertainty`` where it has one; the
        navigation class's 1-sigma for what it lacks."""
        v, u = coeffs.values, getattr(coeffs, "uncertainty", None) or {}

        def largest(name: str, default: float, relative_to: str | None = None) -> float:
            s = u.get(name)
            if s is None:
                return default
            s = np.abs(np.asarray(s, float))
            if relative_to is not None:
                s = s / np.abs(np.asarray(v[relative_to], float))
            s = s[np.isfinite(s)]
            return float(s.max()) if s.size else default

        gyro_k = np.asarray(v.get("gyro.scale", np.ones(3)), float)
        accel_k = np.asarray(v.get("accel.scale", np.ones(3)), float)
        scale_sigma = (
            max(
                largest("gyro.scale", _NAV_SCALE, "gyro.scale") if "gyro.scale" in v else 0.0,
                largest("accel.scale", _NAV_SCALE, "accel.scale") if "accel.scale" in v else 0.0,
            )
            or _NAV_SCALE
        )
        return cls(
            earth_rate_dph=OMEGA_IE_DEG_H,
            gravity_g=normal_gravity_g(latitude_deg, height_m),
            gyro_scale=gyro_k,
            gyro_bias_dph=np.asarray(v.get("gyro.bias", np.zeros(3)), float),
            accel_scale=accel_k,
            accel_bias_g=np.asarray(v.get("accel.bias", np.zeros(3)), float),
            scale_sigma=scale_sigma,
            gyro_bias_sigma_dph=largest("gyro.bias", _NAV_GYRO_BIAS_DPH),
            accel_bias_sigma_g=largest("accel.bias", _NAV_ACCEL_BIAS_G),
            misalignment_sigma=max(
                largest("gyro.misalignment", _NAV_MISALIGNMENT),
                largest("accel.misalignment", _NAV_MISALIGNMENT),
            ),
            source=str(coeffs.metadata.get("source", "the prior"))
            if coeffs.metadata
            else "the prior",
            latitude_deg=float(latitude_deg),
        )

    def at_unknown_latitude(self) -> RestReference:
        """The same with gravity anywhere between the equator's and the pole's (at sea level):
        the reference is their mean and the tolerance grows by half their difference."""
        g_eq, g_pole = normal_gravity_g(0.0, 0.0), normal_gravity_g(90.0, 0.0)
        return replace(
            self, gravity_g=0.5 * (g_eq + g_pole), gravity_unknown_g=0.5 * (g_pole - g_eq),
            latitude_deg=None,
        )  # fmt: skip

    def earth_rate_parts_dph(self) -> tuple[float, float]:
        """Earth's rate along the local vertical (up) and across it, deg/h; NaN where the
        latitude is unknown."""
        if self.latitude_deg is None:
            return math.nan, math.nan
        phi = math.radians(self.latitude_deg)
        return self.earth_rate_dph * math.sin(phi), self.earth_rate_dph * math.cos(phi)

    # ---- output units -> physics ----------------------------------------------------------
    def rate_dph(self, gyro_out: np.ndarray) -> np.ndarray:
        """Output (..., 3) -> angular rate, deg/h (scale and bias only)."""
        return np.asarray(gyro_out, float) / self.gyro_scale - self.gyro_bias_dph

    def force_g(self, accel_out: np.ndarray) -> np.ndarray:
        """Output (..., 3) -> specific force, g (scale and bias only)."""
        return np.asarray(accel_out, float) / self.accel_scale - self.accel_bias_g

    def rate_tolerance_dph(self) -> float:
        """How far the norm of the rate may be off Earth's rate from the coefficients alone."""
        w = self.earth_rate_dph
        return self.k_coeff * math.sqrt(
            (self.scale_sigma * w) ** 2 + 3.0 * self.gyro_bias_sigma_dph**2
            + (self.misalignment_sigma * w) ** 2
        )  # fmt: skip

    def force_tolerance_g(self) -> float:
        """The same for the specific force's norm against gravity."""
        g = self.gravity_g
        return self.gravity_unknown_g + self.k_coeff * math.sqrt(
            (self.scale_sigma * g) ** 2 + 3.0 * self.accel_bias_sigma_g**2
            + (self.misalignment_sigma * g) ** 2
        )  # fmt: skip

    # ---- the test -------------------------------------------------------------------------
    def judge(
        self,
        gyro_out: np.ndarray | None,
        accel_out: np.ndarray | None,
        gyro_sem_out: np.ndarray | None = None,
        accel_sem_out: np.ndarray | None = None,
        extra_rate_dph: np.ndarray | float = 0.0,
        vertical_allowance_dph: np.ndarray | float = 0.0,
    ) -> np.ndarray:
        """One reason per window (``""`` where it is at rest), windows along axis 0.

        gyro_out / accel_out: (n, 3) window means in output units (either may be None);
        *_sem_out: (n, 3) their standard errors (NaN or None: noise not known, coefficients
        only). ``extra_rate_dph``: an allowance the caller adds to the rate tolerance (n,) or
        scalar, deg/h. ``vertical_allowance_dph`` (n,) or scalar: how far the rate along
        gravity may be off Earth's vertical rate, deg/h, beyond the tolerance: a hull's heading
        creep or anchor swing, which the vertical rate cannot tell from a bias and which the
        fit then leaves out (column ``gyro_vertical``, :mod:`recal.detect.creep`). Where it is
        non-zero (and the latitude and the specific force are known), the rate is judged in
        its two parts: across gravity against Earth's horizontal rate, along it within the
        allowance; otherwise by its norm.
        """
        n = len(gyro_out) if gyro_out is not None else len(accel_out)  # type: ignore[arg-type]
        reason = np.full(n, "", dtype=object)
        if accel_out is not None:
            f = self.force_g(accel_out)
            fn = np.linalg.norm(f, axis=1)
            sem = _norm_sem(f, fn, accel_sem_out, self.accel_scale)
            bad = np.abs(fn - self.gravity_g) > (self.force_tolerance_g() + self.k_sigma * sem)
            reason[bad] = "accelerating"
        if gyro_out is None:
            return reason
        allowance = np.broadcast_to(np.asarray(vertical_allowance_dph, float), (n,))
        extra = np.broadcast_to(np.asarray(extra_rate_dph, float), (n,))
        split = allowance > 0
        if accel_out is None or self.latitude_deg is None:
            split = np.zeros(n, dtype=bool)
        gyro_out = np.asarray(gyro_out, float)
        gs = None if gyro_sem_out is None else np.asarray(gyro_sem_out, float)
        for part, judge in ((split, self._judge_in_parts), (~split, self._judge_norm)):
            if not part.any():
                continue
            got = judge(
                gyro_out[part], None if accel_out is None else np.asarray(accel_out)[part],
                None if gs is None else gs[part], extra[part], allowance[part],
            )  # fmt: skip
            reason[part] = np.where(reason[part] == "", got, reason[part])
        return reason

    def _judge_norm(
        self,
        gyro_out: np.ndarray,
        accel_out: np.ndarray | None,
        gyro_sem_out: np.ndarray | None,
        extra_rate_dph: np.ndarray,
        allowance_dph: np.ndarray,
    ) -> np.ndarray:
        """The rate judged by its norm against Earth's rate (:meth:`judge`)."""
        n = len(gyro_out)
        reason = np.full(n, "", dtype=object)
        w = self.rate_dph(gyro_out)
        wn = np.linalg.norm(w, axis=1)
        sem = _norm_sem(w, wn, gyro_sem_out, self.gyro_scale)
        tol = self.rate_tolerance_dph() + self.k_sigma * sem + extra_rate_dph
        high = wn - self.earth_rate_dph > tol
        low = self.earth_rate_dph - wn > tol
        if high.any():
            # Which way the excess points: along gravity (a heading change) or across it.
            if accel_out is not None:
                up = self.force_g(accel_out)
                up = up / np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-12)
                vertical = np.abs(np.sum(w * up, axis=1))
                horizontal = np.sqrt(np.maximum(wn**2 - vertical**2, 0.0))
                # Earth's rate has both parts; the one that exceeds it names the motion
                turning = vertical >= horizontal
            else:
                turning = np.ones(n, dtype=bool)
            reason[high & turning] = "turning"
            reason[high & ~turning] = "swinging"
        reason[low & (reason == "")] = "rate_low"
        return reason

    def _judge_in_parts(
        self,
        gyro_out: np.ndarray,
        accel_out: np.ndarray,
        gyro_sem_out: np.ndarray | None,
        extra_rate_dph: np.ndarray,
        allowance_dph: np.ndarray,
    ) -> np.ndarray:
        """The rate judged across and along gravity (:meth:`judge`'s ``vertical_allowance_dph``):
        "turning" where the vertical part is off Earth's by more than the allowance and the
        tolerance, "swinging" or "rate_low" where the horizontal part is off Earth's."""
        w = self.rate_dph(gyro_out)
        up = self.force_g(accel_out)
        up = up / np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-12)
        vertical = np.sum(w * up, axis=1)
        w_h = w - vertical[:, None] * up
        h = np.linalg.norm(w_h, axis=1)
        v_e, h_e = self.earth_rate_parts_dph()
        s = (
            np.zeros_like(w) if gyro_sem_out is None
            else np.where(np.isfinite(gyro_sem_out), gyro_sem_out, 0.0) / np.abs(self.gyro_scale)
        )  # fmt: skip
        sem_v = np.sqrt(np.sum((up * s) ** 2, axis=1))
        u_h = w_h / np.maximum(h, 1e-300)[:, None]
        sem_h = np.sqrt(np.sum((u_h * s) ** 2, axis=1))
        tol = self.rate_tolerance_dph() + extra_rate_dph
        reason = np.full(len(w), "", dtype=object)
        reason[np.abs(vertical - v_e) > allowance_dph + tol + self.k_sigma * sem_v] = "turning"
        off_h = h - h_e
        band = tol + self.k_sigma * sem_h
        reason[(off_h > band) & (reason == "")] = "swinging"
        reason[(-off_h > band) & (reason == "")] = "rate_low"
        return reason


def _norm_sem(
    v: np.ndarray, vn: np.ndarray, sem_out: np.ndarray | None, scale: np.ndarray
) -> np.ndarray:
    """Standard error of |v| from per-axis standard errors (output units -> input units)."""
    if sem_out is None:
        return np.zeros(len(v))
    s = np.asarray(sem_out, float) / np.abs(scale)
    s = np.where(np.isfinite(s), s, 0.0)
    u = v / np.maximum(vn[:, None], 1e-300)
    # the norm's linear error, plus the chi floor where the vector is near zero
    return np.sqrt(np.sum((u * s) ** 2, axis=1) + np.where(vn > 0, 0.0, np.sum(s**2, axis=1)))


def rest_filter(windows: Sequence[Window], ref: RestReference) -> tuple[list[Window], list[str]]:
    """The windows at rest in physics, and one reason per window ("" where kept).

    Motion rejects (``turning``, ``swinging``, ``accelerating``); ``rate_low`` does not (no motion
    lowers the rate: the unit's settings are checked by recal.detect.plausibility). Each window
    is judged with its own standard errors (``gyro_sem``/``accel_sem``); an
    accelerometer-only window (``gyro_still`` False: the gyro trembled) is judged on gravity
    alone. Callers count the reasons in their report (``DetectionReport.add_rest_rejections``).
    """
    if not windows:
        return [], []
    gyro = np.array([w.gyro for w in windows], dtype=float)
    accel = np.array([w.accel for w in windows], dtype=float)
    has_gyro = np.isfinite(gyro).all(axis=1) & np.array([w.gyro_still for w in windows])
    has_accel = np.isfinite(accel).all(axis=1)
    gs = np.array([w.gyro_sem for w in windows], dtype=float)
    fs = np.array([w.accel_sem for w in windows], dtype=float)
    reasons = np.full(len(windows), "", dtype=object)
    both = has_gyro & has_accel
    if both.any():
        reasons[both] = ref.judge(gyro[both], accel[both], gs[both], fs[both])
    only_g = has_gyro & ~has_accel
    if only_g.any():
        reasons[only_g] = ref.judge(gyro[only_g], None, gs[only_g], None)
    only_a = has_accel & ~has_gyro
    if only_a.any():
        reasons[only_a] = ref.judge(None, accel[only_a], None, fs[only_a])
    # a rate below Earth's is no motion: a wrong setting (recal.detect.plausibility names it) or a
    # unit out of its class; the window is kept, and only motion rejects
    reasons[reasons == "rate_low"] = ""
    kept = [w for w, r in zip(windows, reasons, strict=True) if not r]
    return kept, [str(r) for r in reasons]
