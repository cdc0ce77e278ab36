"""Simulated static sessions: orientation designs, truth, noise -> a positions table.

Navigation frame is ENU (x east, y north, z up). At rest the gyro triad senses Earth rate
``[0, Omega cos L, Omega sin L]`` and the accelerometers the reaction to gravity ``[0, 0, g]``,
both resolved in the body frame: ``x_b = C_nb^T x_n``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import Model
from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H, normal_gravity_g
from recal.model.terms import Term

DESIGNS = ("24", "random", "vessel")


def _rot_x(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(np.shape(a) + (3, 3))
    R[..., 0, 0] = 1
    R[..., 1, 1], R[..., 1, 2], R[..., 2, 1], R[..., 2, 2] = c, -s, s, c
    return R


def _rot_y(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(np.shape(a) + (3, 3))
    R[..., 1, 1] = 1
    R[..., 0, 0], R[..., 0, 2], R[..., 2, 0], R[..., 2, 2] = c, s, -s, c
    return R


def _rot_z(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(np.shape(a) + (3, 3))
    R[..., 2, 2] = 1
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1] = c, -s, s, c
    return R


def design_orientations(
    design: str, n_positions: int | None, rng: np.random.Generator, tilt_deg: float = 1.5
) -> np.ndarray:
    """Body-to-ENU rotation matrices C_nb, shape (M, 3, 3).

    * ``"24"``: seed 002 section 7.1 -- each body axis in turn points north while the table
      turns about it in 45 deg steps (8 x 3 positions).
    * ``"random"``: uniformly random orientations (default 24).
    * ``"vessel"``: a hull-fixed IMU: z up, random headings, roll and pitch within +-tilt_deg.
    """
    if design == "24":
        if n_positions not in (None, 24):
            raise RecalInputError("the 24-position design has exactly 24 positions")
        north, west, up = np.array([0, 1.0, 0]), np.array([-1.0, 0, 0]), np.array([0, 0, 1.0])
        mats = []
        for k in range(3):  # body axis k points north; the next two start west and up
            base = np.zeros((3, 3))
            base[:, k], base[:, (k + 1) % 3], base[:, (k + 2) % 3] = north, west, up
            for phi in np.radians(np.arange(8) * 45.0):
                turn = (_rot_x, _rot_y, _rot_z)[k](phi)
                mats.append(base @ turn)
        return np.array(mats)
    n = 24 if n_positions is None else int(n_positions)
    if n < 1:
        raise RecalInputError("--positions must be at least 1")
    if design == "random":
        q = rng.normal(size=(n, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        w, x, y, z = q.T
        return np.stack(
            [
                np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
            ],
            axis=1,
        )
    if design == "vessel":
        heading = rng.uniform(0, 2 * np.pi, n)
        roll, pitch = np.radians(rng.uniform(-tilt_deg, tilt_deg, (2, n)))
        return _rot_z(heading) @ _rot_y(pitch) @ _rot_x(roll)
    raise RecalInputError(f"unknown design {design!r}; choose one of {', '.join(DESIGNS)}")


@dataclass(frozen=True)
class NoiseSpec:
    """Sensor noise and window timing.

    arw_deg_rt_h: gyro angle random walk, deg/sqrt(h) (seed 000 Table 4: 0.0005).
    vrw_ug_rt_hz: accelerometer white noise density, micro-g/sqrt(Hz).
    window_s: static window length; slew_s: time between windows; rate_hz: sample rate.
    gm_gyro_dph, gm_accel_ug: steady-state 1-sigma of a first-order Gauss-Markov bias added to
        every sample (deg/h, micro-g), correlation time gm_tau_s (s). Real sensors have such
        correlated noise (bias instability); 0 (the default) leaves it out. The sample-level
        simulator (:func:`recal.sim.session.simulate_session`) draws it per sample,
        :func:`simulate_positions` per window (the process averaged over the window, windows
        correlated by exp(-gap / tau)): the bias wander between windows.
    """

    arw_deg_rt_h: float = 0.0005
    vrw_ug_rt_hz: float = 20.0
    window_s: float = 100.0
    slew_s: float = 30.0
    rate_hz: float = 1000.0
    gm_gyro_dph: float = 0.0
    gm_accel_ug: float = 0.0
    gm_tau_s: float = 20.0

    def gauss_markov_sigma(self, sensor: str) -> float:
        """Steady-state 1-sigma of the Gauss-Markov bias in input units (deg/h or g)."""
        return self.gm_gyro_dph if sensor == "gyro" else self.gm_accel_ug * 1e-6

    def per_sample_sigma(self, sensor: str) -> float:
        """Per-sample 1-sigma in input units (deg/h or g)."""
        if sensor == "gyro":
            return self.arw_deg_rt_h * 60.0 * np.sqrt(self.rate_hz)  # deg/h/sqrt(Hz) * sqrt(Hz)
        return self.vrw_ug_rt_hz * 1e-6 * np.sqrt(self.rate_hz)


@dataclass(frozen=True)
class TemperatureSpec:
    """Temperature over the session (t in h): a ramp plus an optional daily-cycle-like swing,

    T(t) = start_c + slope_c_per_h * t + swing_c * sin(2 pi t / period_h).

    A swing makes temperature effects separable from a drift in time, which a ramp is not.
    """

    start_c: float = 20.0
    slope_c_per_h: float = 2.0
    swing_c: float = 0.0
    period_h: float = 1.0

    def at(self, t_h: np.ndarray) -> np.ndarray:
        """Temperature, degC."""
        w = 2 * np.pi / self.period_h
        return self.start_c + self.slope_c_per_h * t_h + self.swing_c * np.sin(w * t_h)

    def rate(self, t_h: np.ndarray) -> np.ndarray:
        """dT/dt, degC/h."""
        w = 2 * np.pi / self.period_h
        return self.slope_c_per_h + self.swing_c * w * np.cos(w * t_h)


def truth_model(
    truth: CoefficientSet, sensor: str, hidden: Sequence[Term] = ()
) -> tuple[np.ndarray, Model]:
    """The truth parameter vector (1, D) and the model that simulates ``sensor``: the seed model
    plus the ``hidden`` terms, which take their typical magnitude when ``truth`` lacks them."""
    extra = [t for t in hidden if t.sensor == sensor]
    model = Model.seed(sensor, extra)
    vals = truth.copy()
    for t in extra:
        if vals.get(t.name) is None:
            vals.values[t.name] = np.asarray(t.typical, float)
    missing = [t.name for t in model.terms if vals.get(t.name) is None]
    if missing:
        raise RecalInputError(f"truth lacks {', '.join(missing)}")
    return np.concatenate([vals.values[t.name] for t in model.terms])[None], model


def window_gauss_markov(
    t_mid_s: np.ndarray, window_s: float, sigma: float, tau_s: float, rng: np.random.Generator
) -> np.ndarray:
    """(M, 3) window means of a first-order Gauss-Markov process (steady-state 1-sigma
    ``sigma``, correlation time ``tau_s``) over windows of ``window_s`` centred at ``t_mid_s``:
    each mean's variance is the process's averaged over the window, consecutive means are
    correlated by exp(-gap / tau) (exact for windows much shorter than tau). Zeros when sigma is
    0 (no draw, so other draws are unchanged)."""
    M = len(t_mid_s)
    if sigma <= 0 or M == 0:
        return np.zeros((M, 3))
    x = window_s / tau_s
    var = sigma**2 * (2.0 * (x - 1.0 + np.exp(-x)) / x**2 if x > 1e-6 else 1.0)
    rho = np.exp(-np.diff(t_mid_s) / tau_s)
    out = np.empty((M, 3))
    out[0] = rng.normal(size=3)
    for k in range(1, M):  # an AR(1) recursion over windows (tens), not samples
        out[k] = rho[k - 1] * out[k - 1] + np.sqrt(1.0 - rho[k - 1] ** 2) * rng.normal(size=3)
    return out * np.sqrt(var)


def simulate_positions(
    truth: CoefficientSet,
    design: str = "24",
    n_positions: int | None = None,
    latitude_deg: float = 45.0,
    height_m: float = 0.0,
    seed: int = 0,
    sensors: Sequence[str] = ("gyro", "accel"),
    noise: NoiseSpec | None = None,
    temperature: TemperatureSpec | None = None,
    hidden: Sequence[Term] = (),
) -> Positions:
    """Simulate the window means of a static multi-position session.

    ``hidden`` terms (catalogue effects) are added to the truth model with their values taken
    from ``truth`` (or their typical magnitude when ``truth`` lacks them), so a calibration with
    the plain seed model sees an unmodelled effect.
    """
    noise = noise or NoiseSpec()
    temperature = temperature or TemperatureSpec()
    rng = np.random.default_rng(seed)
    C_nb = design_orientations(design, n_positions, rng)
    M = len(C_nb)
    lat = np.radians(latitude_deg)
    g = normal_gravity_g(latitude_deg, height_m)
    w_n = np.array([0.0, OMEGA_IE_DEG_H * np.cos(lat), OMEGA_IE_DEG_H * np.sin(lat)])
    f_n = np.array([0.0, 0.0, g])
    true_in = {
        "gyro": np.einsum("mji,j->mi", C_nb, w_n),
        "accel": np.einsum("mji,j->mi", C_nb, f_n),
    }
    start = np.arange(M) * (noise.window_s + noise.slew_s)
    end = start + noise.window_s
    samples = np.full(M, round(noise.window_s * noise.rate_hz), dtype=float)
    t_mid_h = 0.5 * (start + end) / 3600.0
    temp = temperature.at(t_mid_h)
    temp_rate = temperature.rate(t_mid_h)
    cols: dict[str, np.ndarray] = {"start_s": start, "end_s": end, "samples": samples}
    ctx = {
        "temperature_c": temp,
        "temperature_rate_c_per_h": temp_rate,
        "time_h": t_mid_h,
        "specific_force_g": true_in["accel"],
    }
    for sensor in sensors:
        theta, model = truth_model(truth, sensor, hidden)
        sigma_in = noise.per_sample_sigma(sensor)
        n_in = true_in[sensor] + rng.normal(size=(M, 3)) * sigma_in / np.sqrt(samples)[:, None]
        n_in += window_gauss_markov(
            0.5 * (start + end),
            noise.window_s,
            noise.gauss_markov_sigma(sensor),
            noise.gm_tau_s,
            rng,
        )
        out = model.forward(theta, n_in, ctx)[0]
        gain = np.abs(truth.values[f"{sensor}.scale"])
        for i, a in enumerate("xyz"):
            cols[f"{sensor}_{a}"] = out[:, i]
            cols[f"{sensor}_{a}_std"] = np.full(M, sigma_in * gain[i])
    cols["temperature_c"] = temp
    cols["temperature_rate_c_per_h"] = temp_rate
    return Positions.from_columns(cols, source=f"simulated {design} design")
