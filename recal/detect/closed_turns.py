"""Closed turns: slews that turn whole revolutions about the vertical, found at the prior
(:func:`turn_candidates`), decided closed by the Earth-rate heading check or by declaration,
and their residuals (the heading misclosure, rad) and 1-sigma. A closed turn pins the gyro's
scale factor along the vertical, which the gravity directions alone cannot see.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from recal.detect.quaternions import quat_conjugate, quat_from_rotvec, quat_multiply
from recal.detect.slew_data import Slews
from recal.detect.slew_rotation import angle_random_walk_var, picked_rotations
from recal.model.reference import OMEGA_IE_DEG_H, OMEGA_IE_RAD_S

# ---- closed turns ------------------------------------------------------------------------------
#: A slew is a candidate closed turn when the gravity direction returns to within this angle, deg ...
CLOSED_TURN_TILT_DEG = 1.0
#: ... the gyro integrates within this of a whole, non-zero number of turns about the vertical,
#: deg (room for a prior scale a few % off) ...
CLOSED_TURN_SLACK_DEG = 30.0
#: ... and off the vertical by less than this, deg (a turn, not a tumble that ends where it began).
CLOSED_TURN_OFF_AXIS_DEG = 20.0
#: A candidate is taken as closed, checked, when its two windows' Earth-rate headings agree within
#: this many 1-sigma of their difference ...
HEADING_AGREEMENT_SIGMA = 3.0
#: ... and the heading is observable: the gyro bias's prior 1-sigma across the horizontal Earth
#: rate below this fraction of it (a bias as large as Earth rate turns the measured north with the
#: body, and two windows a turn apart would then agree whatever the turn).
HEADING_BIAS_MAX = 0.1
#: How a closed turn was decided (:attr:`TurnCandidate.how`).
CHECKED = "checked by Earth rate"
DECLARED = "declared"


@dataclass(frozen=True, eq=False)
class ClosedTurns:
    """Slews taken as whole turns about the vertical (gravity returns to where it was while the
    gyro integrates close to k x 360 deg about it). Their rotation is then known: k x 360 deg
    plus ``target_rad`` about the vertical, with the 1-sigma ``sigma_rad``. That pins the scale
    factor along the vertical, which the gravity directions alone cannot see.

    index: (C,) positions in the :class:`Slews` arrays. turns: (C,) signed whole turns k.
    axis: (C, 3) the vertical (unit gravity direction) in window ``first``'s body frame.
    sigma_rad: (C,) 1-sigma of the closure (the Earth-rate heading check's, or the declared one).
    target_rad: (C,) the heading change beyond k whole turns, as a rotation about ``axis``: the
    Earth-rate headings' for a checked turn, 0 for a declared one. checked: (C,) bool.
    """

    index: np.ndarray
    turns: np.ndarray
    axis: np.ndarray
    sigma_rad: np.ndarray
    target_rad: np.ndarray | None = None
    checked: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.index.shape[0])


class HeadingCheck(NamedTuple):
    """What the Earth-rate heading check needs beyond the slews, at the prior (or the current
    estimate). rate_dph / force_g: (M, 3) each window's calibrated mean rate (deg/h) and specific
    force (g); rate_sem_dph: (M, 3) the standard error of the window's mean rate, deg/h, or None
    (no noise columns); latitude_deg; bias_sigma_dph (3,) and scale_sigma_rel (3,): the gyro's
    prior 1-sigma (bias, deg/h; scale factor, relative); earth_rate: whether the gyro resolves
    Earth rate in a window (:func:`recal.solve.slew_fit._slews_see_earth_rate`)."""

    rate_dph: np.ndarray
    force_g: np.ndarray
    rate_sem_dph: np.ndarray | None
    latitude_deg: float
    bias_sigma_dph: np.ndarray
    scale_sigma_rel: np.ndarray
    earth_rate: bool = True


class TurnCandidate(NamedTuple):
    """A slew that integrates close to whole turns about the vertical, and what was decided.

    slew: position in the :class:`Slews` arrays; first / second: its windows; turns: k;
    integrated_deg: the gyro's angle about the vertical at the prior; closed; how:
    :data:`CHECKED`, :data:`DECLARED` or "" (not closed); reason: why. heading_first_deg /
    heading_second_deg: the azimuth of a body reference axis in each window from the horizontal
    Earth rate (NaN where the heading is not observable); heading_change_deg: the turn the two
    headings show beyond whole turns, about the vertical (right-handed about up); sigma_deg: its
    1-sigma (for a closed turn: the closure's 1-sigma).
    """

    slew: int
    first: int
    second: int
    turns: int
    integrated_deg: float
    closed: bool
    how: str
    reason: str
    heading_first_deg: float = float("nan")
    heading_second_deg: float = float("nan")
    heading_change_deg: float = float("nan")
    sigma_deg: float = float("nan")

    def to_json_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        return {
            "slew": self.slew, "windows": [self.first, self.second], "turns": self.turns,
            "integrated_deg": round(self.integrated_deg, 4), "closed": self.closed,
            "how": self.how or None, "reason": self.reason,
            "heading_first_deg": num(self.heading_first_deg),
            "heading_second_deg": num(self.heading_second_deg),
            "heading_change_deg": num(self.heading_change_deg), "sigma_deg": num(self.sigma_deg),
        }  # fmt: skip


def earth_rate_headings(
    rate: np.ndarray, up: np.ndarray, ref: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(heading (N,), rad, cross-track unit vectors (N, 3)) from the horizontal Earth rate.

    rate (N, 3): the window's calibrated mean rate; up (N, 3): its gravity direction (the
    specific force, unit); ref (N, 3): a body axis not along ``up``. The horizontal part of the
    rate points north; the heading is the azimuth (clockwise from north, seen from above) of
    ``ref`` projected on the horizontal plane: atan2 of north's components along (e1, up x e1).
    The cross-track direction ``up x north`` is the one whose rate noise moves the heading.
    """
    u = up / np.linalg.norm(up, axis=1, keepdims=True)
    e1 = ref - np.sum(ref * u, axis=1, keepdims=True) * u
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    h = rate - np.sum(rate * u, axis=1, keepdims=True) * u
    north = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
    psi = np.arctan2(np.sum(h * e2, axis=1), np.sum(h * e1, axis=1))
    return psi, np.cross(u, north)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


def turn_candidates(
    slews: Slews,
    rotvec: np.ndarray,
    up_first: np.ndarray,
    up_second: np.ndarray,
    declared_sigma_deg: float = 0.0,
    exclude: np.ndarray | None = None,
    check: HeadingCheck | None = None,
) -> list[TurnCandidate]:
    """The slews that may be whole turns about the vertical, each decided closed or not.

    A candidate: gravity returns to within :data:`CLOSED_TURN_TILT_DEG` while the gyro
    (``rotvec`` (S, 3), :func:`integrated_rotvec` at the prior) integrates within
    :data:`CLOSED_TURN_SLACK_DEG` of k x 360 deg (k != 0) about the vertical and less than
    :data:`CLOSED_TURN_OFF_AXIS_DEG` off it. up_first / up_second: (S, 3) gravity directions of
    each slew's two windows. exclude: (S,) bool, slews not to consider (a commanded rotation).

    Closed, checked, when the heading is observable (``check``: a gyro that resolves Earth rate,
    a bias prior well below the horizontal Earth rate, noise columns), the check can tell a
    closed turn from one the gyro scale could hide (the headings' 1-sigma difference at most
    the scale's prior 1-sigma x 360 deg x |k|) and the two windows' Earth-rate headings agree
    within :data:`HEADING_AGREEMENT_SIGMA` sigma: its target is the heading change they show,
    its 1-sigma theirs (the same orientation twice: the coefficients' errors cancel in the
    difference). Where the check cannot decide, closed only when declared
    (``declared_sigma_deg`` > 0, target 0). A check that shows the turn is not closed wins
    over a declaration.
    """
    if len(slews) == 0:
        return []
    u1 = up_first / np.linalg.norm(up_first, axis=1, keepdims=True)
    u2 = up_second / np.linalg.norm(up_second, axis=1, keepdims=True)
    tilt = np.arccos(np.clip(np.sum(u1 * u2, axis=1), -1.0, 1.0))
    about = np.sum(rotvec * u1, axis=1)  # signed angle about the vertical, rad
    off = np.linalg.norm(rotvec - about[:, None] * u1, axis=1)
    k = np.round(about / (2 * math.pi))
    ok = (
        (k != 0)
        & (tilt < math.radians(CLOSED_TURN_TILT_DEG))
        & (np.abs(about - 2 * math.pi * k) < math.radians(CLOSED_TURN_SLACK_DEG))
        & (off < math.radians(CLOSED_TURN_OFF_AXIS_DEG))
    )
    if exclude is not None:
        ok &= ~np.asarray(exclude, bool)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return []
    i, j = slews.first[idx], slews.second[idx]
    declare = (
        f"declared (--turn-closure {declared_sigma_deg:g} deg)" if declared_sigma_deg > 0 else ""
    )
    unseen = _heading_unseen(check)
    out = []
    psi1 = psi2 = change = sd = np.full(idx.size, np.nan)
    sd_bias = np.zeros(idx.size)
    if unseen is None:
        assert check is not None and check.rate_sem_dph is not None
        ref = np.eye(3)[np.argmin(np.abs(u1[idx]), axis=1)]  # the body axis most horizontal
        horizontal = OMEGA_IE_DEG_H * math.cos(math.radians(check.latitude_deg))
        psi1, c1 = earth_rate_headings(check.rate_dph[i], check.force_g[i], ref)
        psi2, c2 = earth_rate_headings(check.rate_dph[j], check.force_g[j], ref)
        sem = check.rate_sem_dph
        noise = np.sqrt(np.sum((c1 * sem[i]) ** 2, 1) + np.sum((c2 * sem[j]) ** 2, 1))
        sd = noise / horizontal  # rad, the difference's
        b = np.asarray(check.bias_sigma_dph, float)
        sd_bias = np.sqrt(np.maximum(np.sum((c1 * b) ** 2, 1), np.sum((c2 * b) ** 2, 1)))
        sd_bias = sd_bias / horizontal
        change = -_wrap(psi2 - psi1)  # the body turns one way, north the other
        # a turn about u integrates sum u_i^2 (1 + dK_i / K_i): the scales' share along u
        ks = np.sqrt(np.sum((u1[idx] ** 2 * np.asarray(check.scale_sigma_rel, float)) ** 2, 1))
        hidden = ks * 2 * math.pi * np.abs(k[idx])  # what a 1-sigma scale error hides, rad
    for n, s in enumerate(idx):
        base = dict(slew=int(s), first=int(i[n]), second=int(j[n]), turns=int(k[s]),
                    integrated_deg=math.degrees(float(about[s])),
                    heading_first_deg=math.degrees(float(psi1[n])) % 360.0,
                    heading_second_deg=math.degrees(float(psi2[n])) % 360.0,
                    heading_change_deg=math.degrees(float(change[n])))  # fmt: skip
        why = unseen
        if why is None and sd_bias[n] > HEADING_BIAS_MAX:
            why = (
                f"the heading is not observable: the gyro bias's prior 1-sigma moves it by "
                f"{math.degrees(sd_bias[n]):.3g} deg"
            )
        if why is None and sd[n] > hidden[n]:
            why = (
                f"the Earth-rate headings differ by {base['heading_change_deg']:+.3g} +- "
                f"{math.degrees(sd[n]):.3g} deg: too noisy to tell a closed turn from one that "
                f"a gyro scale 1-sigma of {ks[n] * 1e6:.3g} ppm hides ({math.degrees(hidden[n]):.3g} deg)"
            )
        if why is None:
            agree = abs(change[n]) <= HEADING_AGREEMENT_SIGMA * sd[n]
            text = (
                f"the Earth-rate headings differ by {base['heading_change_deg']:+.3g} +- "
                f"{math.degrees(sd[n]):.3g} deg"
            )
            if agree:
                out.append(TurnCandidate(**base, closed=True, how=CHECKED, reason=text,
                                         sigma_deg=math.degrees(float(sd[n]))))  # fmt: skip
            else:
                out.append(TurnCandidate(
                    **base, closed=False, how="", sigma_deg=math.degrees(float(sd[n])),
                    reason=f"{text}: not a closed turn" + (" (Earth rate overrules the "
                                                           "declaration)" if declare else ""),
                ))  # fmt: skip
            continue
        if declare:
            out.append(TurnCandidate(**base, closed=True, how=DECLARED,
                                     reason=f"{declare}: {why}", sigma_deg=declared_sigma_deg))  # fmt: skip
        else:
            out.append(TurnCandidate(**base, closed=False, how="",
                                     reason=f"{why}; not assumed closed unless declared "
                                     "(--turn-closure DEG)"))  # fmt: skip
    return out


def _heading_unseen(check: HeadingCheck | None) -> str | None:
    """Why no window's heading can be seen from Earth rate, or None."""
    if check is None:
        return "no Earth-rate heading check"
    if not check.earth_rate:
        return "the heading is not observable: Earth rate is below the gyro's window-mean noise"
    if check.rate_sem_dph is None:
        return "the heading check needs the windows' gyro noise (std or sem columns)"
    horizontal = OMEGA_IE_DEG_H * math.cos(math.radians(check.latitude_deg))
    if horizontal < 1e-3 * OMEGA_IE_DEG_H:
        return f"the heading is not observable at latitude {check.latitude_deg:g} deg"
    return None


def closed_turns_of(
    candidates: Sequence[TurnCandidate], up_first: np.ndarray
) -> ClosedTurns | None:
    """The :class:`ClosedTurns` of the candidates decided closed (``up_first`` (S, 3)), or None."""
    closed = [c for c in candidates if c.closed]
    if not closed:
        return None
    idx = np.array([c.slew for c in closed], dtype=np.int64)
    u1 = up_first[idx] / np.linalg.norm(up_first[idx], axis=1, keepdims=True)
    checked = np.array([c.how == CHECKED for c in closed])
    target = np.where(checked, np.radians([c.heading_change_deg for c in closed]), 0.0)
    return ClosedTurns(
        idx,
        np.array([c.turns for c in closed], dtype=np.int64),
        u1,
        np.radians([c.sigma_deg for c in closed]),
        target,
        checked,
    )


def closure_residuals(
    slews: Slews,
    turns: ClosedTurns,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    earth_rate: bool,
    zero_rate: np.ndarray | None = None,
) -> np.ndarray:
    """Closed-turn residuals (P, C), rad: the integrated rotation's component about the
    vertical after k whole turns (the heading misclosure) less the turn's target (the Earth-rate
    headings' change for a checked turn, 0 for a declared one), Earth's turn over the slew taken
    out as in :func:`rotation_residuals` with ``earth_rate``."""
    sub, q, rest = picked_rotations(slews, turns.index, gain, A, offset, zero_rate)
    if earth_rate:
        conj = quat_conjugate(quat_from_rotvec(rest * sub.duration_s[None, :, None]))
        q = quat_multiply(conj, q)
    q = q * np.sign(q[..., :1] + 1e-300)  # whole turns: q = -1 is no rotation
    r = np.einsum("psi,si->ps", 2.0 * q[..., 1:], turns.axis)
    return r if turns.target_rad is None else r - turns.target_rad[None]


def closure_sigma(
    slews: Slews, turns: ClosedTurns, gyro_std_in: np.ndarray, earth_rate: bool
) -> np.ndarray:
    """1-sigma (C,) of the closed-turn residuals, rad: the closure's own (the Earth-rate heading
    check's, or the declared one), the gyro's angle random walk over the slew (per-sample std in
    deg/h, (M, 3)) and, when Earth's turn is left in, its vertical part at most Omega T."""
    pick = turns.index
    T = slews.duration_s[pick]
    var = angle_random_walk_var(slews, gyro_std_in, pick) + turns.sigma_rad**2
    if not earth_rate:
        var = var + (OMEGA_IE_RAD_S * T) ** 2 / 3.0
    return np.sqrt(var)
