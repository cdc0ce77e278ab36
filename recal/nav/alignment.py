"""Static initial alignment: levelling from the accelerometers, gyrocompassing from the gyros.

The mean corrected specific force ``f_b`` and body rate ``w_b`` over the alignment period give
the attitude directly (analytic coarse alignment, NED)::

    down_b  = -f_b / |f_b|                      (the reaction to gravity points up)
    east_b  = down_b x w_b / |down_b x w_b|     (Earth rate lies in the north-down plane)
    north_b = east_b x down_b
    C_bn    = [north_b; east_b; down_b]         (rows: the NED axes in body coordinates)

What survives alignment (first order, psi-angle errors of :mod:`recal.nav.ins_error`):

* An accelerometer bias ``del_N, del_E`` (NED components) tilts the level by exactly the angle
  that hides it at the start: ``psi_E = -del_N / g``, ``psi_N = del_E / g``. So no Schuler
  oscillation follows (the unaligned INS would oscillate with amplitude R del / g). What stays:
  an east accel bias together with its gyrocompass heading term (below) leaves psi parallel to
  Earth's axis, which is stationary -- hidden for good. A north accel bias leaves a tilt about
  east, which Earth rate turns (psi_N' = -Omega sin L psi_E): a 24 h error of order
  R del_N / g (0.64 km per 100 ug). The tilt also leaves the attitude wrong by del / g
  (0.1 mg -> 21 arcsec), and the bias shows again when the vessel turns.
* An east gyro error ``eps_E`` turns the heading: ``psi_D = eps_E / (Omega cos L)`` (plus a
  term from the east-accelerometer tilt, ``-tan L * del_E / g``). The heading error makes the
  computed frame turn so that eps_E is balanced: no static position error from it either.
  0.01 deg/h at 45 deg latitude -> 3.2 arcmin of heading.
* The gyro error along Earth's axis (north and down components) is not seen by a static
  alignment (the gyrocompass measures only the east component) and drives the position error:
  a longitude error that grows linearly with time plus 24 h and Schuler (84.4 min)
  oscillations. This is why recalibrating the gyro biases matters for a static INS.

Noise: the heading's 1-sigma is sigma(mean east rate) / (Omega cos L), i.e. ARW / sqrt(T) /
(Omega cos L); the tilt's is VRW / sqrt(T) / g. A FOG with ARW 0.0005 deg/rt h aligned for
300 s at 45 deg: 0.0017 deg/h / 10.6 deg/h = 1.6e-4 rad (0.55 arcmin).

Pure numerics; the CLI decides which samples are the alignment period.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from recal.errors import RecalInputError
from recal.model.reference import OMEGA_IE_RAD_S, normal_gravity_m_s2
from recal.nav.navigation import euler_angles

#: Highest |latitude| for gyrocompassing: the horizontal Earth rate Omega cos L vanishes at
#: the poles (at 85 deg it is 1.3 deg/h, a 0.01 deg/h bias turns the heading by 0.4 deg).
MAX_LATITUDE_DEG = 85.0
#: A segment's mean body rate above this (deg/h, beside Earth rate) means the body turned.
TURN_LIMIT_DEG_H = 200.0
#: Segment-to-segment change of the gravity direction above this (deg) means it moved.
TILT_LIMIT_DEG = 0.05
#: Mean |f| differing from normal gravity by more than this fraction means it accelerated.
GRAVITY_TOLERANCE = 0.01
#: Segments the alignment period is cut into for the static check.
SEGMENTS = 10


@dataclass(frozen=True)
class Alignment:
    """Attitude from one alignment period, per coefficient set (leading axis P).

    C_bn: (P, 3, 3) body to NED; rpy_rad: (P, 3) roll, pitch, yaw.
    heading_sigma_rad, tilt_sigma_rad: (P,) 1-sigma from the sensor noise seen in the period.
    """

    C_bn: np.ndarray
    rpy_rad: np.ndarray
    heading_sigma_rad: np.ndarray
    tilt_sigma_rad: np.ndarray


def coarse_alignment(force_b: np.ndarray, omega_b: np.ndarray) -> np.ndarray:
    """Mean specific force (..., 3) and body rate (..., 3), any units -> C_bn (..., 3, 3)."""
    down = -force_b / np.linalg.norm(force_b, axis=-1, keepdims=True)
    east = np.cross(down, omega_b)
    east /= np.linalg.norm(east, axis=-1, keepdims=True)
    north = np.cross(east, down)
    return np.stack([north, east, down], axis=-2)


def check_static(
    force_m_s2: np.ndarray,
    omega_rad_s: np.ndarray,
    latitude_deg: float,
    height_m: float = 0.0,
    what: str = "alignment period",
) -> None:
    """Raise :class:`RecalInputError` unless the samples (N, 3) look like a body at rest."""
    n = force_m_s2.shape[0]
    if n < SEGMENTS:
        raise RecalInputError(f"the {what} has only {n} samples: too short to align")
    cut = n // SEGMENTS * SEGMENTS
    f = force_m_s2[:cut].reshape(SEGMENTS, -1, 3).mean(axis=1)
    w = omega_rad_s[:cut].reshape(SEGMENTS, -1, 3).mean(axis=1)
    g = normal_gravity_m_s2(latitude_deg, height_m)
    ratio = np.linalg.norm(f, axis=1) / g
    u = f / np.linalg.norm(f, axis=1, keepdims=True)
    tilt = np.degrees(
        np.arccos(np.clip(u @ u.mean(axis=0) / np.linalg.norm(u.mean(axis=0)), -1, 1))
    )
    rate_dph = np.degrees(np.linalg.norm(w, axis=1)) * 3600.0
    turn = np.abs(rate_dph - math.degrees(OMEGA_IE_RAD_S) * 3600.0)
    problems = []
    if np.abs(ratio - 1.0).max() > GRAVITY_TOLERANCE:
        problems.append(f"|f| is {ratio.min():.3f}..{ratio.max():.3f} g_local")
    if tilt.max() > TILT_LIMIT_DEG:
        problems.append(f"the gravity direction moves by {tilt.max():.2f} deg")
    if turn.max() > TURN_LIMIT_DEG_H:
        problems.append(f"the body turns at up to {turn.max():.0f} deg/h")
    if problems:
        raise RecalInputError(
            f"the {what} is not static ({'; '.join(problems)}): start the recording at rest, "
            "or give --attitude ROLL,PITCH,YAW"
        )


def align_static(
    force_m_s2: np.ndarray,
    omega_rad_s: np.ndarray,
    latitude_deg: float,
    height_m: float = 0.0,
    check: bool = True,
) -> Alignment:
    """Align on the corrected samples of the alignment period: (P, N, 3) or (N, 3) each.

    ``check`` first verifies (on the first set) that the period is static.
    """
    if abs(latitude_deg) > MAX_LATITUDE_DEG:
        raise RecalInputError(
            f"gyrocompassing needs |latitude| <= {MAX_LATITUDE_DEG:g} deg (Earth rate is nearly "
            "vertical at the poles): give --attitude ROLL,PITCH,YAW"
        )
    f = np.asarray(force_m_s2, float)
    w = np.asarray(omega_rad_s, float)
    if f.ndim == 2:
        f, w = f[None], w[None]
    if check:
        check_static(f[0], w[0], latitude_deg, height_m)
    n = f.shape[1]
    C = coarse_alignment(f.mean(axis=1), w.mean(axis=1))
    # Noise of the means from the sample scatter (white noise assumed), in the NED frame.
    w_sem = np.linalg.norm(w.std(axis=1), axis=-1) / math.sqrt(3 * n)
    f_sem = np.linalg.norm(f.std(axis=1), axis=-1) / math.sqrt(3 * n)
    horizontal = OMEGA_IE_RAD_S * math.cos(math.radians(latitude_deg))
    g = normal_gravity_m_s2(latitude_deg, height_m)
    return Alignment(C, euler_angles(C), w_sem / horizontal, f_sem / g)


def parse_attitude(text: str) -> tuple[float, float, float]:
    """'ROLL,PITCH,YAW' in deg -> three floats, checked (roll, yaw in [-360, 360], |pitch| <= 90)."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise RecalInputError(f"--attitude must be ROLL,PITCH,YAW in degrees, not {text!r}")
    roll, pitch, yaw = values
    if abs(pitch) > 90.0 or abs(roll) > 360.0 or abs(yaw) > 360.0:
        raise RecalInputError(
            f"--attitude {text!r}: pitch must be within +-90 deg, roll and yaw within +-360"
        )
    return roll, pitch, yaw
