"""Free-inertial strapdown navigation of corrected IMU outputs (WGS-84, NED, height held).

Frames and conventions
----------------------
* Navigation frame **NED** (x north, y east, z down). ``C_bn`` is the body-to-NED rotation
  (``x_n = C_bn x_b``); roll, pitch, yaw are the z-y-x (yaw first) Euler angles of the body in
  NED, as ``recal navigate --attitude`` takes them. The calibration side of the project
  (:mod:`recal.sim.simulate`, :mod:`recal.sim.session`) works in **ENU**; :data:`ENU_FROM_NED` converts.
* At rest the gyros sense Earth rate ``w_ie^n = Omega [cos L, 0, -sin L]`` and the
  accelerometers the specific force ``f^n = [0, 0, -g]`` (m/s^2).
* Height is held at its known value (vertical velocity 0): the free vertical channel of an INS
  is unstable, and a vessel's height is known.

Pipeline
--------
1. :class:`Decimator` averages the raw outputs (output units) over blocks of samples, streamed
   chunk by chunk, e.g. 1000 Hz -> 10 Hz. An average of outputs is the sum of the increments the
   sensor measured, so for the affine parts of the error model nothing is lost. What it costs:
   the nonlinear terms (accel K2, scale asymmetry) are applied to the block mean instead of to
   each sample (K2 * var(f): ~1e-5/g * (0.6 mg)^2 = 4e-12 g for 20 ug/rtHz at 1 kHz), and motion
   faster than the output rate (coning, sculling above ~5 Hz) is averaged away. A static
   recording loses nothing measurable; a ship's 5-15 s roll is far below 5 Hz.
2. :func:`correct_outputs` applies each coefficient set (the inverse of docs/reference.md#models,
   :meth:`recal.model.error_model.Model.inverse`, effects included) -> rates in rad/s, specific force m/s^2,
   batched over P coefficient sets (leading axis).
3. :func:`navigate`: a two-speed strapdown algorithm. The fast part composes the samples of
   each block exactly (rotation of every sample by Rodrigues, the velocity increment of each
   sample rotated into the block's first body frame at its mid-time: rotation compensation and
   sculling), vectorised over all blocks and sets. The slow loop (one step per block, default
   1 s) adds the navigation-frame rotation (Earth rate + transport rate), gravity, Coriolis and
   position. The per-step loop is inherent; it runs once for all P sets (numpy over the leading
   axis), so N sets cost about one loop.

Verified against ``inu.mech`` (pure Python reference mechanization) in
``tests/recal/test_navigation_inu.py``. Pure numerics, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import Model
from recal.model.reference import G0_M_S2, OMEGA_IE_RAD_S, normal_gravity_m_s2
from recal.model.terms import Term, catalogue_terms

#: WGS-84 semi-major axis (m) and first eccentricity squared (as in recal.model.reference).
WGS84_A_M = 6378137.0
WGS84_E2 = 6.69437999014e-3
#: Metres per international nautical mile. (Seed 000 eq. 15 divides by 1851.85; the 0.05 %
#: difference does not matter at the precision of its Table 5.)
NMI_M = 1852.0
DEG_H_TO_RAD_S = math.radians(1.0) / 3600.0
#: ENU <-> NED: x_ned = ENU_FROM_NED.T @ x_enu ... the matrix is its own inverse (swap x/y, flip z).
ENU_FROM_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: Default output rate of the decimator, Hz, and slow-loop step, s.
DEFAULT_RATE_HZ = 10.0
DEFAULT_STEP_S = 1.0
#: Fast-part blocks processed at once (bounds the temporaries near 50 MB per coefficient set).
_CHUNK_BLOCKS = 16384
#: Slow-loop steps between re-orthonormalisations of C_bn.
_ORTHO_EVERY = 64


# ---------------------------------------------------------------------------------- geodesy
def radii_m(lat_rad: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """WGS-84 meridian (north-south) and prime-vertical (east-west) radii of curvature, m."""
    s2 = np.sin(lat_rad) ** 2
    k = np.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A_M * (1.0 - WGS84_E2) / k**3, WGS84_A_M / k


def schuler_period_s(latitude_deg: float, height_m: float = 0.0) -> float:
    """2 pi sqrt(R / g): 84.4 min at the Earth's surface."""
    rm, rn = radii_m(math.radians(latitude_deg))
    r = math.sqrt(float(rm) * float(rn)) + height_m
    return 2.0 * math.pi * math.sqrt(r / normal_gravity_m_s2(latitude_deg, height_m))


