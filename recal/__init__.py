"""Pure numerics for in-field IMU recalibration: models, solvers, observability, detection.

Nothing in this package performs I/O beyond turning arrays and text already in memory into
objects, so every piece can be used from a notebook. The subpackages follow the pipeline:

    recal.model     error models, coefficient sets (versioned), positions, effect plug-ins
    recal.detect    samples -> static windows (detector, noise floor, noise model, slews)
    recal.solve     positions -> coefficients (problem, observability, LM, MCS-NAFSA, ...)
    recal.diagnose  missing effects, drift of a unit, information of new windows
    recal.nav       what coefficients do to navigation (INS error model, free-inertial runs)
    recal.sim       simulated units and sessions
    recal.report    HTML and plot reports (only the command line and the service import it)
    recal.runtime   process-level concerns (allocator, worker processes)

The names most scripts need are importable from here (loaded on first use, so ``import recal``
stays fast): ``from recal import calibrate, CalibrationOptions, CoefficientSet``.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: Public name -> module that defines it.
_API = {
    "CoefficientSet": "recal.model.coefficients",
    "read_coefficients": "recal.model.coefficients",
    "Positions": "recal.model.positions",
    "RecalInputError": "recal.errors",
    "StaticDetector": "recal.detect.static",
    "DetectorConfig": "recal.detect.static",
    "detect_static": "recal.detect.static",
    "windows_to_columns": "recal.detect.windows",
    "calibrate": "recal.solve.calibrate",
    "CalibrationOptions": "recal.solve.calibrate",
    "CalibrationResult": "recal.solve.calibrate",
    "diagnose": "recal.diagnose.effects",
    "drift_inputs": "recal.diagnose.drift",
    "drift_test": "recal.diagnose.drift",
    "DriftConfig": "recal.diagnose.drift",
    "information_gain": "recal.diagnose.information",
    "simulate_positions": "recal.sim.simulate",
    "simulate_session": "recal.sim.session",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'recal' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
