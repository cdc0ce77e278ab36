"""The calibration in the formats other tools read (``recal export``, docs/export.md).

:func:`export_calibration` turns a coefficient set (and, for the noise formats, a ``recal noise
--json`` document) into the text of each file the format has, plus what the format cannot carry
and what leaving it out costs (:mod:`recal.export.losses`). Pure: text out, the caller writes.

=============  ==========================================  ======================================
format         files                                        module
=============  ==========================================  ======================================
``kalibr``     ``imu.yaml`` noise keys                      :mod:`recal.export.noise_formats`
``ros``        sensor_msgs/Imu covariances (YAML)           :mod:`recal.export.noise_formats`
``imucal``     FerrarisCalibrationInfo JSON                 :mod:`recal.export.matrices`
``imu_tk``     one text file per triad (T, K, B)            :mod:`recal.export.matrices`
``px4``        QGroundControl ``.params``                   :mod:`recal.export.autopilot`
``ardupilot``  ``.parm`` (NAME,VALUE)                       :mod:`recal.export.autopilot`
=============  ==========================================  ======================================
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from recal.errors import RecalInputError
from recal.export import autopilot, matrices, noise_formats
from recal.export.losses import Loss
from recal.model.coefficients import CoefficientSet

FORMATS = ("kalibr", "imucal", "imu_tk", "ros", "px4", "ardupilot")
#: Formats whose content is the noise (``noise`` required).
NOISE_FORMATS = frozenset({"kalibr", "ros"})


@dataclass(frozen=True)
class Exported:
    """The files of one export: ``files`` maps a part name ("" for a format with one file;
    "acc", "gyro" for imu_tk) to its text; ``losses``: what the format cannot carry."""

    format: str
    files: dict[str, str]
    losses: list[Loss]


def export_calibration(
    coefficients: CoefficientSet,
    fmt: str,
    noise: Mapping[str, Any] | None = None,
    rate_hz: float | None = None,
) -> Exported:
    """``coefficients`` (and ``noise``, a ``recal noise --json`` object) in format ``fmt``.
    ``rate_hz``: the message rate of the ``ros`` covariances (default: the noise's rate)."""
    if fmt not in FORMATS:
        raise RecalInputError(f"unknown export format {fmt!r} (one of {', '.join(FORMATS)})")
    if fmt in NOISE_FORMATS:
        if noise is None:
            raise RecalInputError(f"--to {fmt} needs --noise NOISE.json (`recal noise --json`)")
        if fmt == "kalibr":
            return Exported(fmt, {"": noise_formats.kalibr(noise, coefficients)}, [])
        return Exported(fmt, {"": noise_formats.ros(noise, coefficients, rate_hz)}, [])
    make = {"imucal": matrices.imucal, "imu_tk": matrices.imu_tk, "px4": autopilot.px4,
            "ardupilot": autopilot.ardupilot}[fmt]  # fmt: skip
    files, lost = make(coefficients)
    return Exported(fmt, files, lost)