# ---------------------------------------------------------------------------------- rotations
def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices: skew(a) @ b == a x b."""
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -v[..., 2], v[..., 1]
    K[..., 1, 0], K[..., 1, 2] = v[..., 2], -v[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -v[..., 1], v[..., 0]
    return K


def rodrigues(phi: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) rad -> rotation matrices exp([phi x]) (..., 3, 3)."""
    a2 = np.einsum("...i,...i->...", phi, phi)
    a = np.sqrt(a2)
    small = a2 < 1e-8  # Taylor series: relative error < 1e-17 there
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, np.sin(a) / a)
        c = np.where(small, 0.5 - a2 / 24.0 + a2 * a2 / 720.0, (1.0 - np.cos(a)) / a2)
    K = skew(phi)
    return np.eye(3) + s[..., None, None] * K + c[..., None, None] * (K @ K)


def attitude_matrix(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """Body-to-NED C_bn from roll, pitch, yaw (z-y-x order: yaw about down, then pitch, roll)."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def euler_angles(C_bn: np.ndarray) -> np.ndarray:
    """(..., 3, 3) body-to-NED -> (..., 3) roll, pitch, yaw in rad (yaw in (-pi, pi])."""
    roll = np.arctan2(C_bn[..., 2, 1], C_bn[..., 2, 2])
    pitch = -np.arcsin(np.clip(C_bn[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(C_bn[..., 1, 0], C_bn[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def orthonormalize(C: np.ndarray) -> np.ndarray:
    """One step of C (3I - C^T C) / 2: removes first-order drift from orthonormality."""
    return C @ (1.5 * np.eye(3) - 0.5 * np.swapaxes(C, -1, -2) @ C)


# ---------------------------------------------------------------------------------- decimation
@dataclass(frozen=True, eq=False)
class ImuData:
    """Sensor outputs at a uniform rate: one row per interval of ``1 / rate_hz`` s.

    time_s: (N,) start of each interval, s (the time stamp of its first raw sample).
    gyro_out, accel_out: (N, 3) mean output over the interval, output units.
    temperature_c: (N,) mean temperature, or None when the recording has none.
    samples: (N,) raw samples averaged into each row (fewer than the factor where frames were
        lost or invalid; 0 where a whole block was lost, the row then repeats the previous one).
    """

    time_s: np.ndarray
    gyro_out: np.ndarray
    accel_out: np.ndarray
    temperature_c: np.ndarray | None
    samples: np.ndarray
    rate_hz: float

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def slice(self, start: int, stop: int | None = None) -> ImuData:
        s = slice(start, stop)
        temp = None if self.temperature_c is None else self.temperature_c[s]
        return ImuData(
            self.time_s[s], self.gyro_out[s], self.accel_out[s], temp, self.samples[s], self.rate_hz
        )


class Decimator:
    """Average raw outputs over blocks of ``factor`` samples, fed in chunks of any size.

    Block k holds raw samples ``k * factor .. (k + 1) * factor - 1`` counted from the first
    frame, lost frames included (``lost_before``), so the output stays on a uniform time grid.
    Invalid frames are left out of their block's mean.
    """

    def __init__(self, input_rate_hz: float, factor: int) -> None:
        if factor < 1:
            raise ValueError("decimation factor must be >= 1")
        self.input_rate_hz = float(input_rate_hz)
        self.factor = int(factor)
        self._index = 0  # raw sample index of the next frame (lost frames counted)
        self._t0: float | None = None
        self._has_temp: bool | None = None
        self._parts: list[tuple[np.ndarray, ...]] = []
        self._pending: tuple[np.ndarray, ...] | None = None

    @property
    def rate_hz(self) -> float:
        return self.input_rate_hz / self.factor

    def feed(
        self,
        time_s: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray,
        temperature_c: np.ndarray | None = None,
        valid: np.ndarray | None = None,
        lost_before: np.ndarray | None = None,
        **_: object,
    ) -> None:
        n = int(np.shape(time_s)[0])
        if n == 0:
            return
        if self._t0 is None:
            self._t0 = float(time_s[0])
            self._has_temp = temperature_c is not None
        lost = np.zeros(n, np.int64) if lost_before is None else np.asarray(lost_before, np.int64)
        index = self._index + np.arange(n) + np.cumsum(lost)
        self._index = int(index[-1]) + 1
        ok = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
        temp = (
            np.asarray(temperature_c, float)
            if temperature_c is not None and self._has_temp
            else np.zeros(n)
        )
        block = index[ok] // self.factor
        b0 = int(block[0]) if block.size else 0
        local = block - b0
        size = int(local.max()) + 1 if block.size else 0
        cols = np.column_stack(
            [np.asarray(gyro, float)[ok], np.asarray(accel, float)[ok], temp[ok]]
        )
        # Reduced to per-block sums at once: memory grows with the output rows, not the input.
        sums = np.stack([np.bincount(local, cols[:, i], size) for i in range(7)], axis=1)
        self._parts.append((b0, np.bincount(local, minlength=size).astype(float), sums))

    def result(self) -> ImuData:
        """All complete blocks so far (a last, partial block is dropped)."""
        if not self._parts:
            raise RecalInputError("the recording has no frames")
        n_blocks = self._index // self.factor
        counts = np.zeros(n_blocks + 1)
        sums = np.zeros((n_blocks + 1, 7))
        for b0, c, s in self._parts:  # a loop over chunks; blocks split by a chunk edge add up
            stop = min(b0 + c.size, n_blocks + 1)
            counts[b0:stop] += c[: stop - b0]
            sums[b0:stop] += s[: stop - b0]
        counts, sums = counts[:n_blocks], sums[:n_blocks]
        with np.errstate(invalid="ignore", divide="ignore"):
            means = sums / counts[:, None]
        empty = counts == 0
        if empty.any():  # a whole block lost: hold the previous block's value
            idx = np.where(~empty, np.arange(n_blocks), 0)
            np.maximum.accumulate(idx, out=idx)
            means = means[idx]
        time_s = (self._t0 or 0.0) + np.arange(n_blocks) * self.factor / self.input_rate_hz
        temp_out = means[:, 6] if self._has_temp else None
        return ImuData(time_s, means[:, :3], means[:, 3:6], temp_out, counts, self.rate_hz)


def decimate(
    time_s: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    temperature_c: np.ndarray | None,
    input_rate_hz: float,
    rate_hz: float = DEFAULT_RATE_HZ,
) -> ImuData:
    """Arrays held in memory -> :class:`ImuData` at ``rate_hz`` (see :class:`Decimator`)."""
    d = Decimator(input_rate_hz, decimation_factor(input_rate_hz, rate_hz))
    d.feed(time_s, gyro, accel, temperature_c)
    return d.result()


def decimation_factor(input_rate_hz: float, rate_hz: float) -> int:
    """Whole number of raw samples per output row (at least 1)."""
    if not (math.isfinite(input_rate_hz) and input_rate_hz > 0):
        raise RecalInputError(f"sample rate must be positive, not {input_rate_hz}")
    return max(1, round(input_rate_hz / rate_hz))


# ---------------------------------------------------------------------------------- correction
def correction_models(coeffs: CoefficientSet) -> tuple[Model, Model]:
    """Seed models plus the catalogue effects the set carries (T0 from the set)."""
    catalogue = catalogue_terms(coeffs.t0_c)
    extra: list[Term] = []
    for name in coeffs.values:
        if name.split(".", 1)[1] in ("scale", "bias", "misalignment", "quadratic"):
            continue
        if name not in catalogue:
            raise RecalInputError(f"coefficients carry effect '{name}', unknown to navigation")
        extra.append(catalogue[name])
    for sensor in ("gyro", "accel"):
        if coeffs.get(f"{sensor}.scale") is None:
            raise RecalInputError(f"coefficients lack {sensor}.scale: navigation needs both triads")
    return tuple(  # type: ignore[return-value]
        Model.seed(s, [t for t in extra if t.sensor == s]) for s in ("gyro", "accel")
    )


def correct_outputs(
    coeff_sets: Sequence[CoefficientSet], data: ImuData, t_start_s: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Outputs -> physical inputs per coefficient set: rates (P, N, 3) rad/s, force m/s^2.

    The context of the effect terms: temperature (degC) and its rate (degC/h, from the
    decimated temperature over +-30 s), session time in h from ``t_start_s`` (default: the first
    row), and the corrected specific force for a gyro g-sensitivity.
    """
    t0 = float(data.time_s[0]) if t_start_s is None else t_start_s
    ctx: dict[str, np.ndarray] = {"time_h": (data.time_s - t0) / 3600.0}
    if data.temperature_c is not None:
        ctx["temperature_c"] = data.temperature_c
        ctx["temperature_rate_c_per_h"] = _temperature_rate(data.temperature_c, data.rate_hz)
    omega, force = [], []
    for cs in coeff_sets:
        gyro_model, accel_model = correction_models(cs)
        for m in (gyro_model, accel_model):
            missing = m.needs - set(ctx) - {"specific_force_g"}
            if missing:
                raise RecalInputError(
                    f"coefficients need {', '.join(sorted(missing))}, which the recording lacks"
                )
        f_g = accel_model.inverse(cs.to_vector(_layout(accel_model))[None], data.accel_out, ctx)[0]
        ctx_g = {**ctx, "specific_force_g": f_g}
        w = gyro_model.inverse(cs.to_vector(_layout(gyro_model))[None], data.gyro_out, ctx_g)
        omega.append(w[0] * DEG_H_TO_RAD_S)
        force.append(f_g * G0_M_S2)
    return np.stack(omega), np.stack(force)


def _layout(model: Model):
    from recal.model.error_model import ParameterLayout

    return ParameterLayout((model,))


def _temperature_rate(
    temp_c: np.ndarray, rate_hz: float, half_window_s: float = 30.0
) -> np.ndarray:
    """dT/dt in degC/h: central difference of the temperature over +-half_window_s (whole-degree
    quantisation would make a sample-to-sample slope useless)."""
    k = max(1, round(half_window_s * rate_hz))
    n = temp_c.shape[0]
    i = np.arange(n)
    hi, lo = np.minimum(i + k, n - 1), np.maximum(i - k, 0)
    span = np.maximum(hi - lo, 1) / rate_hz
    return (temp_c[hi] - temp_c[lo]) / span * 3600.0


# ---------------------------------------------------------------------------------- mechanization
@dataclass(frozen=True, eq=False)
class NavResult:
    """Navigation of P coefficient sets; K slow-loop steps after the initial state.

    time_s: (K + 1,) time of each state from the navigation start, s (0 = initial state).
    lat_rad, lon_rad: (P, K + 1) geodetic position; height_m is held.
    v_ned: (P, K + 1, 3) velocity, m/s (down held at 0).
    C_bn: (P, K + 1, 3, 3) attitude, body to NED.
    """

    time_s: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    v_ned: np.ndarray
    C_bn: np.ndarray
    height_m: float

    @property
    def rpy_rad(self) -> np.ndarray:
        """(P, K + 1, 3) roll, pitch, yaw."""
        return euler_angles(self.C_bn)

    def north_east_error_m(
        self, lat_ref_rad: np.ndarray | float, lon_ref_rad: np.ndarray | float
    ) -> tuple[np.ndarray, np.ndarray]:
        """North and east position error (P, K + 1), m, against a reference position (scalars
        or (K + 1,) arrays): latitude and longitude differences times the WGS-84 radii."""
        rm, rn = radii_m(lat_ref_rad)
        north = (self.lat_rad - lat_ref_rad) * (rm + self.height_m)
        east = (self.lon_rad - lon_ref_rad) * (rn + self.height_m) * np.cos(lat_ref_rad)
        return north, east


def block_increments(
    omega_rad_s: np.ndarray, force_m_s2: np.ndarray, dt_s: float, per_block: int
) -> tuple[np.ndarray, np.ndarray]:
    """Fast part: compose ``per_block`` samples into one rotation and one velocity increment.

    omega_rad_s, force_m_s2: (P, N, 3), each sample constant over its ``dt_s``. Returns
    R (P, B, 3, 3), the body rotation over each block (body at block end in the body frame at
    block start, relative to inertial space), and dv (P, B, 3), the specific-force velocity
    increment in the block's first body frame, m/s; B = N // per_block (a last partial block is
    dropped). Each sample's increment is rotated by the body rotation up to its mid-time.
    """
    P, N, _ = omega_rad_s.shape
    B = N // per_block
    R_all = np.empty((P, B, 3, 3))
    dv_all = np.empty((P, B, 3))
    for b0 in range(0, B, _CHUNK_BLOCKS):  # chunks bound the temporaries' memory
        b1 = min(B, b0 + _CHUNK_BLOCKS)
        alpha = omega_rad_s[:, b0 * per_block : b1 * per_block].reshape(P, b1 - b0, per_block, 3)
        nu = force_m_s2[:, b0 * per_block : b1 * per_block].reshape(P, b1 - b0, per_block, 3)
        alpha = alpha * dt_s
        R = np.broadcast_to(np.eye(3), (P, b1 - b0, 3, 3)).copy()
        dv = np.zeros((P, b1 - b0, 3))
        for j in range(per_block):  # a loop over the samples of a block, vectorised over blocks
            half = rodrigues(0.5 * alpha[:, :, j])
            dv += np.einsum("pbij,pbj->pbi", R @ half, nu[:, :, j] * dt_s)
            R = R @ rodrigues(alpha[:, :, j])
        R_all[:, b0:b1] = R
        dv_all[:, b0:b1] = dv
    return R_all, dv_all


def navigate(
    omega_rad_s: np.ndarray,
    force_m_s2: np.ndarray,
    dt_s: float,
    latitude_deg: float,
    longitude_deg: float,
    height_m: float,
    C_bn0: np.ndarray,
    v0_ned: np.ndarray | Sequence[float] = (0.0, 0.0, 0.0),
    step_s: float = DEFAULT_STEP_S,
    progress: Callable[[int], None] | None = None,
) -> NavResult:
    """Free-inertial navigation of P corrected sample streams from one initial state.

    omega_rad_s, force_m_s2: (P, N, 3) or (N, 3) body rate (rad/s, relative to inertial space)
    and specific force (m/s^2), sample i constant over [i dt, (i + 1) dt]. C_bn0: (3, 3) or
    (P, 3, 3) initial attitude, body to NED. The slow step is ``step_s`` rounded to whole
    samples; ``progress(k)`` is called with the number of slow steps done since the last call.
    """
    omega = np.asarray(omega_rad_s, float)
    force = np.asarray(force_m_s2, float)
    if omega.ndim == 2:
        omega, force = omega[None], force[None]
    P, N, _ = omega.shape
    m = max(1, round(step_s / dt_s))
    T = m * dt_s
    K = N // m
    R_blk, dv_blk = block_increments(omega, force, dt_s, m)

    C = np.broadcast_to(np.asarray(C_bn0, float), (P, 3, 3)).copy()
    lat = np.full(P, math.radians(latitude_deg))
    lon = np.full(P, math.radians(longitude_deg))
    v = np.broadcast_to(np.asarray(v0_ned, float), (P, 3)).copy()
    v[:, 2] = 0.0
    h = float(height_m)
    lat_store = np.empty((P, K + 1))
    lon_store = np.empty((P, K + 1))
    v_store = np.empty((P, K + 1, 3))
    C_store = np.empty((P, K + 1, 3, 3))
    lat_store[:, 0], lon_store[:, 0], v_store[:, 0], C_store[:, 0] = lat, lon, v, C
    lat_prev, v_prev = lat.copy(), v.copy()
    zeta = np.empty((P, 3))
    w_cor = np.empty((P, 3))
    report_every = max(1, K // 200)
    for k in range(K):
        # Mid-step latitude and velocity by linear extrapolation from the last step.
        lat_m = 1.5 * lat - 0.5 * lat_prev
        vn, ve = 1.5 * v[:, 0] - 0.5 * v_prev[:, 0], 1.5 * v[:, 1] - 0.5 * v_prev[:, 1]
        sl, cl = np.sin(lat_m), np.cos(lat_m)
        k2 = np.sqrt(1.0 - WGS84_E2 * sl * sl)
        rn = WGS84_A_M / k2 + h
        rm = WGS84_A_M * (1.0 - WGS84_E2) / k2**3 + h
        wie_n, wie_d = OMEGA_IE_RAD_S * cl, -OMEGA_IE_RAD_S * sl
        wen_n, wen_e, wen_d = ve / rn, -vn / rm, -ve * sl / cl / rn
        # Rotation of the navigation frame over the step (Earth rate + transport rate).
        zeta[:, 0], zeta[:, 1], zeta[:, 2] = (wie_n + wen_n) * T, wen_e * T, (wie_d + wen_d) * T
        dv = np.einsum("pij,pj->pi", C, dv_blk[:, k])
        # The force was resolved in the frame at the step start: half the frame turn since.
        dv_n = dv - 0.5 * _cross(zeta, dv)
        w_cor[:, 0], w_cor[:, 1], w_cor[:, 2] = 2 * wie_n + wen_n, wen_e, 2 * wie_d + wen_d
        cor = _cross(w_cor, np.stack([vn, ve, np.zeros(P)], axis=1))
        # Gravity (normal to the ellipsoid) acts only on the down channel, which is held.
        v_new = v + dv_n - cor * T
        v_new[:, 2] = 0.0
        lat_prev, v_prev = lat, v
        lat = lat + 0.5 * (v[:, 0] + v_new[:, 0]) * T / rm
        lon = lon + 0.5 * (v[:, 1] + v_new[:, 1]) * T / (rn * cl)
        v = v_new
        C = rodrigues(-zeta) @ C @ R_blk[:, k]
        if k % _ORTHO_EVERY == _ORTHO_EVERY - 1:
            C = orthonormalize(C)
        lat_store[:, k + 1], lon_store[:, k + 1], v_store[:, k + 1], C_store[:, k + 1] = (
            lat,
            lon,
            v,
            C,
        )
        if progress is not None and (k + 1) % report_every == 0:
            progress(report_every)
    if progress is not None and K % report_every:
        progress(K % report_every)
    return NavResult(np.arange(K + 1) * T, lat_store, lon_store, v_store, C_store, h)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a x b for (P, 3) arrays (np.cross costs ~10x more on small arrays)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out
