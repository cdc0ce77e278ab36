"""Predicted static navigation error from coefficient errors: the linear INS error model.

Public API (pure functions, no I/O, for the CLI, the benchmark and later the service):

* :func:`predict_static_error` ``(coeffs_used, coeffs_true, latitude_deg, height_m=0,
  attitude_rpy_deg=(0, 0, 0), hours=24, aligned=True) -> PredictedError``: the horizontal
  position error of a static INS that corrects its outputs with ``coeffs_used`` while the
  sensor follows ``coeffs_true``. ``PredictedError`` holds the north/east error curves (m) and
  ``final_nmi`` / ``max_nmi``, the sensor errors in the NED frame and the alignment error.
* :func:`predict_from_uncertainty` ``(sigma_or_doc, coeffs, latitude_deg, ...,
  covariance=None) -> UncertaintyPrediction``: the 1-sigma horizontal error (DRMS) the
  calibration uncertainty allows: 1-sigma per coefficient (a ``CoefficientSet`` of sigmas, or
  the ``"uncertainty"`` section of ``recal calibrate --json``; held coefficients, null there,
  count as exactly known) or a full covariance over the seed layout (gyro 12 then accel 15).
* :func:`describe_change` ``(old, new, ...)``: one sentence, "loading B instead of A changes the
  predicted 24 h static error from 4.5 to 1.2 nmi; the calibration uncertainty of B alone
  allows 0.3 nmi (1 sigma)" -- B is taken as the truth for A's error.

Model (psi-angle form, NED, height held, at rest; Titterton & Weston ch. 12, Benson 1975). The
computed attitude is C_c = (I - [psi x]) C_bn; with eps^n = C_bn dw^b the gyro error and del^n =
C_bn df^b the accelerometer error (rad/s, m/s^2)::

    d(dr)/dt = dv                                               (north, east, m)
    d(dv)/dt = -psi x f^n + del^n - 2 w_ie^n x dv - (g / R) dr  (Schuler loop)
    d(psi)/dt = -w_ie^n x psi - eps^n

The states are integrated exactly (matrix exponential over ``step_s``) for constant errors.
The sensor errors are exact differences at the IMU's attitude: ``dw^b = inverse(used,
forward(true, w^b)) - w^b``, the same for f. **They depend on how the IMU sits in the vessel**
(a scale-factor error of the axis that points up shows as a vertical accel error, one of an
axis pointing north as a north gyro error): ``attitude_rpy_deg`` is the IMU's roll, pitch, yaw
in NED, default level, x forward, heading 0 (x north, y east, z down).
With ``aligned=True`` the initial psi comes from running :func:`recal.nav.alignment.coarse_alignment`
on the same erroneous outputs, so the errors that alignment hides are hidden exactly as in
navigation (horizontal accel errors and the east gyro error, see :mod:`recal.nav.alignment`); the
north and down gyro errors remain and give the growing longitude error, the 24 h (Earth rate)
and Foucault modulations and the 84.4 min Schuler oscillation. ``aligned=False`` starts from
the true attitude (``recal navigate --attitude``).

Checked against :func:`recal.nav.navigation.navigate` on simulated data in the tests and the
benchmark.

The model lives in :mod:`recal.nav.ins_static` (the error states, the sensor errors, the static
prediction), the uncertainty's share in :mod:`recal.nav.ins_uncertainty` (the seed layout,
1-sigma values, the Jacobian) and a version's impact in :mod:`recal.nav.ins_impact`
(:class:`NavigationImpact`, :func:`describe_change`); this module gives their names, as before
the split (docs/navigation.md).
"""

from __future__ import annotations

from recal.model.reference import G0_M_S2, OMEGA_IE_RAD_S
from recal.model.terms import MISALIGNMENT_NAMES
from recal.nav.ins_impact import (
    NavigationImpact,
    complete_seed_set,
    describe_change,
    navigation_impact,
    seed_covariance,
)
from recal.nav.ins_static import (
    DEFAULT_STEP_S,
    PredictedError,
    corrected_static,
    error_dynamics,
    predict_static_error,
    propagate,
    psi_from_attitudes,
    schuler_amplitude_m,
    static_inputs,
)
from recal.nav.ins_uncertainty import (
    SEED_PARAMETERS,
    SEED_TERMS,
    UncertaintyPrediction,
    error_jacobian,
    predict_from_uncertainty,
    seed_sigma,
    sigma_from_doc,
)
from recal.nav.navigation import DEG_H_TO_RAD_S, NMI_M

#: The names this module had before the split, in its order then (``from recal.ins_error
#: import *``, the 0.1.0 path, gives the same).
__all__ = [
    "G0_M_S2", "OMEGA_IE_RAD_S", "MISALIGNMENT_NAMES", "DEG_H_TO_RAD_S", "NMI_M",
    "DEFAULT_STEP_S", "PredictedError", "UncertaintyPrediction", "error_dynamics", "propagate",
    "static_inputs", "corrected_static", "psi_from_attitudes", "predict_static_error",
    "SEED_TERMS", "SEED_PARAMETERS", "sigma_from_doc", "error_jacobian", "seed_sigma",
    "predict_from_uncertainty", "describe_change", "schuler_amplitude_m", "NavigationImpact",
    "seed_covariance", "navigation_impact", "complete_seed_set",
]  # fmt: skip
