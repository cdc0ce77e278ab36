"""Sample-level simulation of a static multi-position session: holds joined by slews.

Where :mod:`recal.sim.simulate` draws the *window means* directly, this module simulates every
sample, so the whole chain (frames, detector, window statistics, calibration) can be tested on
data whose truth is known. Frames and conventions are those of :mod:`recal.sim.simulate`: ENU
navigation frame, body-to-ENU rotations ``C_nb``, Earth rate ``w_n = [0, Omega cos L,
Omega sin L]`` deg/h and specific force ``f_n = [0, 0, g]`` in g, resolved in the body frame as
``x_b = C_nb^T x_n``.

Between two holds the body turns about the fixed axis of the relative rotation with a
raised-cosine angle profile ``theta(u) = Theta (1 - cos(pi u)) / 2``, ``u`` in [0, 1): the rate
is zero at both ends, so the session has no step in rate. The IMU sits at the rotation centre:
no lever-arm (centripetal or tangential) acceleration.

Pure numpy and the engine's own model; no I/O and nothing of the drivers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import lfilter

from recal.detect.slew_data import DEFAULT_GROUPS, Slews
from recal.detect.slew_groups import build_slews
from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H, normal_gravity_g
from recal.model.terms import Term
from recal.sim.simulate import NoiseSpec, TemperatureSpec, design_orientations, truth_model

#: Longest session simulated at once, in samples. Each sample holds about 20 float64 values
#: (inputs, outputs, noise, model temporaries), so this bounds the peak memory near 2 GB.
MAX_SAMPLES = 10_000_000

_RAD_S_TO_DEG_H = math.degrees(1.0) * 3600.0


@dataclass(frozen=True, eq=False)
class Session:
    """A simulated recording, one row per sample at ``rate_hz``.

    time_s: (N,) sample times from the session start (sample i at i / rate_hz).
    gyro_out: (N, 3) gyro output in the model's output units (N_g: deg/h times K_g).
    accel_out: (N, 3) accel output in output units (N_a: g times K_a).
    temperature_c: (N,) sensor temperature, degC (not quantised).
    static: (N,) True inside a hold (the truth the detector is judged against).
    gyro_in_dph / accel_in_g: (N, 3) true noise-free inputs in the body frame (deg/h, g).
    hold_first / hold_last: (M,) indices of the first and last sample of each hold (inclusive).
    orientations: (M, 3, 3) body-to-ENU rotation C_nb of each hold.
    """

    time_s: np.ndarray
    gyro_out: np.ndarray
    accel_out: np.ndarray
    temperature_c: np.ndarray
    static: np.ndarray
    gyro_in_dph: np.ndarray
    accel_in_g: np.ndarray
    hold_first: np.ndarray
    hold_last: np.ndarray
    orientations: np.ndarray
    rate_hz: float
    latitude_deg: float
    height_m: float
    gravity_g: float

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def n_holds(self) -> int:
        return int(self.hold_first.shape[0])

    @property
    def hold_start_s(self) -> np.ndarray:
        """(M,) time of the first sample of each hold, s."""
        return self.hold_first / self.rate_hz

    @property
    def hold_end_s(self) -> np.ndarray:
        """(M,) time of the last sample of each hold, s."""
        return self.hold_last / self.rate_hz


def simulate_session(
    truth: CoefficientSet,
    design: str = "24",
    n_positions: int | None = None,
    latitude_deg: float = 45.0,
    height_m: float = 0.0,
    seed: int = 0,
    rate_hz: float = 1000.0,
    window_s: float = 20.0,
    slew_s: float = 5.0,
    first_hold_s: float | None = None,
    noise: NoiseSpec | None = None,
    temperature: TemperatureSpec | None = None,
    hidden: Sequence[Term] = (),
) -> Session:
    """Simulate every sample of a static multi-position session.

    Timing comes from ``rate_hz`` (samples/s), ``window_s`` (length of each hold, s),
    ``slew_s`` (length of each slew, s) and ``first_hold_s`` (length of the first hold, default
    ``window_s``; make it longer so a detector can learn its thresholds from an initial still
    period). From ``noise`` only the densities are used (``arw_deg_rt_h``, ``vrw_ug_rt_hz``),
    turned into a per-sample sigma at ``rate_hz``, and the Gauss-Markov bias (``gm_*``, off by
    default); its window/slew/rate fields are ignored.
    The orientations are :func:`recal.sim.simulate.design_orientations` with the same ``seed``, so
    they match :func:`recal.sim.simulate.simulate_positions`. ``hidden`` terms are added to the
    truth model as in that function (value from ``truth`` or the term's typical magnitude).
    """
    noise = noise or NoiseSpec()
    temperature = temperature or TemperatureSpec()
    first_hold_s = window_s if first_hold_s is None else first_hold_s
    for name, value in (
        ("rate_hz", rate_hz),
        ("window_s", window_s),
        ("slew_s", slew_s),
        ("first_hold_s", first_hold_s),
    ):
        if not (math.isfinite(value) and value > 0):
            raise RecalInputError(f"session {name} must be a positive number, not {value}")
    rng = np.random.default_rng(seed)
    C_nb = design_orientations(design, n_positions, rng)
    M = len(C_nb)
    n_hold = np.full(M, round(window_s * rate_hz), dtype=np.int64)
    n_hold[0] = round(first_hold_s * rate_hz)
    n_slew = round(slew_s * rate_hz)
    if n_hold.min() < 2 or n_slew < 2:
        raise RecalInputError(
            "holds and slews need at least 2 samples each: raise --rate, --window or --slew"
        )
    hold_first = np.concatenate(([0], np.cumsum(n_hold[:-1] + n_slew)))
    hold_last = hold_first + n_hold - 1
    N = int(hold_last[-1] + 1)
    if N > MAX_SAMPLES:
        raise RecalInputError(
            f"the session would have {N} samples (limit {MAX_SAMPLES}): lower the rate, the "
            "window or slew length, or the number of positions"
        )

    lat = math.radians(latitude_deg)
    g = normal_gravity_g(latitude_deg, height_m)
    w_n = np.array([0.0, OMEGA_IE_DEG_H * math.cos(lat), OMEGA_IE_DEG_H * math.sin(lat)])
    f_n = np.array([0.0, 0.0, g])
    gyro_in = np.empty((N, 3))
    accel_in = np.empty((N, 3))
    static = np.zeros(N, dtype=bool)
    # Slew profile, the same for every slew: u in [0, 1) over the slew's samples.
    u = np.arange(n_slew) / n_slew
    shape = 0.5 * (1.0 - np.cos(np.pi * u))  # theta / Theta
    # each sample's turn rate is the mean over its period (the increment of the profile times
    # the rate), not the rate at its start: the samples then carry exactly the angle Theta from
    # one hold's orientation to the next (the point rate falls short by (pi / 2n)^2 / 3: 3 ppm
    # of scale at 100 Hz over 5 s, which a fit with known rotations sees)
    edges = 0.5 * (1.0 - np.cos(np.pi * np.arange(n_slew + 1) / n_slew))
    shape_rate = np.diff(edges) * rate_hz  # d(theta/Theta)/dt averaged over each sample, 1/s
    for k in range(M):  # a loop over positions; every sample operation below is vectorised
        hold = slice(int(hold_first[k]), int(hold_last[k]) + 1)
        w_b, f_b = C_nb[k].T @ w_n, C_nb[k].T @ f_n
        gyro_in[hold], accel_in[hold] = w_b, f_b
        static[hold] = True
        if k == M - 1:
            break
        axis, angle = axis_angle(C_nb[k].T @ C_nb[k + 1])
        theta = angle * shape
        slew = slice(hold.stop, hold.stop + n_slew)
        # Body rate = turn rate about the (body-fixed) axis + Earth rate in the current body frame.
        turn_dph = np.outer(angle * shape_rate * _RAD_S_TO_DEG_H, axis)
        gyro_in[slew] = _rotate_into_body(w_b, axis, theta) + turn_dph
        accel_in[slew] = _rotate_into_body(f_b, axis, theta)

    time_s = np.arange(N) / rate_hz
    temp_c = temperature.at(time_s / 3600.0)
    ctx = {
        "temperature_c": temp_c,
        "temperature_rate_c_per_h": temperature.rate(time_s / 3600.0),
        "time_h": time_s / 3600.0,
        "specific_force_g": accel_in,
    }
    noise_at_rate = replace(noise, rate_hz=rate_hz)
    out = {}
    for sensor, x in (("gyro", gyro_in), ("accel", accel_in)):
        theta_vec, model = truth_model(truth, sensor, hidden)
        noisy = x + rng.normal(size=(N, 3)) * noise_at_rate.per_sample_sigma(sensor)
        gm_sigma = noise.gauss_markov_sigma(sensor)
        if gm_sigma > 0:  # drawn only when asked for, so white-noise sessions do not change
            noisy += gauss_markov(rng, N, gm_sigma, noise.gm_tau_s, rate_hz)
        out[sensor] = model.forward(theta_vec, noisy, ctx)[0]
    return Session(
        time_s=time_s,
        gyro_out=out["gyro"],
        accel_out=out["accel"],
        temperature_c=temp_c,
        static=static,
        gyro_in_dph=gyro_in,
        accel_in_g=accel_in,
        hold_first=hold_first,
        hold_last=hold_last,
        orientations=C_nb,
        rate_hz=float(rate_hz),
        latitude_deg=float(latitude_deg),
        height_m=float(height_m),
        gravity_g=g,
    )


def sample_context(
    time_s: np.ndarray, temperature_c: np.ndarray, specific_force_g: np.ndarray
) -> dict[str, np.ndarray]:
    """The per-sample context the sensor models read (a constant temperature: no rate)."""
    return {
        "temperature_c": temperature_c,
        "temperature_rate_c_per_h": np.zeros(len(time_s)),
        "time_h": np.asarray(time_s) / 3600.0,
        "specific_force_g": specific_force_g,
    }


def gauss_markov(
    rng: np.random.Generator, n: int, sigma: float, tau_s: float, rate_hz: float
) -> np.ndarray:
    """(n, 3) first-order Gauss-Markov process: stationary 1-sigma ``sigma``, correlation time
    ``tau_s`` (s), sampled at ``rate_hz``; b_k = phi b_(k-1) + sqrt(1 - phi^2) sigma w_k."""
    if not (math.isfinite(tau_s) and tau_s > 0):
        raise RecalInputError(f"Gauss-Markov correlation time must be > 0 s, not {tau_s}")
    phi = math.exp(-1.0 / (tau_s * rate_hz))
    drive = rng.normal(size=(n, 3)) * (sigma * math.sqrt(1.0 - phi * phi))
    # Start in the stationary distribution: the first sample already has variance sigma^2.
    drive[0] = rng.normal(size=3) * sigma
    return lfilter([1.0], [1.0, -phi], drive, axis=0)


def session_positions(session: Session, sensors: Sequence[str] = ("gyro", "accel")) -> Positions:
    """The true window means: one row per hold, every sample of the hold averaged.

    Columns as ``recal positions`` writes them (docs/reference.md#positions): start/end times of the
    hold's first and last samples, sample count, mean and per-sample standard deviation (ddof 1)
    per axis, mean temperature and its least-squares slope (degC/h).
    """
    rows = []
    for a, b in zip(session.hold_first, session.hold_last + 1, strict=True):
        t = session.time_s[a:b]
        temp = session.temperature_c[a:b]
        dt = t - t.mean()
        slope_c_per_s = float(dt @ (temp - temp.mean()) / (dt @ dt))
        row = {
            "start_s": t[0],
            "end_s": t[-1],
            "samples": float(b - a),
            "temperature_c": float(temp.mean()),
            "temperature_rate_c_per_h": slope_c_per_s * 3600.0,
        }
        for sensor in sensors:
            values = session.gyro_out[a:b] if sensor == "gyro" else session.accel_out[a:b]
            mean, std = values.mean(axis=0), values.std(axis=0, ddof=1)
            for i, axis in enumerate("xyz"):
                row[f"{sensor}_{axis}"] = mean[i]
                row[f"{sensor}_{axis}_std"] = std[i]
        rows.append(row)
    cols = {name: np.array([r[name] for r in rows]) for name in rows[0]}
    return Positions.from_columns(cols, source="simulated session (true holds)")


def axis_angle(R: np.ndarray) -> tuple[np.ndarray, float]:
    """Unit axis and angle (rad, in [0, pi]) of a rotation matrix: R = exp([axis]x angle).

    Goes through the quaternion (Shepperd's pivot on the largest of w, x, y, z) so it stays
    accurate at 0 and at 180 degrees, where the axis from the antisymmetric part alone fails.
    """
    tr = float(np.trace(R))
    pivot = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if pivot == 0:
        w = 0.5 * math.sqrt(max(1.0 + tr, 0.0))
        q = [w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w)]
        q.append((R[1, 0] - R[0, 1]) / (4 * w))
    else:
        i = pivot - 1
        j, k = (i + 1) % 3, (i + 2) % 3
        v = np.empty(3)
        v[i] = 0.5 * math.sqrt(max(1.0 + 2.0 * R[i, i] - tr, 0.0))
        w = (R[k, j] - R[j, k]) / (4 * v[i])
        v[j] = (R[i, j] + R[j, i]) / (4 * v[i])
        v[k] = (R[i, k] + R[k, i]) / (4 * v[i])
        q = [w, *v]
    qa = np.asarray(q, dtype=float)
    qa /= np.linalg.norm(qa)
    if qa[0] < 0:
        qa = -qa  # the shorter way round: angle <= pi
    s = float(np.linalg.norm(qa[1:]))
    if s == 0.0:
        return np.array([0.0, 0.0, 1.0]), 0.0
    return qa[1:] / s, 2.0 * math.atan2(s, float(qa[0]))


def _rotate_into_body(v: np.ndarray, axis: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """A navigation-fixed vector (given in the body frame at theta = 0) in the body frame after
    the body turned by theta (N,) about ``axis``: Rodrigues with -theta, shape (N, 3)."""
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    return v * c - np.cross(axis, v) * s + np.outer(1.0 - c[:, 0], axis * float(axis @ v))


def session_slews(session: Session, groups: int = DEFAULT_GROUPS) -> Slews:
    """The slews of a simulated session, as ``recal positions`` keeps them: between holds k and
    k + 1 the gyro outputs from the frame after hold k's last to hold k + 1's first, referenced
    to hold k's mean output (:func:`recal.detect.slew_groups.build_slews`). Hold rows as in
    :func:`session_positions`."""
    period = 1.0 / session.rate_hz
    pieces = []
    for k in range(session.n_holds - 1):  # a loop over slews; every sample operation is vectorised
        a, b = int(session.hold_first[k]), int(session.hold_last[k])
        samples = session.gyro_out[b + 1 : int(session.hold_first[k + 1]) + 1]
        pieces.append((k, k + 1, session.gyro_out[a : b + 1].mean(axis=0), samples))
    start, end = session.hold_start_s, session.hold_end_s
    return build_slews(pieces, period, start, end, groups=groups)


# ---- a hand-held low-cost MEMS session --------------------------------------------------------
#: Gravity directions (body frame, unnormalised) of the hand-held poses, in the order they are
#: taken: the six faces, then the cube diagonals, then the edge midpoints.
_HANDHELD_UP = np.array(
    [[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0],
     [1, 1, 1], [-1, 1, -1], [1, -1, -1], [-1, -1, 1], [1, 1, -1], [-1, 1, 1], [1, -1, 1],
     [-1, -1, -1], [1, 1, 0], [0, 1, 1], [1, 0, 1], [-1, 1, 0], [0, -1, 1], [1, 0, -1]],
    dtype=float,
)  # fmt: skip
#: A low-cost MEMS unit in raw counts (an MPU-6050-like datasheet): counts per deg/s, per g.
MEMS_GYRO_COUNTS_PER_DPS = 131.0
MEMS_ACCEL_COUNTS_PER_G = 16384.0


def mems_truth(rng: np.random.Generator | int | None = None) -> CoefficientSet:
    """Coefficients of a low-cost MEMS unit in raw counts: gyro 131 counts/(deg/s) (K_g in
    counts per deg/h) +-2 %, bias 0.5-3 deg/s (in deg/h); accel 16384 counts/g +-1 %, bias
    10-50 mg; misalignment ~3e-3 rad; no quadratic term."""
    rng = np.random.default_rng(rng)

    def signed(lo: float, hi: float) -> np.ndarray:
        return rng.choice([-1.0, 1.0], 3) * rng.uniform(lo, hi, 3)

    values = {
        "gyro.scale": MEMS_GYRO_COUNTS_PER_DPS / 3600.0 * (1.0 + 0.02 * rng.uniform(-1, 1, 3)),
        "gyro.bias": signed(0.5, 3.0) * 3600.0,
        "gyro.misalignment": 3e-3 * rng.normal(size=6),
        "accel.scale": MEMS_ACCEL_COUNTS_PER_G * (1.0 + 0.01 * rng.uniform(-1, 1, 3)),
        "accel.bias": signed(0.01, 0.05),
        "accel.misalignment": 3e-3 * rng.normal(size=6),
        "accel.quadratic": np.zeros(3),
    }
    return CoefficientSet(values, metadata={"source": "mems_truth (simulated)"})


@dataclass(frozen=True)
class HandheldSpec:
    """How a hand-held session is made (times in s, rates in deg/s, accelerations in g).

    hold_s: (min, max) of each pose's hold, drawn uniformly; slew_s: (min, max) of the turn to
    the next pose (raised-cosine angle profile). tremor_deg_s: (min, max) amplitude of the hand's
    physiological tremor, drawn per pose: a small rotation oscillating at tremor_hz (three
    sinusoids per axis drawn in that band); it changes smoothly across a slew. hand_accel_g:
    amplitude of the hand's own linear acceleration (three sinusoids per axis at 1-4 Hz).
    tilt_deg: how far a pose's gravity direction strays from its nominal one.
    gyro_noise_dps_rt_hz, accel_noise_ug_rt_hz: white noise densities. quantise: round the
    outputs to whole counts (and clip them to int16), as a raw MEMS recording is.
    """

    hold_s: tuple[float, float] = (5.0, 10.0)
    slew_s: tuple[float, float] = (2.0, 3.5)
    tremor_deg_s: tuple[float, float] = (0.5, 3.0)
    tremor_hz: tuple[float, float] = (8.0, 12.0)
    hand_accel_g: float = 1e-3
    tilt_deg: float = 5.0
    gyro_noise_dps_rt_hz: float = 0.01
    accel_noise_ug_rt_hz: float = 300.0
    quantise: bool = True


def simulate_handheld(
    truth: CoefficientSet | None = None,
    n_poses: int = 10,
    spec: HandheldSpec | None = None,
    rate_hz: float = 100.0,
    latitude_deg: float = 45.0,
    height_m: float = 0.0,
    temperature_c: float = 25.0,
    seed: int = 0,
) -> Session:
    """Simulate a low-cost MEMS unit held by hand in ``n_poses`` poses, every sample.

    The body attitude is C_nb(t) = C_base(t) exp([phi(t)]x): C_base holds each pose and turns
    between poses like :func:`simulate_session`; phi is the hand tremor (a small body-frame
    rotation vector, 8-12 Hz). Each gyro sample is the rotation from the sample's start to its
    end divided by the period (so the samples integrate exactly to the attitude change) plus
    Earth rate; each accel sample is the specific force at the sample's middle, with the hand's
    linear acceleration added. ``truth`` defaults to :func:`mems_truth` (raw counts); outputs
    are whole counts unless ``spec.quantise`` is off. ``Session.static`` marks the holds (the
    hand still trembles there: the accelerometer is still, the gyro is not).
    """
    from scipy.spatial.transform import Rotation

    spec = spec or HandheldSpec()
    rng = np.random.default_rng(seed)
    truth = mems_truth(rng) if truth is None else truth
    if not 1 <= n_poses <= len(_HANDHELD_UP):
        raise RecalInputError(f"hand-held poses: 1 to {len(_HANDHELD_UP)}, not {n_poses}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise RecalInputError(f"rate must be positive, not {rate_hz}")
    # Pose attitudes: the nominal gravity direction, a small hand tilt, a random heading.
    up = _HANDHELD_UP[:n_poses] / np.linalg.norm(_HANDHELD_UP[:n_poses], axis=1, keepdims=True)
    tilt = Rotation.from_rotvec(np.radians(spec.tilt_deg) * rng.uniform(-1, 1, (n_poses, 3)))
    up = tilt.apply(up)
    # C_nb^T e_up = up: align the body vector `up` with ENU up, then turn about the vertical.
    poses = []
    for u in up:
        align = Rotation.align_vectors([[0.0, 0.0, 1.0]], [u])[0]
        heading = Rotation.from_rotvec([0.0, 0.0, rng.uniform(0, 2 * np.pi)])
        poses.append(heading * align)
    n_hold = np.round(rng.uniform(*spec.hold_s, n_poses) * rate_hz).astype(np.int64)
    n_slew = np.round(rng.uniform(*spec.slew_s, max(n_poses - 1, 0)) * rate_hz).astype(np.int64)
    hold_first = np.concatenate(([0], np.cumsum(n_hold[:-1] + n_slew)))
    hold_last = hold_first + n_hold - 1
    N = int(hold_last[-1] + 1)
    if N > MAX_SAMPLES:
        raise RecalInputError(f"the session would have {N} samples (limit {MAX_SAMPLES})")
    # Attitude on a half-sample grid: edges (sample starts and ends) and sample middles.
    grid = np.arange(2 * N + 1) / (2.0 * rate_hz)
    k = np.searchsorted(hold_first / rate_hz, grid, side="right") - 1  # the pose last started
    base_rv = np.zeros((grid.shape[0], 3))
    amp = np.empty(grid.shape[0])
    tremor = rng.uniform(*spec.tremor_deg_s, n_poses)
    hold_end_t = (hold_last + 1) / rate_hz
    quats = np.empty((grid.shape[0], 4))
    for j in range(n_poses):  # a loop over poses; the samples of each are vectorised
        sel = k == j
        t = grid[sel]
        inside = t < hold_end_t[j]
        amp[sel] = tremor[j]
        rot = Rotation.from_quat(np.tile(poses[j].as_quat(), (t.shape[0], 1)))
        if j < n_poses - 1 and (~inside).any():
            rel = (poses[j].inv() * poses[j + 1]).as_rotvec()
            u = np.clip((t[~inside] - hold_end_t[j]) * rate_hz / n_slew[j], 0.0, 1.0)
            shape = 0.5 * (1.0 - np.cos(np.pi * u))
            base_rv[np.flatnonzero(sel)[~inside]] = shape[:, None] * rel
            amp[np.flatnonzero(sel)[~inside]] = tremor[j] + (tremor[j + 1] - tremor[j]) * shape
            rot = rot * Rotation.from_rotvec(base_rv[sel])
        quats[sel] = rot.as_quat()
    # Tremor: per axis three sinusoids in the tremor band, rate amplitude amp (deg/s) in all.
    f = rng.uniform(*spec.tremor_hz, (3, 3))
    phase = rng.uniform(0, 2 * np.pi, (3, 3))
    wave = np.sin(2 * np.pi * f[None] * grid[:, None, None] + phase[None]) / (2 * np.pi * f[None])
    phi = np.radians(amp)[:, None] * wave.sum(axis=2) / 3.0  # (G, 3) rad
    C = Rotation.from_quat(quats) * Rotation.from_rotvec(phi)  # body -> ENU
    edges, mid = C[0::2], C[1::2]
    lat = math.radians(latitude_deg)
    g = normal_gravity_g(latitude_deg, height_m)
    w_n = np.array([0.0, OMEGA_IE_DEG_H * math.cos(lat), OMEGA_IE_DEG_H * math.sin(lat)])
    turn = (edges[:-1].inv() * edges[1:]).as_rotvec() * rate_hz  # rad/s over each sample
    gyro_in = np.degrees(turn) * 3600.0 + mid.inv().apply(w_n)
    fa, pa = rng.uniform(1.0, 4.0, (3, 3)), rng.uniform(0, 2 * np.pi, (3, 3))
    t_mid = grid[1::2]
    hand = spec.hand_accel_g / 3.0 * np.sin(2 * np.pi * fa[None] * t_mid[:, None, None] + pa[None])
    accel_in = mid.inv().apply(np.array([0.0, 0.0, g]) + hand.sum(axis=2))
    time_s = np.arange(N) / rate_hz
    temp = np.full(N, float(temperature_c))
    ctx = sample_context(time_s, temp, accel_in)
    sigma = {
        "gyro": spec.gyro_noise_dps_rt_hz * 3600.0 * math.sqrt(rate_hz),  # deg/h per sample
        "accel": spec.accel_noise_ug_rt_hz * 1e-6 * math.sqrt(rate_hz),  # g per sample
    }
    out = {}
    for sensor, x in (("gyro", gyro_in), ("accel", accel_in)):
        theta, model = truth_model(truth, sensor)
        y = model.forward(theta, x + rng.normal(size=(N, 3)) * sigma[sensor], ctx)[0]
        out[sensor] = np.clip(np.round(y), -32768, 32767) if spec.quantise else y
    static = np.zeros(N, dtype=bool)
    for a, b in zip(hold_first, hold_last, strict=True):
        static[a : b + 1] = True
    return Session(
        time_s=time_s,
        gyro_out=out["gyro"],
        accel_out=out["accel"],
        temperature_c=temp,
        static=static,
        gyro_in_dph=gyro_in,
        accel_in_g=accel_in,
        hold_first=hold_first,
        hold_last=hold_last,
        orientations=np.array([p.as_matrix() for p in poses]),
        rate_hz=float(rate_hz),
        latitude_deg=float(latitude_deg),
        height_m=float(height_m),
        gravity_g=g,
    )
