"""Pure numerics for in-field IMU recalibration: models, solvers, observability, detection.

Nothing in this package performs I/O beyond turning arrays and text already in memory into
objects, so every piece can be used from a notebook. The subpackages follow the pipeline:

    recal.model     error models, coefficient sets (versioned), positions, effect plug-ins
    recal.detect    samples -> static windows (detector, noise floor, noise model, slews)
    recal.solve     positions -> coefficients (problem, observability, LM, MCS-NAFSA, ...)
    recal.diagnose  missing effects, drift of a unit, information of new windows
    recal.nav       what coefficients do to navigation (INS error model, free-inertial runs)
    recal.sim       simulated units and sessions
    recal.fleet     what only a fleet knows: ageing per model (the fleet prior), outlier units
    recal.report    HTML and plot reports (only the command line and the service import it)
    recal.runtime   process-level concerns (allocator, worker processes)

The public API is the names of ``__all__``, importable from here: ``from recal import
calibrate, CalibrationOptions, CoefficientSet, Term``. They are loaded on first use, so
``import recal`` stays fast. A public name keeps its signature within a major version
(tests/test_public_api.py pins them); a module that moves keeps its old path for one minor
release with a DeprecationWarning (recal._moved). docs/api.md lists the names and the policy.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any

from recal import _moved

#: The release, in semantic versions (CHANGELOG.md). The single source: pyproject.toml reads it
#: from here (setuptools' static ``attr``, nothing imported), so it cannot disagree.
__version__ = "0.2.0"

#: Public name -> module that defines it, grouped as in docs/api.md.
_API = {
    # coefficients, positions, input errors
    "CoefficientSet": "recal.model.coefficients",
    "read_coefficients": "recal.model.coefficients",
    "Positions": "recal.model.positions",
    "RecalInputError": "recal.errors",
    # applying coefficients to raw outputs (docs/apply.md)
    "apply": "recal.model.apply",
    "Calibrated": "recal.model.apply",
    # error-model terms: what a plugin subclasses (recal.model.terms)
    "Term": "recal.model.terms",
    "Context": "recal.model.terms",
    "ScaleTerm": "recal.model.terms",
    "BiasTerm": "recal.model.terms",
    "MisalignmentTerm": "recal.model.terms",
    "QuadraticTerm": "recal.model.terms",
    "ColumnBiasTerm": "recal.model.terms",
    "TemperatureScaleTerm": "recal.model.terms",
    "GSensitivityTerm": "recal.model.terms",
    "ScaleAsymmetryTerm": "recal.model.terms",
    "seed_terms": "recal.model.terms",
    "catalogue_terms": "recal.model.terms",
    # plugins: load and check a file of terms, simulate one as a hidden truth
    "load_plugin_source": "recal.model.plugins",
    "validate_terms": "recal.model.plugins",
    "hidden_plugin": "recal.model.plugins",
    # detection
    "StaticDetector": "recal.detect.static_detector",
    "DetectorConfig": "recal.detect.static_config",
    "detect_static": "recal.detect.static_detector",
    "windows_to_columns": "recal.detect.windows",
    # calibration
    "calibrate": "recal.solve.calibrate",
    "CalibrationOptions": "recal.solve.options",
    "CalibrationResult": "recal.solve.result",
    "WanderModel": "recal.solve.wander_model",
    "TriadWander": "recal.solve.wander_model",
    # checking a calibration
    "diagnose": "recal.diagnose.effects",
    "drift_inputs": "recal.diagnose.drift",
    "drift_test": "recal.diagnose.drift",
    "DriftConfig": "recal.diagnose.drift",
    "information_gain": "recal.diagnose.information",
    # the fleet prior (issue 28)
    "FleetPrior": "recal.fleet.prior",
    "read_fleet_prior": "recal.fleet.prior",
    "VersionTable": "recal.fleet.history",
    "fleet_prior": "recal.fleet.compute",
    "outlier_units": "recal.fleet.outliers",
    "simulate_fleet": "recal.fleet.simulate",
    # simulators
    "simulate_positions": "recal.sim.simulate",
    "design_orientations": "recal.sim.simulate",
    "NoiseSpec": "recal.sim.simulate",
    "TemperatureSpec": "recal.sim.simulate",
    "simulate_session": "recal.sim.session",
    "simulate_handheld": "recal.sim.session",
    "HandheldSpec": "recal.sim.session",
    "simulate_vessel": "recal.sim.vessel",
    "VesselSpec": "recal.sim.vessel_spec",
    "SeaState": "recal.sim.vessel_spec",
    "Segment": "recal.sim.vessel_spec",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'recal' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    bound = globals().get(name)  # importing the module may have bound the function-and-package
    if isinstance(bound, _FunctionAndPackage) and bound.__wrapped__ is value:
        return bound
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)


class _FunctionAndPackage:
    """A public function whose name is also a subpackage's (``recal.diagnose``): calling it
    calls the function, its attributes are the package's (its submodules), and ``inspect``
    sees the function's signature and docstring. So both ``from recal import diagnose`` and
    ``import recal.diagnose.drift as m`` (which looks ``drift`` up on what ``recal.diagnose``
    is) work whatever was imported first."""

    def __init__(self, function: Any, package: types.ModuleType) -> None:
        object.__setattr__(self, "__wrapped__", function)
        object.__setattr__(self, "_package", package)
        for attr in ("__doc__", "__name__", "__qualname__", "__module__"):
            object.__setattr__(self, attr, getattr(function, attr))

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.__wrapped__(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._package, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self._package, name, value)  # a submodule imported later binds on the package

    def __repr__(self) -> str:
        return f"<function and package recal.{self.__name__}>"


class _Recal(types.ModuleType):
    """The package's module type: a public name is never replaced by a module of the same
    spelling. Importing a submodule binds it on its parent, so without this ``recal.diagnose``
    (the function) became the subpackage ``recal.diagnose`` after any ``import
    recal.diagnose.drift``, and ``recal.calibrate`` the old module ``recal.calibrate`` after a
    script imported that deprecated path: ``from recal import diagnose`` depended on what was
    imported before. A subpackage of a public function's name is reached through the function
    (:class:`_FunctionAndPackage`); a deprecated module of that name by its full name only."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _API and isinstance(value, types.ModuleType):
            if value.__name__ == f"{__name__}.{name}" and hasattr(value, "__path__"):
                function = getattr(importlib.import_module(_API[name]), name)
                super().__setattr__(name, _FunctionAndPackage(function, value))
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Recal
_moved.install(__all__)
