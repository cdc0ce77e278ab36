"""The slew invariant: the gyro, integrated over the motion between two static windows, must carry
the gravity direction measured in the first window onto the one measured in the next.

Norms cannot see a rotation of a triad's frame (docs/reference.md#norms). Integrating the gyro over
each slew (the samples between two consecutive windows) can: the integrated rotation, applied to
the calibrated accelerometers' gravity direction of window k, predicts the direction of window
k + 1, and the two must agree (Tedaldi et al., ICRA 2014, the method of imu_tk). The residual has
2 degrees of freedom per slew (a rotation about the vertical moves no gravity direction).

Data (what ``recal positions`` keeps beside the CSV, :meth:`Slews.to_npz_bytes`): per slew the
indices of its two windows, the sample period, the window-k gyro output ``N_ref`` and, over ``G``
groups of consecutive samples (G = :data:`DEFAULT_GROUPS`, padded with empty groups), three sums
of the output increments ``n_i = (N_i - N_ref) dt`` (output units x s):

    S_g = sum_i n_i,   W_g = sum_i (m_g - 1 - 2 i) n_i,   C_g = 1/2 sum_{i<j} n_i x n_j

Because the gyro model is affine in its output (``alpha_i = M n_i + c``, with
``M = u A^-1 diag(1/K)``, ``c = u A^-1 (N_ref / K - b) dt`` and ``u`` = deg/h -> rad/s), the
second-order (Bortz / BCH) rotation vector of a group, ``sum alpha_i + 1/2 sum_{i<j} alpha_i x
alpha_j``, is exactly

    phi_g = M S_g + m_g c + 1/2 (M W_g) x c + cof(M) C_g,    cof(M) = det(M) M^-T

for every parameter vector: the per-sample coning correction survives the downsampling, and the
engine integrates ``G`` increments per slew instead of every sample. The groups' quaternions are
multiplied by a pairwise (tree) product: log2(G) vectorised steps for all P parameter vectors and
all slews at once.

Where each piece lives (issue 27); this module re-exports their names, so every name it held
before still imports from here:

* :mod:`recal.detect.slew_data`: :class:`Slews` and its side file, :data:`DEFAULT_GROUPS`,
  :data:`DROP_REASONS`, :data:`MAX_SLEW_S`;
* :mod:`recal.detect.slew_groups`: the group sums (:func:`group_increments`,
  :func:`compose_groups`, :func:`shift_reference`) and :func:`build_slews`;
* :mod:`recal.detect.slew_collect`: collection from a stream (:class:`SlewCollector`,
  :class:`SlewTracker`, :class:`ReducedSlew`, :func:`slews_from_reduced`);
* :mod:`recal.detect.quaternions`: the rotation algebra (:func:`quat_from_rotvec`,
  :func:`quat_multiply`, :func:`rotate_back`, :func:`rodrigues`, :func:`cofactor3`);
* :mod:`recal.detect.slew_rotation`: the integration batched over parameter vectors
  (:func:`slew_rotations`, :func:`integrated_rotvec`, :func:`integrate_samples`,
  :data:`DEG_H_TO_RAD_S`);
* :mod:`recal.detect.slew_gravity`: the invariant's residuals and 1-sigma
  (:func:`slew_residuals`, :func:`slew_sigma`, :func:`horizontal_basis`);
* :mod:`recal.detect.known_rotations`: commanded rotations (:class:`KnownRotations`,
  :func:`rotation_residuals`, :func:`rotation_sigma`);
* :mod:`recal.detect.closed_turns`: whole turns about the vertical and the Earth-rate heading
  check (:func:`turn_candidates`, :class:`ClosedTurns`, :func:`closure_residuals`, ...);
* :mod:`recal.detect.slew_gauge`: :func:`in_accel_frame`, the gauge of a fit with slews.

Everything here is numpy on arrays in memory: no I/O (the npz is produced and parsed as bytes).
"""

from __future__ import annotations

from recal.detect.closed_turns import (
    CHECKED,
    CLOSED_TURN_OFF_AXIS_DEG,
    CLOSED_TURN_SLACK_DEG,
    CLOSED_TURN_TILT_DEG,
    DECLARED,
    HEADING_AGREEMENT_SIGMA,
    HEADING_BIAS_MAX,
    ClosedTurns,
    HeadingCheck,
    TurnCandidate,
    closed_turns_of,
    closure_residuals,
    closure_sigma,
    earth_rate_headings,
    turn_candidates,
)
from recal.detect.known_rotations import (
    KNOWN_ROTATION_SIGMA_DEG,
    KnownRotations,
    rotation_residuals,
    rotation_sigma,
)
from recal.detect.quaternions import (
    cofactor3,
    quat_from_rotvec,
    quat_multiply,
    rodrigues,
    rotate_back,
)
from recal.detect.slew_collect import ReducedSlew, SlewCollector, SlewTracker, slews_from_reduced
from recal.detect.slew_data import DEFAULT_GROUPS, DROP_REASONS, MAX_SLEW_S, Slews
from recal.detect.slew_gauge import in_accel_frame
from recal.detect.slew_gravity import horizontal_basis, slew_residuals, slew_sigma
from recal.detect.slew_groups import build_slews, compose_groups, group_increments, shift_reference
from recal.detect.slew_rotation import (
    DEG_H_TO_RAD_S,
    integrate_samples,
    integrated_rotvec,
    slew_rotations,
)
from recal.model.reference import OMEGA_IE_DEG_H, OMEGA_IE_RAD_S

#: The names ``from recal.detect.slews import *`` gives (those it held before the split).
__all__ = [
    "OMEGA_IE_DEG_H",
    "OMEGA_IE_RAD_S",
    "DEFAULT_GROUPS",
    "DEG_H_TO_RAD_S",
    "DROP_REASONS",
    "MAX_SLEW_S",
    "Slews",
    "group_increments",
    "build_slews",
    "SlewCollector",
    "compose_groups",
    "shift_reference",
    "ReducedSlew",
    "SlewTracker",
    "slews_from_reduced",
    "in_accel_frame",
    "KNOWN_ROTATION_SIGMA_DEG",
    "KnownRotations",
    "rotation_residuals",
    "rotation_sigma",
    "cofactor3",
    "quat_from_rotvec",
    "quat_multiply",
    "rotate_back",
    "rodrigues",
    "slew_rotations",
    "horizontal_basis",
    "slew_residuals",
    "slew_sigma",
    "integrate_samples",
    "CLOSED_TURN_TILT_DEG",
    "CLOSED_TURN_SLACK_DEG",
    "CLOSED_TURN_OFF_AXIS_DEG",
    "HEADING_AGREEMENT_SIGMA",
    "HEADING_BIAS_MAX",
    "CHECKED",
    "DECLARED",
    "ClosedTurns",
    "HeadingCheck",
    "TurnCandidate",
    "earth_rate_headings",
    "integrated_rotvec",
    "turn_candidates",
    "closed_turns_of",
    "closure_residuals",
    "closure_sigma",
]
