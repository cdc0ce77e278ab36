"""A hull-fixed IMU on a vessel, sample by sample: berth holds that rock, steady turns, indexing.

This is what the product's first user sees (``shared/spec/vessel.md`` has the magnitudes): the
IMU is bolted to the hull, so new orientations come only from heading changes (the vessel swings
at its berth, turns in port, or sails) or from an indexing (rotation-modulation) mechanism
between the hull and the IMU. Even at berth the hull is never still: it rolls, pitches, heaves and
swings slowly in yaw.

A :class:`VesselSpec` is a list of :class:`Segment` s:

* ``hold``: the vessel keeps its heading (apart from the sea's yaw swing) for ``duration_s``;
* ``turn``: a steady heading change by ``heading_change_deg``: the turn rate rises over
  ``turn_ramp_s`` (raised cosine), stays constant, and falls again, so a moving-variance test sees
  only the ramps;
* ``index``: the indexing mechanism turns the IMU in the hull to ``mount_rpy_deg`` about the
  fixed axis of the relative rotation (raised-cosine angle profile, as the lab sessions of
  :mod:`recal.sim.session`);
* ``transit``: the ship sails on its heading at ``speed_kn`` (from a standstill and back to one,
  raised-cosine speed ramps of ``VesselSpec.speed_ramp_s``), a straight line over a spherical
  Earth of radius :data:`recal.detect.underway.EARTH_RADIUS_M`. Only here does the vessel move
  over the Earth: its inputs then carry the transport rate w_en^n = (v_E / R, -v_N / R,
  -v_E tan(lat) / R), Earth's rate and gravity at the latitude it has reached, and the Coriolis
  and Eotvos accelerations (2 w_ie^n + w_en^n) x v^n besides the speed ramps' own;
  :func:`ship_track` gives its position, speed, course and heading (what its GNSS and
  gyrocompass say).

The sea (:class:`SeaState`) moves the hull in every segment: roll, pitch and yaw swing, each a
narrow-band sum of sinusoids (``components`` periods spread by ``period_spread`` around the
nominal, random phases) whose peak amplitude is about the given one (RMS times sqrt 2), heave,
and the lever arm of the IMU from the hull's centre of rotation (tangential and centripetal
accelerations). Each segment scales the sea by its ``sea_scale`` (0 is a flat calm); the scale
changes smoothly over ``sea_ramp_s`` at a segment's start.

Frames: navigation frame NED, the vessel frame forward-right-down, the IMU body frame turned in
the hull by the mount (``C_nb = C_nv C_vb``). The inputs are exact kinematics at the middle of
each sample interval:

    w_ib^b = C_bn w_ie^n + C_bv w_nv^v(Euler rates) + w_vb^b(indexing)       (deg/h)
    f^b    = C_bn (a^n - g^n),  a^n = heave + d2/dt2 (C_nv r^v)               (g)

and the outputs are the truth model's forward map of the inputs plus white noise
(:class:`recal.sim.simulate.NoiseSpec` densities), then, with ``VesselSpec.output_filter``, the
unit's own low-pass (:class:`OutputFilter`: a FOG's 1 kHz output through a second-order filter,
which makes its noise coloured). The vessel does not sail: transport rate and
Coriolis acceleration are zero outside ``transit`` segments (a unit under way at constant speed
sees the Eotvos effect, about 75 ug at 5 m/s, which the detector cannot tell from gravity; the
berth is where the product recalibrates).

A long voyage is simulated in chunks (:func:`vessel_chunks`), so a week at 100 Hz needs no more
memory than a chunk; :func:`simulate_vessel` returns a whole recording as a
:class:`recal.sim.session.Session` (holds = the ``hold`` segments), which
``service.capture_sim.session_to_kvh`` encodes as KVH frames. Pure numpy, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from scipy.signal import butter, lfilter, lfilter_zi

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.reference import G0_M_S2, OMEGA_IE_RAD_S, normal_gravity_g
from recal.nav.navigation import ENU_FROM_NED, attitude_matrix, euler_angles
from recal.nav.trajectory import dcm_zyx, euler_rates_to_body
from recal.sim.session import MAX_SAMPLES, Session, axis_angle, sample_context
from recal.sim.simulate import NoiseSpec, truth_model

_RAD_S_TO_DEG_H = math.degrees(1.0) * 3600.0
_KNOT_M_S = 1852.0 / 3600.0

SegmentKind = Literal["hold", "turn", "index", "transit"]


@dataclass(frozen=True)
class SeaState:
    """Hull motion (``shared/spec/vessel.md``): peak amplitudes in deg and m, periods in s.

    ``lever_arm_m`` is the IMU's position from the hull's centre of rotation in the vessel frame
    (forward, right, down), m. ``yaw_swing_deg`` is the slow heading swing at a berth.
    """

    roll_deg: float = 0.3
    roll_period_s: float = 8.0
    pitch_deg: float = 0.15
    pitch_period_s: float = 6.0
    yaw_swing_deg: float = 0.1
    yaw_period_s: float = 180.0
    heave_m: float = 0.0
    heave_period_s: float = 8.0
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    components: int = 3
    period_spread: float = 0.15
    #: heading creep at a berth or anchor, deg/h (mooring lines stretching, tide turning the
    #: ship): a steady rate about the vertical, which the yaw swing above never has (it averages
    #: to zero)
    creep_dph: float = 0.0
    #: the swing round a single anchor: heading amplitude (deg) of a sinusoid of
    #: ``anchor_period_s`` (a tide, 12.42 h), zero at the start and turning fastest there
    anchor_swing_deg: float = 0.0
    anchor_period_s: float = 12.42 * 3600.0

    @classmethod
    def calm(cls) -> SeaState:
        """A perfectly still hull (the laboratory case)."""
        return cls(roll_deg=0.0, pitch_deg=0.0, yaw_swing_deg=0.0, heave_m=0.0)

    @classmethod
    def berth(cls, roll_deg: float, yaw_swing_deg: float | None = None, **kw: float) -> SeaState:
        """A moored hull: pitch half the roll, yaw swing a third of it unless given."""
        yaw = roll_deg / 3.0 if yaw_swing_deg is None else yaw_swing_deg
        return cls(roll_deg=roll_deg, pitch_deg=roll_deg / 2.0, yaw_swing_deg=yaw, **kw)

    def __post_init__(self) -> None:
        for name in ("roll_period_s", "pitch_period_s", "yaw_period_s", "heave_period_s",
                     "anchor_period_s"):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise RecalInputError(f"sea state {name} must be a positive number, not {v}")
        if self.components < 1 or not 0 <= self.period_spread < 0.9:
            raise RecalInputError("sea state needs components >= 1 and 0 <= period_spread < 0.9")


@dataclass(frozen=True)
class Segment:
    """One stretch of the schedule (see the module docstring)."""

    kind: SegmentKind
    duration_s: float
    heading_change_deg: float = 0.0
    mount_rpy_deg: tuple[float, float, float] | None = None
    sea_scale: float = 1.0
    #: a transit's speed over ground, kn (its ramps in and out included in ``duration_s``)
    speed_kn: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("hold", "turn", "index", "transit"):
            raise RecalInputError(
                f"segment kind must be hold, turn, index or transit, not {self.kind!r}"
            )
        if not (math.isfinite(self.speed_kn) and self.speed_kn >= 0):
            raise RecalInputError(f"a transit's speed must be >= 0 kn, not {self.speed_kn}")
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise RecalInputError(f"segment duration must be positive, not {self.duration_s}")
        if self.kind == "index" and self.mount_rpy_deg is None:
            raise RecalInputError("an index segment needs the mount_rpy_deg it turns the IMU to")
        if self.sea_scale < 0:
            raise RecalInputError("sea_scale must be >= 0")


@dataclass(frozen=True)
class OutputFilter:
    """The unit's own output low-pass: a digital Butterworth of ``order`` (default 2) at
    ``cutoff_hz``, unit gain at zero frequency, run at the output rate (a FOG's electronics
    filter its 1 kHz output so).

    It filters the whole output of both triads, signal and noise alike, as the sensor does. Its
    noise is then no longer white: neighbouring samples are correlated over about
    1 / (2 pi cutoff_hz), and their variance is a fraction of the white level (41 %, 21 % and
    5.5 % at 200, 100 and 25 Hz for order 2 at 1 kHz), while a long mean's is the white level's
    (the filter passes zero frequency whole). The signal is delayed by the group delay,
    sqrt(2) / (2 pi cutoff_hz) at order 2 (2.3 ms at 100 Hz), and the truth (``gyro_in_dph``,
    ``accel_in_g``) is not: a window's mean then differs from the truth's by the delay times the
    signal's change across the window over its length, nothing against the noise at a berth. The
    filter starts settled on the first output (a unit that has been running) and keeps its state
    from chunk to chunk.
    """

    cutoff_hz: float
    order: int = 2

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cutoff_hz) and self.cutoff_hz > 0):
            raise RecalInputError(f"output filter cutoff must be positive, not {self.cutoff_hz}")
        if self.order < 1:
            raise RecalInputError(f"output filter order must be at least 1, not {self.order}")

    def coefficients(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) of the filter at ``rate_hz``."""
        if not self.cutoff_hz < 0.5 * rate_hz:
            raise RecalInputError(
                f"output filter cutoff {self.cutoff_hz:g} Hz must lie below half the rate "
                f"({0.5 * rate_hz:g} Hz)"
            )
        b, a = butter(self.order, self.cutoff_hz, fs=rate_hz)
        return np.asarray(b), np.asarray(a)

    def apply(
        self, x: np.ndarray, rate_hz: float, state: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """x (n, k) filtered along time, and the state to continue with; ``state`` None: the
        filter settled on x[0]."""
        b, a = self.coefficients(rate_hz)
        if state is None:
            state = lfilter_zi(b, a)[:, None] * x[:1]
        y, state = lfilter(b, a, x, axis=0, zi=state)
        return y, state


@dataclass(frozen=True)
class VesselSpec:
    """The schedule, the starting heading and mount, and the sea; ``output_filter``: the unit's
    own low-pass on its outputs (None, the default: white noise as drawn)."""

    segments: tuple[Segment, ...]
    heading0_deg: float = 0.0
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sea: SeaState = field(default_factory=SeaState)
    turn_ramp_s: float = 5.0
    sea_ramp_s: float = 60.0
    #: a transit's speed rises from and falls to a standstill over this, s
    speed_ramp_s: float = 60.0
    output_filter: OutputFilter | None = None

    def __post_init__(self) -> None:
        if not self.segments:
            raise RecalInputError("a vessel schedule needs at least one segment")
        for s in self.segments:
            if s.kind == "turn" and s.duration_s <= 2.0 * self.turn_ramp_s:
                raise RecalInputError(
                    f"a {s.duration_s:g} s turn is shorter than its two {self.turn_ramp_s:g} s ramps"
                )
            if s.kind == "transit" and s.duration_s <= 2.0 * self.speed_ramp_s:
                raise RecalInputError(
                    f"a {s.duration_s:g} s transit is shorter than its two {self.speed_ramp_s:g} s "
                    "speed ramps"
                )

    @property
    def duration_s(self) -> float:
        return float(sum(s.duration_s for s in self.segments))

    @classmethod
    def berth(
        cls,
        holds: int = 12,
        hold_s: float = 600.0,
        turn_s: float = 60.0,
        turn_deg: float = 30.0,
        sea: SeaState | None = None,
        heading0_deg: float = 0.0,
        mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
        transit_s: float = 0.0,
        transit_kn: float = 12.0,
    ) -> VesselSpec:
        """``holds`` holds of ``hold_s`` joined by steady ``turn_deg`` turns of ``turn_s``; with
        ``transit_s``, the ship sails that long at ``transit_kn`` on its heading after the first
        half of the holds (ceil(holds / 2)), to another berth where the rest are held."""
        if holds < 1:
            raise RecalInputError("a berth schedule needs at least one hold")
        segs: list[Segment] = []
        for k in range(holds):
            if k:
                segs.append(Segment("turn", turn_s, heading_change_deg=turn_deg))
            segs.append(Segment("hold", hold_s))
            if transit_s and k == (holds + 1) // 2 - 1:
                segs.append(Segment("transit", transit_s, speed_kn=transit_kn))
        return cls(tuple(segs), heading0_deg, mount_rpy_deg, sea or SeaState())

    @classmethod
    def indexing(
        cls,
        stops: Sequence[tuple[float, float, float]],
        hold_s: float = 600.0,
        index_s: float = 20.0,
        sea: SeaState | None = None,
        heading0_deg: float = 0.0,
    ) -> VesselSpec:
        """An IMU on an indexing mechanism: held at each mount attitude of ``stops`` (roll,
        pitch, yaw of the IMU in the hull, deg) for ``hold_s``, indexed between them in
        ``index_s``; the hull keeps its heading."""
        if not stops:
            raise RecalInputError("an indexing schedule needs at least one stop")
        segs: list[Segment] = [Segment("hold", hold_s)]
        for stop in stops[1:]:
            segs.append(Segment("index", index_s, mount_rpy_deg=tuple(stop)))
            segs.append(Segment("hold", hold_s))
        return cls(tuple(segs), heading0_deg, tuple(stops[0]), sea or SeaState())


@dataclass(frozen=True, eq=False)
class VesselRecording:
    """A simulated recording (``session``) and its truth.

    rpy_deg: (N, 3) roll, pitch, yaw of the IMU in NED at each sample's time stamp;
    segment: (N,) index of the segment each sample lies in; kinds: the segments' kinds.
    """

    session: Session
    rpy_deg: np.ndarray
    segment: np.ndarray
    spec: VesselSpec

    @property
    def time_s(self) -> np.ndarray:
        return self.session.time_s


# ---- the schedule, evaluated at any times ------------------------------------------------------
class _Schedule:
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
        self.speed = np.array([s.speed_kn * _KNOT_M_S if s.kind == "transit" else 0.0
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


def _vessel_rate(att: dict[str, np.ndarray]) -> np.ndarray:
    """w_nv^v: the vessel's rate relative to NED in the vessel frame, (N, 3) rad/s."""
    return euler_rates_to_body(
        att["roll"], att["pitch"], att["roll_dot"], att["pitch_dot"], att["heading_dot"]
    )


def _inputs(
    sched: _Schedule, t: np.ndarray, latitude_deg: float, gravity_g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True gyro (deg/h) and accel (g) inputs in the body frame at times ``t``, and C_nb."""
    att = sched.attitude(t)
    C_nv = dcm_zyx(att["roll"], att["pitch"], att["heading"])
    C_vb = att["C_vb"]
    C_nb = C_nv @ C_vb
    lat = math.radians(latitude_deg)
    w_ie = OMEGA_IE_RAD_S * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    w_nv = _vessel_rate(att)
    if sched.has_transit:  # the ship moves over the Earth (_under_way); at a berth it does not
        w_in, a_move, gravity_g = _under_way(sched, t, att["segment"], latitude_deg, gravity_g)
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
        w_p = _vessel_rate(sched.attitude(t + h))
        w_m = _vessel_rate(sched.attitude(t - h))
        alpha = (w_p - w_m) / (2.0 * h)
        r = sched.lever
        a_v = np.cross(alpha, r) + np.cross(w_nv, np.cross(w_nv, r))
        a_n += np.einsum("nij,nj->ni", C_nv, a_v)
    f_n = a_n / G0_M_S2
    f_n[:, 2] -= gravity_g
    f_b = np.einsum("nji,nj->ni", C_nb, f_n)
    return w_ib * _RAD_S_TO_DEG_H, f_b, C_nb


def _under_way(
    sched: _Schedule, t: np.ndarray, seg: np.ndarray, latitude_deg: float, gravity_g: float
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


def ship_track(
    spec: VesselSpec,
    time_s: np.ndarray,
    latitude_deg: float = 45.0,
    longitude_deg: float = 0.0,
    height_m: float = 0.0,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """What the ship's own sensors say at ``time_s`` (s from the start) of the recording
    :func:`vessel_chunks` makes of ``spec`` with this ``seed``: ``latitude_deg``,
    ``longitude_deg`` and ``height_m`` of its GNSS antenna (the hull's centre of rotation),
    ``sog_kn`` and ``cog_deg`` (speed and course over ground) and ``heading_deg`` (true heading,
    the sea's yaw swing and slow heading changes included), each (N,). Pure numbers: the NMEA
    sentences are written by the caller (service.cli.simulate_vessel)."""
    from recal.detect.underway import EARTH_RADIUS_M as R

    sched = _Schedule(spec, seed)
    t = np.asarray(time_s, dtype=float)
    att = sched.attitude(t)
    tr = sched.track(t, att["segment"])
    lat = latitude_deg + np.degrees(tr["north"] / R)
    mid = np.radians(0.5 * (latitude_deg + lat))  # a straight course: cos at the mean latitude
    lon = longitude_deg + np.degrees(tr["east"] / (R * np.cos(mid)))
    return {
        "latitude_deg": lat,
        "longitude_deg": (lon + 180.0) % 360.0 - 180.0,
        "height_m": np.full(len(t), float(height_m)),
        "sog_kn": tr["speed"] / _KNOT_M_S,
        "cog_deg": np.degrees(tr["course"]) % 360.0,
        "heading_deg": np.degrees(att["heading"]) % 360.0,
    }


def _check(spec: VesselSpec, rate_hz: float, latitude_deg: float) -> None:
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise RecalInputError(f"rate must be positive, not {rate_hz}")
    if not -89.0 <= latitude_deg <= 89.0:
        raise RecalInputError(f"latitude {latitude_deg} deg: a vessel needs |latitude| <= 89")
    if spec.duration_s * rate_hz < 2:
        raise RecalInputError("the schedule needs at least two samples")


@dataclass(frozen=True)
class VesselChunk:
    """One chunk of a long recording: time stamps (s), outputs, temperature and the truth."""

    time_s: np.ndarray
    gyro_out: np.ndarray
    accel_out: np.ndarray
    temperature_c: np.ndarray
    gyro_in_dph: np.ndarray
    accel_in_g: np.ndarray
    C_nb: np.ndarray  # (N, 3, 3) at the stamps
    segment: np.ndarray  # (N,) segment index


def vessel_chunks(
    truth: CoefficientSet,
    spec: VesselSpec,
    latitude_deg: float = 45.0,
    height_m: float = 0.0,
    rate_hz: float = 100.0,
    noise: NoiseSpec | None = None,
    temperature_c: float = 25.0,
    seed: int = 0,
    chunk_s: float = 600.0,
) -> Iterator[VesselChunk]:
    """The recording of ``spec`` in chunks of ``chunk_s`` seconds (the last one shorter).

    Sample i has time stamp i / rate_hz and the inputs at the middle of its interval. Each chunk
    draws its noise from its own generator (seed, chunk index), so the recording does not depend
    on anything but the seed and the chunk length. The Gauss-Markov bias of ``noise`` and the
    output filter (``spec.output_filter``) carry their state from chunk to chunk.
    """
    noise = noise if noise is not None else NoiseSpec(arw_deg_rt_h=0.012, vrw_ug_rt_hz=20.0)
    _check(spec, rate_hz, latitude_deg)
    sched = _Schedule(spec, seed)
    g = normal_gravity_g(latitude_deg, height_m)
    n_total = round(spec.duration_s * rate_hz)
    per_chunk = max(1, round(chunk_s * rate_hz))
    noise_at_rate = replace(noise, rate_hz=rate_hz)
    models = {s: truth_model(truth, s) for s in ("gyro", "accel")}
    gm_state = {s: np.zeros(3) for s in ("gyro", "accel")}
    gm_phi = math.exp(-1.0 / (noise.gm_tau_s * rate_hz)) if noise.gm_tau_s > 0 else 0.0
    lowpass = spec.output_filter
    if lowpass is not None:
        lowpass.coefficients(rate_hz)  # a cutoff above half the rate is bad input before any work
    filter_state: dict[str, np.ndarray | None] = {"gyro": None, "accel": None}
    for k, i0 in enumerate(range(0, n_total, per_chunk)):
        i1 = min(n_total, i0 + per_chunk)
        idx = np.arange(i0, i1)
        t = idx / rate_hz
        gyro_in, accel_in, _ = _inputs(sched, (idx + 0.5) / rate_hz, latitude_deg, g)
        att = sched.attitude(t)
        C_nb = dcm_zyx(att["roll"], att["pitch"], att["heading"]) @ att["C_vb"]
        rng = np.random.default_rng([seed, k])
        temp = np.full(len(t), float(temperature_c))
        ctx = sample_context(t, temp, accel_in)
        out = {}
        for sensor, x in (("gyro", gyro_in), ("accel", accel_in)):
            theta, model = models[sensor]
            noisy = x + rng.normal(size=x.shape) * noise_at_rate.per_sample_sigma(sensor)
            gm = noise.gauss_markov_sigma(sensor)
            if gm > 0:
                if k == 0:
                    gm_state[sensor] = rng.normal(size=3) * gm
                drive = rng.normal(size=x.shape) * (gm * math.sqrt(1.0 - gm_phi**2))
                # b_i = phi^(i+1) b_-1 + sum_j phi^(i-j) drive_j: a first-order recursion, in
                # closed form per chunk (scipy's lfilter with an initial state)
                b, _zf = lfilter([1.0], [1.0, -gm_phi], drive, axis=0,
                                 zi=(gm_phi * gm_state[sensor])[None, :])  # fmt: skip
                gm_state[sensor] = b[-1]
                noisy = noisy + b
            out[sensor] = model.forward(theta, noisy, ctx)[0]
            if lowpass is not None:  # the unit's own low-pass, on the whole output
                out[sensor], filter_state[sensor] = lowpass.apply(
                    out[sensor], rate_hz, filter_state[sensor]
                )
        yield VesselChunk(t, out["gyro"], out["accel"], temp, gyro_in, accel_in, C_nb,
                          att["segment"])  # fmt: skip


def simulate_vessel(
    truth: CoefficientSet,
    spec: VesselSpec | None = None,
    latitude_deg: float = 45.0,
    height_m: float = 0.0,
    rate_hz: float = 100.0,
    noise: NoiseSpec | None = None,
    temperature_c: float = 25.0,
    seed: int = 0,
) -> VesselRecording:
    """Every sample of ``spec`` (default: 12 berth holds of 10 min with 30-degree turns of 60 s
    in a 0.3-degree sea) as one :class:`VesselRecording`. ``noise`` defaults to a KVH
    1750-class unit: ARW 0.012 deg/sqrt(h), VRW 20 ug/sqrt(Hz)."""
    spec = spec or VesselSpec.berth()
    _check(spec, rate_hz, latitude_deg)
    N = round(spec.duration_s * rate_hz)
    if N > MAX_SAMPLES:
        raise RecalInputError(
            f"the recording would have {N} samples (limit {MAX_SAMPLES}): lower the rate, or "
            "stream it with vessel_chunks"
        )
    chunks = list(
        vessel_chunks(
            truth,
            spec,
            latitude_deg,
            height_m,
            rate_hz,
            noise,
            temperature_c,
            seed,
            chunk_s=max(1.0, spec.duration_s),
        )  # fmt: skip
    )
    c = chunks[0] if len(chunks) == 1 else _concat(chunks)
    seg = c.segment
    holds = np.flatnonzero(np.array([s.kind == "hold" for s in spec.segments]))
    first, last = [], []
    for h in holds:  # a loop over segments, not samples
        where = np.flatnonzero(seg == h)
        if len(where) >= 2:
            first.append(where[0])
            last.append(where[-1])
    hold_first, hold_last = np.array(first, dtype=np.int64), np.array(last, dtype=np.int64)
    session = Session(
        time_s=c.time_s,
        gyro_out=c.gyro_out,
        accel_out=c.accel_out,
        temperature_c=c.temperature_c,
        static=np.isin(seg, holds),
        gyro_in_dph=c.gyro_in_dph,
        accel_in_g=c.accel_in_g,
        hold_first=hold_first,
        hold_last=hold_last,
        orientations=ENU_FROM_NED @ c.C_nb[hold_first],
        rate_hz=float(rate_hz),
        latitude_deg=float(latitude_deg),
        height_m=float(height_m),
        gravity_g=normal_gravity_g(latitude_deg, height_m),
    )
    rpy = np.degrees(euler_angles(c.C_nb))
    return VesselRecording(session, rpy, seg, spec)


def _concat(chunks: list[VesselChunk]) -> VesselChunk:
    return VesselChunk(*(np.concatenate([getattr(c, f) for c in chunks]) for f in (
        "time_s", "gyro_out", "accel_out", "temperature_c", "gyro_in_dph", "accel_in_g", "C_nb",
        "segment")))  # fmt: skip


def random_hull_unit(rng: np.random.Generator) -> CoefficientSet:
    """A navigation-grade unit in deg/h and g for hull simulations: scale factors within 500 ppm
    of 1, gyro biases within 1 deg/h, accel biases within 1 mg, misalignments within 0.3 mrad
    (uniform draws from ``rng``, in that order), no quadratic term."""
    return CoefficientSet({
        "gyro.scale": 1.0 + rng.uniform(-5e-4, 5e-4, 3),
        "gyro.bias": rng.uniform(-1.0, 1.0, 3),
        "gyro.misalignment": rng.uniform(-3e-4, 3e-4, 6),
        "accel.scale": 1.0 + rng.uniform(-5e-4, 5e-4, 3),
        "accel.bias": rng.uniform(-1e-3, 1e-3, 3),
        "accel.misalignment": rng.uniform(-3e-4, 3e-4, 6),
        "accel.quadratic": np.zeros(3),
    })  # fmt: skip
