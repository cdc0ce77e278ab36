"""A simulated vessel's motion: its schedule evaluated at any times, and the IMU's exact inputs.

:class:`Schedule` turns a :class:`recal.sim.vessel_spec.VesselSpec` into the hull's attitude,
heading, track and the IMU's mount at any times (the sea's waves drawn once from the seed);
:func:`vessel_inputs` gives the exact specific force and angular rate at those times, with the
transport rate, Coriolis and Eotvos terms of a ``transit`` (:func:`under_way`). The frames and
equations are in :mod:`recal.sim.vessel`.
"""

from __future__ import annotations

import math

import numpy as np

from recal.model.reference import G0_M_S2, OMEGA_IE_RAD_S, normal_gravity_g
from recal.nav.navigation import attitude_matrix
from recal.nav.trajectory import dcm_zyx, euler_rates_to_body
from recal.sim.session import axis_angle
from recal.sim.vessel_spec import VesselSpec

#: rad/s to deg/h.
RAD_S_TO_DEG_H = math.degrees(1.0) * 3600.0
#: One knot, m/s.
KNOT_M_S = 1852.0 / 3600.0


# ---- the schedule, evaluated at any times ------------------------------------------------------
class Schedule:
    """Everything about the segments that does not depend on time: starts, heading at each
    segment start, mount at each segment start, the sea's sinusoids."""

    def __init__(self, spec: VesselSpec, seed: int) -> None:
        self.spec = spec
        durations = np.array([s.duration_s for s in spec.segments])
        self.start = np.concatenate(([0.0], np.cumsum(durations)[:-1]))
        self.duration = durations
        self.kind = np.array([s.kind for s in spec.segments])
        dh = np.array([math.radians(s.heading_change_deg) if s.kind == "turn" else 0.0
                       for s in spec.segments])  # fmt: skip
        self.turn = dh
        self.heading_start = math.radians(spec.heading0_deg) + np.concatenate(
            ([0.0], np.cumsum(dh)[:-1])
        )
        scale = np.array([s.sea_scale for s in spec.segments])
        self.sea_scale = scale
        self.sea_prev = np.concatenate(([scale[0]], scale[:-1]))
        # transits: speed (m/s) and the track's north and east at each segment's start (m)
        self.speed = np.array([s.speed_kn * KNOT_M_S if s.kind == "transit" else 0.0
                               for s in spec.segments])  # fmt: skip
        self.has_transit = bool(np.any(self.speed > 0))
        sailed = self.speed * np.maximum(durations - spec.speed_ramp_s, 0.0)
        self.north_start = np.concatenate(
            ([0.0], np.cumsum(sailed * np.cos(self.heading_start))[:-1])
        )
        self.east_start = np.concatenate(
            ([0.0], np.cumsum(sailed * np.sin(self.heading_start))[:-1])
        )
        # mounts: C_vb at each segment's start, and for index segments the axis and angle
        mounts = [attitude_matrix(*np.radians(spec.mount_rpy_deg))]
        axes, angles = [], []
        for s in spec.segments:
            C0 = mounts[-1]
            if s.kind == "index":
                assert s.mount_rpy_deg is not None
                C1 = attitude_matrix(*np.radians(s.mount_rpy_deg))
                axis, angle = axis_angle(C0.T @ C1)  # body-fixed axis of the relative rotation
            else:
                C1, axis, angle = C0, np.array([0.0, 0.0, 1.0]), 0.0
            axes.append(axis)
            angles.append(angle)
            mounts.append(C1)
        self.mount_start = np.array(mounts[:-1])
        self.index_axis = np.array(axes)
        self.index_angle = np.array(angles)
        # sea: per motion, (components,) amplitudes, angular frequencies and phases
        rng = np.random.default_rng([seed, 7])
        sea = spec.sea
        n = sea.components
        self.waves: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        for name, amp, period in (
            ("roll", math.radians(sea.roll_deg), sea.roll_period_s),
            ("pitch", math.radians(sea.pitch_deg), sea.pitch_period_s),
            ("yaw", math.radians(sea.yaw_swing_deg), sea.yaw_period_s),
            ("heave", sea.heave_m, sea.heave_period_s),
        ):
            spread = 1.0 + sea.period_spread * (np.linspace(-1.0, 1.0, n) if n > 1 else np.zeros(1))
            w = 2.0 * math.pi / (period * spread)
            a = np.full(n, amp / math.sqrt(n))  # RMS of the sum = amp / sqrt(2)
            self.waves[name] = (a, w, rng.uniform(0.0, 2.0 * math.pi, n))
        self.lever = np.asarray(sea.lever_arm_m, dtype=float)

    def segment_of(self, t: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(self.start, t, side="right") - 1, 0, len(self.start) - 1)

    def envelope(self, t: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sea scale and its rate: from the previous segment's to this one's over sea_ramp_s."""
        ramp = self.spec.sea_ramp_s
        u = np.clip((t - self.start[seg]) / ramp, 0.0, 1.0) if ramp > 0 else np.ones(t.shape)
        d = self.sea_scale[seg] - self.sea_prev[seg]
        env = self.sea_prev[seg] + d * 0.5 * (1.0 - np.cos(np.pi * u))
        inside = (u > 0.0) & (u < 1.0)
        rate = np.where(inside, d * 0.5 * np.pi * np.sin(np.pi * u) / max(ramp, 1e-12), 0.0)
        return env, rate

    def wave(self, name: str, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Value, first and second derivative of one motion's sum of sinusoids (scale 1)."""
        a, w, p = self.waves[name]
        ph = np.outer(t, w) + p
        s, c = np.sin(ph), np.cos(ph)
        return s @ a, c @ (a * w), -(s @ (a * w * w))

    def heading(self, t: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Heading (rad) from the turns alone, and its rate (rad/s): trapezoidal rate profile
        with raised-cosine ramps of turn_ramp_s."""
        tau = self.spec.turn_ramp_s
        T = self.duration[seg]
        x = np.clip(t - self.start[seg], 0.0, T)
        delta = self.turn[seg]
        R = np.where(self.kind[seg] == "turn", delta / np.maximum(T - tau, 1e-12), 0.0)

        # angle covered after time x of a ramp-up of length tau: R (x - tau sin(pi x/tau)/pi)/2
        def ramp_angle(x_: np.ndarray) -> np.ndarray:
            return 0.5 * (x_ - tau / np.pi * np.sin(np.pi * x_ / tau))

        up = np.minimum(x, tau)
        angle = R * ramp_angle(up)
        rate = np.where(x < tau, R * 0.5 * (1.0 - np.cos(np.pi * up / tau)), R)
        mid = np.clip(x - tau, 0.0, T - 2.0 * tau)
        angle = angle + R * mid
        down = np.clip(x - (T - tau), 0.0, tau)  # time into the ramp-down
        angle = angle + R * (down - ramp_angle(down))
        rate = np.where(x > T - tau, R * 0.5 * (1.0 + np.cos(np.pi * down / tau)), rate)
        return self.heading_start[seg] + angle, rate

    def track(self, t: np.ndarray, seg: np.ndarray) -> dict[str, np.ndarray]:
        """The ship over the Earth: north and east of its start (m), velocity (m/s) and
        acceleration (m/s^2) north and east, speed over ground (m/s) and course (rad). A transit
        sails on the heading its segment starts with; its speed rises over ``speed_ramp_s``
        (raised cosine), stays, and falls to a standstill at the segment's end."""
        tau = self.spec.speed_ramp_s
        T = self.duration[seg]
        V = self.speed[seg]
        x = np.clip(t - self.start[seg], 0.0, T)

        def ramp_distance(x_: np.ndarray) -> np.ndarray:  # per unit speed, up a ramp
            return 0.5 * (x_ - tau / np.pi * np.sin(np.pi * x_ / tau))

        up = np.minimum(x, tau)
        down = np.clip(x - (T - tau), 0.0, tau)
        dist = V * (ramp_distance(up) + np.clip(x - tau, 0.0, T - 2.0 * tau)
                    + down - ramp_distance(down))  # fmt: skip
        speed = np.where(x < tau, V * 0.5 * (1.0 - np.cos(np.pi * up / tau)), V)
        speed = np.where(x > T - tau, V * 0.5 * (1.0 + np.cos(np.pi * down / tau)), speed)
        accel = np.where(x < tau, V * 0.5 * np.pi / tau * np.sin(np.pi * up / tau), 0.0)
        accel = np.where(x > T - tau, -V * 0.5 * np.pi / tau * np.sin(np.pi * down / tau), accel)
        course = self.heading_start[seg]
        c, s = np.cos(course), np.sin(course)
        return {
            "north": self.north_start[seg] + dist * c,
            "east": self.east_start[seg] + dist * s,
            "v_north": speed * c,
            "v_east": speed * s,
            "a_north": accel * c,
            "a_east": accel * s,
            "speed": speed,
            "course": course,
        }

    def mount(self, t: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """C_vb (N, 3, 3) and the indexing rate w_vb^b (N, 3) rad/s."""
        T = self.duration[seg]
        u = np.clip((t - self.start[seg]) / T, 0.0, 1.0)
        angle = self.index_angle[seg]
        theta = angle * 0.5 * (1.0 - np.cos(np.pi * u))
        theta_dot = angle * 0.5 * np.pi * np.sin(np.pi * u) / T
        axis = self.index_axis[seg]
        C = self.mount_start[seg]
        # Rodrigues: R(axis, theta) = I + sin K + (1 - cos) K^2, only where the mount turns (R is
        # exactly I elsewhere, and building it for every sample cost most of a berth's time)
        i = np.flatnonzero(theta != 0.0)
        if i.size:
            a = axis[i]
            K = np.zeros((i.size, 3, 3))
            K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -a[:, 2], a[:, 1], -a[:, 0]
            K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = a[:, 2], -a[:, 1], a[:, 0]
            s, c = np.sin(theta[i])[:, None, None], np.cos(theta[i])[:, None, None]
            C[i] = C[i] @ (np.eye(3) + s * K + (1.0 - c) * (K @ K))
        return C, axis * theta_dot[:, None]

    def attitude(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """Vessel Euler angles and rates (rad, rad/s), mount and indexing rate at times ``t``."""
        seg = self.segment_of(t)
        env, env_dot = self.envelope(t, seg)
        out: dict[str, np.ndarray] = {"segment": seg}
        for name in ("roll", "pitch", "yaw", "heave"):
            v, d1, d2 = self.wave(name, t)
            out[name] = env * v
            out[name + "_dot"] = env * d1 + env_dot * v
            out[name + "_ddot"] = env * d2 + 2.0 * env_dot * d1  # the envelope's curvature omitted
        head, head_dot = self.heading(t, seg)
        sea = self.spec.sea
        if sea.creep_dph or sea.anchor_swing_deg:  # slow heading changes at a berth or anchor
            c = math.radians(sea.creep_dph) / 3600.0
            a, w = math.radians(sea.anchor_swing_deg), 2.0 * math.pi / sea.anchor_period_s
            head = head + c * t + a * np.sin(w * t)
            head_dot = head_dot + c + a * w * np.cos(w * t)
        out["heading"] = head + out["yaw"]
        out["heading_dot"] = head_dot + out["yaw_dot"]
        out["C_vb"], out["w_vb"] = self.mount(t, seg)
        return out


def vessel_rate(att: dict[str, np.ndarray]) -> np.ndarray:
    """w_nv^v: the vessel's rate relative to NED in the vessel frame, (N, 3) rad/s."""
    return euler_rates_to_body(
        att["roll"], att["pitch"], att["roll_dot"], att["pitch_dot"], att["heading_dot"]
    )


def vessel_inputs(
    sched: Schedule, t: np.ndarray, latitude_deg: float, gravity_g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True gyro (deg/h) and accel (g) inputs in the body frame at times ``t``, and C_nb."""
    att = sched.attitude(t)
    C_nv = dcm_zyx(att["roll"], att["pitch"], att["heading"])
    C_vb = att["C_vb"]
    C_nb = C_nv @ C_vb
    lat = math.radians(latitude_deg)
    w_ie = OMEGA_IE_RAD_S * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    w_nv = vessel_rate(att)
    if sched.has_transit:  # the ship moves over the Earth (under_way); at a berth it does not
        w_in, a_move, gravity_g = under_way(sched, t, att["segment"], latitude_deg, gravity_g)
        w_ib = np.einsum("nji,nj->ni", C_nb, w_in)
    else:
        w_ib = np.einsum("nji,j->ni", C_nb, w_ie)
    w_ib = w_ib + np.einsum("nji,nj->ni", C_vb, w_nv) + att["w_vb"]  # C_bv w_nv^v, indexing
    a_n = np.zeros((len(t), 3))
    if sched.has_transit:
        a_n += a_move
    a_n[:, 2] -= att["heave_ddot"]  # heave is up, NED z is down
    if np.any(sched.lever):
        # d2/dt2 (C_nv r) = C_nv (alpha x r + w x (w x r)), alpha from a central difference of w
        h = 1e-3
        w_p = vessel_rate(sched.attitude(t + h))
        w_m = vessel_rate(sched.attitude(t - h))
        alpha = (w_p - w_m) / (2.0 * h)
        r = sched.lever
        a_v = np.cross(alpha, r) + np.cross(w_nv, np.cross(w_nv, r))
        a_n += np.einsum("nij,nj->ni", C_nv, a_v)
    f_n = a_n / G0_M_S2
    f_n[:, 2] -= gravity_g
    f_b = np.einsum("nji,nj->ni", C_nb, f_n)
    return w_ib * RAD_S_TO_DEG_H, f_b, C_nb


def under_way(
    sched: Schedule, t: np.ndarray, seg: np.ndarray, latitude_deg: float, gravity_g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For a schedule with transits, at times ``t``: the navigation frame's inertial rate
    w_ie^n + w_en^n (N, 3) rad/s at the latitude reached, the kinematic acceleration besides
    the sea's, dv^n/dt + (2 w_ie^n + w_en^n) x v^n (N, 3) m/s^2, and normal gravity there (N,)
    g (``gravity_g`` at the start latitude, moved by the change of normal gravity)."""
    from recal.detect.underway import EARTH_RADIUS_M as R

    tr = sched.track(t, seg)
    lat = math.radians(latitude_deg) + tr["north"] / R
    v = np.column_stack([tr["v_north"], tr["v_east"], np.zeros(len(t))])
    w_ie = OMEGA_IE_RAD_S * np.column_stack([np.cos(lat), np.zeros(len(t)), -np.sin(lat)])
    w_en = np.column_stack([tr["v_east"] / R, -tr["v_north"] / R, -tr["v_east"] * np.tan(lat) / R])
    a = np.column_stack([tr["a_north"], tr["a_east"], np.zeros(len(t))])
    a = a + np.cross(2.0 * w_ie + w_en, v)
    deg = np.degrees(lat)
    lo, hi = float(deg.min()), float(deg.max())
    g0 = normal_gravity_g(latitude_deg)  # normal gravity's change with latitude, exact at lo, hi
    g = gravity_g + np.interp(
        deg, [lo, hi + 1e-9], [normal_gravity_g(lo) - g0, normal_gravity_g(hi) - g0]
    )
    return w_ie + w_en, a, g
