"""Simulated vessel trajectories, sample by sample: a moored (static) start, then a voyage.

A :class:`VoyageSpec` describes the vessel: moored at heading ``heading0_deg`` for ``moor_s``
seconds (perfectly still, so an INS can align), then legs of given speed and heading joined by
smooth raised-cosine changes (turn rate and acceleration limited), with a sinusoidal roll and
pitch from the waves while under way. With no legs it is a static recording of ``moor_s``.

The IMU sits at the vessel's reference point, turned in the hull by ``mount_rpy_deg``
(C_bn = C_vessel_to_NED @ C_imu_to_vessel). Navigation frame NED, WGS-84, height constant.
The true inputs are exact kinematics (no inverse mechanization):

    w_ib^b = C_bn^T (w_ie^n + w_en^n) + w_nb^b(Euler rates)       (deg/h for the model)
    f^b    = C_bn^T (dv/dt + (2 w_ie^n + w_en^n) x v - g^n)         (g for the model)

sample i is the value at the middle of its interval [i, i + 1] / rate (the interval mean to
second order), and the truth state is given at the interval start (the sample's time stamp).
Outputs are the truth model's forward map (:func:`recal.sim.simulate.truth_model`) of the inputs
plus white noise (:class:`recal.sim.simulate.NoiseSpec` densities) and an optional Gauss-Markov bias.
The result carries a :class:`recal.sim.session.Session`, so ``service.capture_sim.session_to_kvh``
encodes it as KVH frames. Pure numpy, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.reference import G0_M_S2, OMEGA_IE_RAD_S, normal_gravity_g, normal_gravity_m_s2
from recal.nav.navigation import ENU_FROM_NED, WGS84_A_M, WGS84_E2, attitude_matrix, euler_angles
from recal.sim.session import MAX_SAMPLES, Session, gauss_markov, sample_context
from recal.sim.simulate import NoiseSpec, truth_model

_RAD_S_TO_DEG_H = math.degrees(1.0) * 3600.0


@dataclass(frozen=True)
class Leg:
    """Sail ``duration_s`` at ``speed_m_s`` on ``heading_deg`` (the change into it included)."""

    duration_s: float
    speed_m_s: float
    heading_deg: float


#: A lake voyage of about 1.6 h like seed 000 section 5.2: speed and heading changes.
DEFAULT_LEGS: tuple[Leg, ...] = (
    Leg(900.0, 5.0, 30.0),
    Leg(900.0, 8.0, 100.0),
    Leg(1200.0, 6.0, 190.0),
    Leg(900.0, 3.0, 280.0),
    Leg(900.0, 7.0, 20.0),
)


@dataclass(frozen=True)
class VoyageSpec:
    """Moored start and legs (see the module docstring); angles in deg, times in s."""

    moor_s: float = 900.0
    legs: tuple[Leg, ...] = DEFAULT_LEGS
    heading0_deg: float = 30.0
    turn_rate_deg_s: float = 1.0
    accel_m_s2: float = 0.05
    roll_deg: float = 1.5
    roll_period_s: float = 9.0
    pitch_deg: float = 0.5
    pitch_period_s: float = 6.0
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def duration_s(self) -> float:
        return self.moor_s + sum(leg.duration_s for leg in self.legs)

    @classmethod
    def static(
        cls, duration_s: float, attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0)
    ) -> VoyageSpec:
        """A static recording: the IMU at rest at ``attitude_rpy_deg`` (roll, pitch, yaw in NED)."""
        r, p, y = (float(a) for a in attitude_rpy_deg)
        return cls(moor_s=duration_s, legs=(), heading0_deg=y, mount_rpy_deg=(r, p, 0.0))


@dataclass(frozen=True, eq=False)
class Voyage:
    """A simulated recording and its truth.

    session: the samples (time_s, gyro_out, accel_out, temperature_c, true inputs) as a
        :class:`recal.sim.session.Session`; one hold, the mooring.
    lat_deg, lon_deg: (N,) true position at each sample's time stamp; height_m constant.
    v_ned: (N, 3) true velocity, m/s; rpy_deg: (N, 3) true roll, pitch, yaw of the IMU in NED.
    """

    session: Session
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: float
    v_ned: np.ndarray
    rpy_deg: np.ndarray
    spec: VoyageSpec = field(default_factory=VoyageSpec)

    @property
    def time_s(self) -> np.ndarray:
        return self.session.time_s

    def truth_columns(self) -> dict[str, np.ndarray]:
        """The truth as named columns (the ``--truth`` CSV of ``recal navigate``)."""
        return {
            "time_s": self.time_s,
            "latitude_deg": self.lat_deg,
            "longitude_deg": self.lon_deg,
            "height_m": np.full(self.time_s.shape, self.height_m),
            "v_north_m_s": self.v_ned[:, 0],
            "v_east_m_s": self.v_ned[:, 1],
            "roll_deg": self.rpy_deg[:, 0],
            "pitch_deg": self.rpy_deg[:, 1],
            "yaw_deg": self.rpy_deg[:, 2],
        }


def _smooth_steps(
    t: np.ndarray, starts: np.ndarray, lengths: np.ndarray, deltas: np.ndarray, v0: float
) -> tuple[np.ndarray, np.ndarray]:
    """v0 + sum of raised-cosine steps (start, length, size): value and its time derivative."""
    value = np.full(t.shape, float(v0))
    rate = np.zeros(t.shape)
    for t0, tau, d in zip(starts, lengths, deltas, strict=True):  # a loop over the few changes
        u = np.clip((t - t0) / tau, 0.0, 1.0)
        value += d * 0.5 * (1.0 - np.cos(np.pi * u))
        inside = (t > t0) & (t < t0 + tau)
        rate += np.where(inside, d * 0.5 * np.pi * np.sin(np.pi * u) / tau, 0.0)
    return value, rate


def kinematics(spec: VoyageSpec, t: np.ndarray) -> dict[str, np.ndarray]:
    """Speed, heading (rad), their rates, and roll/pitch with rates at times ``t`` (s)."""
    starts, speed_d, head_d, speed_tau, head_tau = [], [], [], [], []
    speed, heading = 0.0, spec.heading0_deg
    t_leg = spec.moor_s
    for leg in spec.legs:
        ds = leg.speed_m_s - speed
        dh = (leg.heading_deg - heading + 180.0) % 360.0 - 180.0  # the shorter way round
        starts.append(t_leg)
        speed_d.append(ds)
        head_d.append(math.radians(dh))
        # raised cosine: peak rate = pi/2 * delta / tau, kept within the limits
        speed_tau.append(max(10.0, 0.5 * math.pi * abs(ds) / spec.accel_m_s2))
        head_tau.append(max(10.0, 0.5 * math.pi * abs(dh) / spec.turn_rate_deg_s))
        speed, heading = leg.speed_m_s, heading + dh
        t_leg += leg.duration_s
    st = np.array(starts)
    s, s_dot = _smooth_steps(t, st, np.array(speed_tau), np.array(speed_d), 0.0)
    chi, chi_dot = _smooth_steps(
        t, st, np.array(head_tau), np.array(head_d), math.radians(spec.heading0_deg)
    )
    out = {"speed": s, "speed_dot": s_dot, "heading": chi, "heading_dot": chi_dot}
    # Waves while under way: amplitude ramps in over the first 60 s after the mooring.
    if spec.legs:
        env, env_dot = _smooth_steps(t, np.array([spec.moor_s]), np.array([60.0]), np.ones(1), 0.0)
    else:
        env, env_dot = np.zeros(t.shape), np.zeros(t.shape)
    for name, amp, period in (
        ("roll", spec.roll_deg, spec.roll_period_s),
        ("pitch", spec.pitch_deg, spec.pitch_period_s),
    ):
        w = 2.0 * math.pi / period
        a = math.radians(amp)
        ph = w * (t - spec.moor_s)
        out[name] = env * a * np.sin(ph)
        out[name + "_dot"] = env_dot * a * np.sin(ph) + env * a * w * np.cos(ph)
    return out


def euler_rates_to_body(
    roll: np.ndarray, pitch: np.ndarray, droll: np.ndarray, dpitch: np.ndarray, dyaw: np.ndarray
) -> np.ndarray:
    """z-y-x Euler angle rates -> body rate relative to NED, (N, 3) rad/s."""
    sr, cr = np.sin(roll), np.cos(roll)
    sp, cp = np.sin(pitch), np.cos(pitch)
    return np.stack(
        [droll - dyaw * sp, dpitch * cr + dyaw * sr * cp, -dpitch * sr + dyaw * cr * cp], axis=1
    )


def dcm_zyx(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 3, 3) body-to-NED from vectors of z-y-x angles."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    C = np.empty(roll.shape + (3, 3))
    C[:, 0, 0], C[:, 0, 1], C[:, 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    C[:, 1, 0], C[:, 1, 1], C[:, 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    C[:, 2, 0], C[:, 2, 1], C[:, 2, 2] = -sp, cp * sr, cp * cr
    return C


def _state(
    spec: VoyageSpec, t: np.ndarray, lat0: float, lon0: float, h: float
) -> dict[str, np.ndarray]:
    """Position (by integrating the velocity on the grid ``t``), velocity, attitude at ``t``."""
    kin = kinematics(spec, t)
    vn = kin["speed"] * np.cos(kin["heading"])
    ve = kin["speed"] * np.sin(kin["heading"])
    lat = np.full(t.shape, lat0)
    dt = np.diff(t)
    for _ in range(2):  # the radii depend on latitude: one refinement is plenty (< 1e-12 rad)
        s2 = np.sin(lat) ** 2
        k = np.sqrt(1.0 - WGS84_E2 * s2)
        rm, rn = WGS84_A_M * (1.0 - WGS84_E2) / k**3 + h, WGS84_A_M / k + h
        dlat, dlon = vn / rm, ve / (rn * np.cos(lat))
        lat = lat0 + np.concatenate(([0.0], np.cumsum(0.5 * (dlat[1:] + dlat[:-1]) * dt)))
    lon = lon0 + np.concatenate(([0.0], np.cumsum(0.5 * (dlon[1:] + dlon[:-1]) * dt)))
    return {**kin, "lat": lat, "lon": lon, "vn": vn, "ve": ve}


def simulate_voyage(
    truth: CoefficientSet,
    spec: VoyageSpec | None = None,
    latitude_deg: float = 45.0,
    longitude_deg: float = 0.0,
    height_m: float = 0.0,
    rate_hz: float = 100.0,
    noise: NoiseSpec | None = None,
    temperature_c: float = 25.0,
    seed: int = 0,
) -> Voyage:
    """Simulate every sample of a voyage (or a static recording, ``VoyageSpec.static``).

    ``noise`` densities (arw deg/rt h, vrw ug/rt Hz) give the per-sample sigma at ``rate_hz``;
    ``noise=NoiseSpec(0, 0)`` is noiseless. The temperature is constant.
    """
    spec = spec or VoyageSpec()
    noise = noise if noise is not None else NoiseSpec()
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise RecalInputError(f"rate must be positive, not {rate_hz}")
    if not -89.0 <= latitude_deg <= 89.0:
        raise RecalInputError(f"latitude {latitude_deg} deg: a voyage needs |latitude| <= 89")
    N = round(spec.duration_s * rate_hz)
    if N < 2:
        raise RecalInputError("the voyage needs at least two samples")
    if N > MAX_SAMPLES:
        raise RecalInputError(
            f"the recording would have {N} samples (limit {MAX_SAMPLES}): lower the rate"
        )
    lat0, lon0 = math.radians(latitude_deg), math.radians(longitude_deg)
    h = float(height_m)
    time_s = np.arange(N) / rate_hz
    # Truth at the stamps and at the mid-points (the inputs), from one fine grid of both.
    grid = np.arange(2 * N + 1) * (0.5 / rate_hz)
    st = _state(spec, grid, lat0, lon0, h)
    at, mid = slice(0, 2 * N, 2), slice(1, 2 * N, 2)
    C_mount = attitude_matrix(*np.radians(spec.mount_rpy_deg))

    def attitude(sl: slice) -> np.ndarray:
        return dcm_zyx(st["roll"][sl], st["pitch"][sl], st["heading"][sl]) @ C_mount

    C_bn = attitude(mid)
    lat, vn, ve = st["lat"][mid], st["vn"][mid], st["ve"][mid]
    sl_, cl_ = np.sin(lat), np.cos(lat)
    k = np.sqrt(1.0 - WGS84_E2 * sl_**2)
    rm, rn = WGS84_A_M * (1.0 - WGS84_E2) / k**3 + h, WGS84_A_M / k + h
    w_ie = np.stack([OMEGA_IE_RAD_S * cl_, np.zeros(N), -OMEGA_IE_RAD_S * sl_], axis=1)
    w_en = np.stack([ve / rn, -vn / rm, -ve * sl_ / cl_ / rn], axis=1)
    w_nb_v = euler_rates_to_body(
        st["roll"][mid], st["pitch"][mid], st["roll_dot"][mid], st["pitch_dot"][mid],
        st["heading_dot"][mid],
    )  # fmt: skip
    # vessel-frame rate relative to NED -> IMU body frame through the fixed mounting
    w_nb = w_nb_v @ C_mount
    w_ib = np.einsum("nji,nj->ni", C_bn, w_ie + w_en) + w_nb
    s, s_dot, chi, chi_dot = (st[n][mid] for n in ("speed", "speed_dot", "heading", "heading_dot"))
    a_n = np.stack(
        [s_dot * np.cos(chi) - s * chi_dot * np.sin(chi),
         s_dot * np.sin(chi) + s * chi_dot * np.cos(chi), np.zeros(N)], axis=1,
    )  # fmt: skip
    v = np.stack([vn, ve, np.zeros(N)], axis=1)
    g = np.array([normal_gravity_m_s2(math.degrees(x), h) for x in lat[:: max(1, N // 1000)]])
    g_n = np.zeros((N, 3))
    g_n[:, 2] = np.interp(np.arange(N), np.arange(N)[:: max(1, N // 1000)], g)
    f_n = a_n + np.cross(2.0 * w_ie + w_en, v) - g_n
    f_b = np.einsum("nji,nj->ni", C_bn, f_n)

    gyro_in = w_ib * _RAD_S_TO_DEG_H
    accel_in = f_b / G0_M_S2
    rng = np.random.default_rng(seed)
    noise_at_rate = replace(noise, rate_hz=rate_hz)
    temp = np.full(N, float(temperature_c))
    ctx = sample_context(time_s, temp, accel_in)
    out = {}
    for sensor, x in (("gyro", gyro_in), ("accel", accel_in)):
        theta, model = truth_model(truth, sensor)
        noisy = x + rng.normal(size=(N, 3)) * noise_at_rate.per_sample_sigma(sensor)
        gm = noise.gauss_markov_sigma(sensor)
        if gm > 0:
            noisy += gauss_markov(rng, N, gm, noise.gm_tau_s, rate_hz)
        out[sensor] = model.forward(theta, noisy, ctx)[0]
    n_moor = max(2, min(N, round(spec.moor_s * rate_hz)))
    session = Session(
        time_s=time_s,
        gyro_out=out["gyro"],
        accel_out=out["accel"],
        temperature_c=temp,
        static=np.arange(N) < n_moor,
        gyro_in_dph=gyro_in,
        accel_in_g=accel_in,
        hold_first=np.array([0]),
        hold_last=np.array([n_moor - 1]),
        orientations=ENU_FROM_NED @ attitude(at)[:1],
        rate_hz=float(rate_hz),
        latitude_deg=float(latitude_deg),
        height_m=h,
        gravity_g=normal_gravity_g(latitude_deg, h),
    )
    rpy = np.degrees(euler_angles(attitude(at)))
    v_at = np.stack([st["vn"][at], st["ve"][at], np.zeros(N)], axis=1)
    return Voyage(session, np.degrees(st["lat"][at]), np.degrees(st["lon"][at]), h, v_at, rpy, spec)
