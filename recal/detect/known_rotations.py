"""Known rotations: slews whose rotation was commanded (an indexing mechanism, a fixture of
known angles), parsed from CSV (:class:`KnownRotations`), with the integrated gyro's residuals
against them and their 1-sigma, rad.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np

from recal.detect.quaternions import quat_conjugate, quat_from_rotvec, quat_multiply
from recal.detect.slew_data import Slews
from recal.detect.slew_rotation import DEG_H_TO_RAD_S, angle_random_walk_var, picked_rotations
from recal.errors import RecalInputError
from recal.model.reference import OMEGA_IE_RAD_S

#: Default 1-sigma of a commanded rotation, deg, when the file does not give one: an indexing
#: mechanism's encoder is good to arc-seconds; 0.01 deg leaves room for its mounting.
KNOWN_ROTATION_SIGMA_DEG = 0.01


@dataclass(frozen=True, eq=False)
class KnownRotations:
    """Commanded rotations of some slews (an indexing mechanism, a fixture of known angles).

    slew: (K,) the slews they belong to, as the row of the slew's first window in the positions
    (the slew from window ``slew[k]`` to the next one). rotvec: (K, 3) the rotation from the
    body frame at the end of that window to the one at the start of the next, as a rotation
    vector in the first frame (rad; the case's axes, i.e. the nominal sensor axes). sigma_rad:
    (K,) its 1-sigma per component.
    """

    slew: np.ndarray
    rotvec: np.ndarray
    sigma_rad: np.ndarray

    def __len__(self) -> int:
        return int(self.slew.shape[0])

    @classmethod
    def from_csv_text(cls, text: str, source: str = "<known rotations>") -> KnownRotations:
        """Parse ``axis_x,axis_y,axis_z,angle_deg[,sigma_deg][,window]``: one row per slew in
        order (row k: the slew after window k, unless a ``window`` column names it), the axis in
        the first window's body frame (any length), the angle right-handed in degrees. An empty
        angle marks a slew whose rotation is not known."""
        import csv

        rows = [r for r in csv.reader(io.StringIO(text)) if r and any(c.strip() for c in r)]
        if not rows:
            raise RecalInputError(f"{source}: empty (expected axis_x,axis_y,axis_z,angle_deg)")
        head = [c.strip() for c in rows[0]]
        need = ["axis_x", "axis_y", "axis_z", "angle_deg"]
        missing = [c for c in need if c not in head]
        if missing:
            raise RecalInputError(f"{source}: no column {', '.join(missing)} in the header")
        col = {c: head.index(c) for c in head}
        slew, rot, sig = [], [], []
        for n, r in enumerate(rows[1:], start=2):

            def cell(name: str, r=r, n=n) -> float | None:
                if name not in col or col[name] >= len(r) or not r[col[name]].strip():
                    return None
                try:
                    v = float(r[col[name]])
                except ValueError:
                    raise RecalInputError(
                        f"{source}: line {n}: {name} {r[col[name]]!r} is not a number"
                    ) from None
                if not math.isfinite(v):
                    raise RecalInputError(f"{source}: line {n}: {name} is not finite")
                return v

            angle = cell("angle_deg")
            if angle is None:
                continue
            axis = np.array([cell(c) or 0.0 for c in need[:3]])
            if np.linalg.norm(axis) == 0:
                raise RecalInputError(f"{source}: line {n}: the rotation axis is zero")
            sigma = cell("sigma_deg")
            if sigma is not None and sigma <= 0:
                raise RecalInputError(f"{source}: line {n}: sigma_deg must be positive")
            window = cell("window")
            slew.append(n - 2 if window is None else int(window))
            rot.append(axis / np.linalg.norm(axis) * math.radians(angle))
            sig.append(math.radians(KNOWN_ROTATION_SIGMA_DEG if sigma is None else sigma))
        if not slew:
            raise RecalInputError(f"{source}: no rotation with an angle")
        return cls(np.array(slew, dtype=np.int64), np.array(rot), np.array(sig))


def rotation_residuals(
    slews: Slews,
    known: KnownRotations,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    earth_rate: bool,
    zero_rate: np.ndarray | None = None,
) -> np.ndarray:
    """Known-rotation residuals (P, 3 K), rad: the integrated gyro rotation against the
    commanded one, ``2 vec(q_pred* q_gyro)`` in the first window's frame.

    The gyro measures the rotation in inertial space: the commanded one after Earth's turn over
    the slew, q_pred = q(w_b T) q_cmd with w_b the Earth rate in the first window's body frame
    (``earth_rate``: the calibrated rest rate). A gyro blind to Earth rate (``zero_rate``, see
    :func:`slew_rotations`) leaves that turn in the noise. ``known.slew`` must all be in
    ``slews.first``; the model arrays are those of :func:`slew_rotations` for all the slews.
    """
    pick = np.searchsorted(slews.first, known.slew)
    sub, q, rest = picked_rotations(slews, pick, gain, A, offset, zero_rate)
    q_cmd = quat_from_rotvec(known.rotvec)[None]  # (1, K, 4)
    if earth_rate:
        q_cmd = quat_multiply(quat_from_rotvec(rest * sub.duration_s[None, :, None]), q_cmd)
    d = quat_multiply(quat_conjugate(q_cmd), q)
    d = d * np.sign(d[..., :1] + 1e-300)  # the short way round
    return (2.0 * d[..., 1:]).reshape(q.shape[0], -1)


def rotation_sigma(
    slews: Slews,
    known: KnownRotations,
    gyro_std_in: np.ndarray,
    gyro_sem_in: np.ndarray | None,
    earth_rate: bool,
) -> np.ndarray:
    """1-sigma (3 K,) of the known-rotation residuals, rad: the gyro's angle random walk over
    the slew, the commanded rotation's own sigma and the Earth-rate term (its noise when taken
    out, the whole turn Omega T / sqrt(3) per component when left in)."""
    pick = np.searchsorted(slews.first, known.slew)
    i, T = slews.first[pick], slews.duration_s[pick]
    var = angle_random_walk_var(slews, gyro_std_in, pick) + known.sigma_rad**2
    if earth_rate and gyro_sem_in is not None:
        var = var + (DEG_H_TO_RAD_S * T) ** 2 * np.mean(gyro_sem_in[i] ** 2, axis=1)
    elif not earth_rate:
        var = var + (OMEGA_IE_RAD_S * T) ** 2 / 3.0
    return np.repeat(np.sqrt(var), 3)
