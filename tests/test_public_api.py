"""The public API (docs/api.md) is a contract: its names, their signatures, the old module paths
that still work with a DeprecationWarning, and the version that says which release this is.

The tables below are the contract written out, not read from the code: a public name that
disappears, a parameter renamed, reordered or given another default, or an old path dropped
before its release fails here. A deliberate change edits the table, docs/api.md and
CHANGELOG.md together (a removal or an incompatible change needs the next major version, or a
deprecation first).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import re
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import pytest

import recal

ROOT = Path(__file__).resolve().parents[1]

#: ``recal.__all__``: every name a plugin, a notebook or a script may import from recal.
PUBLIC_NAMES = {
    "__version__",
    # coefficients, positions, input errors
    "CoefficientSet", "read_coefficients", "Positions", "RecalInputError",
    # applying coefficients (docs/apply.md)
    "apply", "Calibrated",
    # error-model terms and plugins
    "Term", "Context", "ScaleTerm", "BiasTerm", "MisalignmentTerm", "QuadraticTerm",
    "ColumnBiasTerm", "TemperatureScaleTerm", "GSensitivityTerm", "ScaleAsymmetryTerm",
    "seed_terms", "catalogue_terms", "load_plugin_source", "validate_terms", "hidden_plugin",
    # detection
    "StaticDetector", "DetectorConfig", "detect_static", "windows_to_columns",
    # calibration
    "calibrate", "CalibrationOptions", "CalibrationResult", "WanderModel", "TriadWander",
    # checking a calibration
    "diagnose", "drift_inputs", "drift_test", "DriftConfig", "information_gain",
    # the fleet prior
    "FleetPrior", "read_fleet_prior", "VersionTable", "fleet_prior", "outlier_units",
    "simulate_fleet",
    # simulators
    "simulate_positions", "design_orientations", "NoiseSpec", "TemperatureSpec",
    "simulate_session", "simulate_handheld", "HandheldSpec",
    "simulate_vessel", "VesselSpec", "SeaState", "Segment",
}  # fmt: skip

#: Term and the subclasses a plugin may instantiate or subclass.
TERM_CLASSES = ("Term", "ScaleTerm", "BiasTerm", "MisalignmentTerm", "QuadraticTerm",
                "ColumnBiasTerm", "TemperatureScaleTerm", "GSensitivityTerm",
                "ScaleAsymmetryTerm")  # fmt: skip

REQUIRED = object()  # a parameter or field without a default
KW = "keyword-only"

#: Parameters of the main callables: (name, default) or (name, default, KW), in order.
SIGNATURES = {
    "calibrate": [("positions", REQUIRED), ("options", None), ("progress", None)],
    "diagnose": [("positions", REQUIRED), ("options", None), ("candidates", None),
                 ("max_rounds", 4)],
    "simulate_positions": [("truth", REQUIRED), ("design", "24"), ("n_positions", None),
                           ("latitude_deg", 45.0), ("height_m", 0.0), ("seed", 0),
                           ("sensors", ("gyro", "accel")), ("noise", None), ("temperature", None),
                           ("hidden", ())],
    "simulate_session": [("truth", REQUIRED), ("design", "24"), ("n_positions", None),
                         ("latitude_deg", 45.0), ("height_m", 0.0), ("seed", 0),
                         ("rate_hz", 1000.0), ("window_s", 20.0), ("slew_s", 5.0),
                         ("first_hold_s", None), ("noise", None), ("temperature", None),
                         ("hidden", ())],
    "simulate_vessel": [("truth", REQUIRED), ("spec", None), ("latitude_deg", 45.0),
                        ("height_m", 0.0), ("rate_hz", 100.0), ("noise", None),
                        ("temperature_c", 25.0), ("seed", 0)],
    "read_coefficients": [("data", REQUIRED), ("terms", None), ("source", "JSON")],
    "apply": [("coefficients", REQUIRED), ("gyro", REQUIRED), ("accel", REQUIRED),
              ("temperature", None), ("time_s", None, KW), ("gyro_unit", "deg/h", KW),
              ("accel_unit", "g", KW), ("terms", None, KW)],
    "fleet_prior": [("versions", REQUIRED), ("model", REQUIRED), ("version", 1),
                    ("false_alarm", 0.01), ("created_at", None), ("metadata", None)],
    "detect_static": [("time_s", REQUIRED), ("gyro", REQUIRED), ("accel", REQUIRED),
                      ("temperature_c", None), ("valid", None), ("lost_before", None),
                      ("config", None, KW)],
    "load_plugin_source": [("source", REQUIRED), ("path", REQUIRED)],
    "hidden_plugin": [("term", REQUIRED), ("C_nb", REQUIRED), ("latitude_deg", REQUIRED)],
}  # fmt: skip

#: Fields of the dataclasses a script builds, in order (positional construction relies on it).
FIELDS = {
    "CalibrationOptions": [
        ("sensor", None), ("method", "lm"), ("mc_runs", 100), ("seed", 0),
        ("latitude_deg", 45.0), ("height_m", 0.0), ("prior", None), ("effects", ()),
        ("plugin_terms", ()), ("paper", False), ("polish", False), ("swarm_config", None),
        ("cycles", 4), ("indicator_threshold", None), ("t0_c", 25.0), ("slews", None),
        ("known_rotations", None), ("turn_closure_sigma_deg", 0.0), ("wander", None),
        ("refuse_at_solution", True), ("fleet_prior", None), ("prior_age_months", None),
    ],
    # a plugin constructs its terms positionally: Term("gyro.x", "gyro", ("a",), ...)
    "Term": [
        ("name", REQUIRED), ("sensor", REQUIRED), ("params", REQUIRED), ("units", REQUIRED),
        ("typical", REQUIRED), ("neutral", REQUIRED), ("explanation", REQUIRED),
        ("category", ""), ("needs", frozenset()), ("linearize_at_zero", False),
        ("relative_typical", False),
    ],
    "NoiseSpec": [
        ("arw_deg_rt_h", 0.0005), ("vrw_ug_rt_hz", 20.0), ("window_s", 100.0),
        ("slew_s", 30.0), ("rate_hz", 1000.0), ("gm_gyro_dph", 0.0), ("gm_accel_ug", 0.0),
        ("gm_tau_s", 20.0),
    ],
}  # fmt: skip

#: Fields a Term subclass adds after Term's (keyword arguments of a catalogue-style plugin).
SUBCLASS_FIELDS = {
    "ColumnBiasTerm": [("column", "temperature_c"), ("origin", 0.0)],
    "TemperatureScaleTerm": [("t0_c", 25.0)],
}

#: What a Term subclass overrides (``None`` from each means "no contribution") and what the
#: engine reads from any term: method -> parameters after self.
TERM_METHODS = {
    "scale": ("p", "ctx"),
    "matrix": ("p",),
    "offset": ("p", "ctx"),
    "nonlinear": ("p", "x", "ctx"),
    "nonlinear_components": ("p", "x", "ctx"),
    "unit_of": ("i",),
}
TERM_PROPERTIES = ("size", "group")

#: Old module path -> (a name it had, the module that defines the name now). Each works, with
#: a DeprecationWarning naming the new path, until 0.3.0.
MOVED = {
    "recal.alignment": ("Alignment", "recal.nav.alignment"),
    "recal.calibrate": ("CalibrationOptions", "recal.solve.options"),
    "recal.coefficient_schema": ("schema_version", "recal.model.coefficient_schema"),
    "recal.coefficients": ("CoefficientSet", "recal.model.coefficients"),
    "recal.consider": ("prior_sigma", "recal.solve.consider"),
    "recal.convergence": ("FixedPoint", "recal.solve.convergence"),
    "recal.drift": ("DriftConfig", "recal.diagnose.drift"),
    "recal.imucal": ("coefficients_from_imucal", "recal.model.imucal"),
    "recal.information": ("InformationGain", "recal.diagnose.information"),
    "recal.ins_error": ("PredictedError", "recal.nav.ins_error"),
    "recal.lm": ("LMResult", "recal.solve.lm"),
    "recal.mcs": ("run_mcs", "recal.solve.mcs"),
    "recal.nafsa": ("NafsaConfig", "recal.solve.nafsa"),
    "recal.navigation": ("radii_m", "recal.nav.navigation"),
    "recal.noise": ("edf_simple", "recal.detect.noise"),
    "recal.oafsa": ("OafsaConfig", "recal.solve.oafsa"),
    "recal.observability": ("jacobian", "recal.solve.observability"),
    "recal.perf": ("tune_allocator", "recal.runtime.allocator"),
    "recal.phases": ("Phase", "recal.solve.phases"),
    "recal.plausibility": ("UnitCheck", "recal.detect.plausibility"),
    "recal.plots": ("html_page", "recal.report.plots"),
    "recal.plugins": ("builtin_names", "recal.model.plugins"),
    "recal.positions": ("Positions", "recal.model.positions"),
    "recal.problem": ("Problem", "recal.solve.problem"),
    "recal.reference": ("normal_gravity_m_s2", "recal.model.reference"),
    "recal.report_navigation": ("navigation_html", "recal.report.navigation"),
    "recal.report_positions": ("TraceEnvelope", "recal.report.positions"),
    "recal.safsa": ("SafsaConfig", "recal.solve.safsa"),
    "recal.session": ("Session", "recal.sim.session"),
    "recal.simulate": ("simulate_positions", "recal.sim.simulate"),
    "recal.slews": ("Slews", "recal.detect.slew_data"),
    "recal.static": ("StaticDetector", "recal.detect.static_detector"),
    "recal.surrogate": ("motion_names", "recal.solve.surrogate"),
    "recal.swarm": ("SwarmConfig", "recal.solve.swarm"),
    "recal.terms": ("Term", "recal.model.terms"),
    "recal.trajectory": ("Leg", "recal.nav.trajectory"),
    # split modules: each name from where it went
    "recal.static:NoiseFloorEstimator": ("NoiseFloorEstimator", "recal.detect.floor"),
    "recal.static:windows_to_columns": ("windows_to_columns", "recal.detect.windows"),
    "recal.mcs:PROGRESS_POLL_S": ("PROGRESS_POLL_S", "recal.runtime.pool"),
    # 0.2.0 paths of modules that only re-exported others (issue 38)
    "recal.detect.static": ("DetectorConfig", "recal.detect.static_config"),
    "recal.detect.static:REJECT_REASONS": ("REJECT_REASONS", "recal.detect.static_report"),
    "recal.detect.slews": ("SlewTracker", "recal.detect.slew_collect"),
    "recal.detect.slews:OMEGA_IE_DEG_H": ("OMEGA_IE_DEG_H", "recal.model.reference"),
    # old modules whose path is now a package of the same name
    "recal.diagnose": ("diagnose", "recal.diagnose.effects"),
    "recal.model": ("Model", "recal.model.error_model"),
    "recal.report": ("diagnosis_html", "recal.report.html"),
}


def _parameters(func) -> list[tuple]:
    out = []
    for p in inspect.signature(func).parameters.values():
        default = REQUIRED if p.default is inspect.Parameter.empty else p.default
        assert p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY), (func.__name__, p)
        out.append(
            (p.name, default) if p.kind == p.POSITIONAL_OR_KEYWORD else (p.name, default, KW)
        )
    return out


def _fields(cls) -> list[tuple]:
    out = []
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out.append((f.name, f.default))
        elif f.default_factory is not dataclasses.MISSING:
            out.append((f.name, f.default_factory()))
        else:
            out.append((f.name, REQUIRED))
    return out


# ---- the names ----------------------------------------------------------------------------------
def test_the_public_names_are_the_pinned_ones() -> None:
    gone = sorted(PUBLIC_NAMES - set(recal.__all__))
    assert not gone, f"public names removed (a breaking change: deprecate first): {gone}"
    new = sorted(set(recal.__all__) - PUBLIC_NAMES)
    assert not new, f"new public names: add them to PUBLIC_NAMES, docs/api.md, CHANGELOG: {new}"
    assert len(recal.__all__) == len(set(recal.__all__))


def test_every_public_name_resolves_to_its_definition() -> None:
    for name in sorted(set(recal.__all__) - {"__version__"}):
        value = getattr(recal, name)
        value = getattr(value, "__wrapped__", value)  # recal.diagnose: function and package
        defining = importlib.import_module(recal._API[name])
        assert value is getattr(defining, name), name
        if inspect.isclass(value) or inspect.isfunction(value):
            assert value.__module__ == defining.__name__, name  # defined there, not re-exported
    assert set(dir(recal)) >= set(recal.__all__)


def test_a_public_name_is_not_replaced_by_a_module_of_the_same_spelling() -> None:
    """``recal.diagnose`` is a function and a subpackage; importing the subpackage binds it on
    recal, which made ``from recal import drift_test, diagnose`` return the package."""
    first = (
        "import recal.diagnose.drift\n"
        "from recal import diagnose, drift_test\n"
        "from recal.diagnose import effects, information\n"
        "assert getattr(diagnose, '__wrapped__', diagnose) is effects.diagnose, diagnose\n"
        "import recal\n"
        "assert recal.diagnose is diagnose\n"
    )
    # the function first, then the subpackage through it (the name is both)
    then = (
        "import inspect\n"
        "from recal import diagnose\n"
        "import recal.diagnose.drift as m\n"
        "import recal.diagnose.information\n"
        "import recal\n"
        "assert m.__name__ == 'recal.diagnose.drift' and recal.diagnose.drift is m\n"
        "assert recal.diagnose.information.information_gain is recal.information_gain\n"
        "assert list(inspect.signature(recal.diagnose).parameters)[:2] == "
        "['positions', 'options']\n"
        "assert recal.diagnose.__doc__.startswith('Rank candidate effects')\n"
    )
    for code in (first, then):
        subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_importing_recal_loads_nothing_until_a_name_is_used() -> None:
    code = "import sys, recal\nprint(sorted(m for m in sys.modules if m.startswith(('recal', 'numpy'))))"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                         text=True, timeout=60).stdout  # fmt: skip
    assert out.strip() == "['recal', 'recal._moved']"


def test_docs_api_lists_every_public_name() -> None:
    text = (ROOT / "docs" / "api.md").read_text()
    missing = [n for n in sorted(PUBLIC_NAMES) if f"`{n}`" not in text]
    assert not missing, missing


# ---- the signatures -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(SIGNATURES))
def test_signature(name: str) -> None:
    assert _parameters(getattr(recal, name)) == SIGNATURES[name]


@pytest.mark.parametrize("name", sorted(FIELDS))
def test_dataclass_fields(name: str) -> None:
    assert _fields(getattr(recal, name)) == FIELDS[name]


def test_term_interface() -> None:
    Term = recal.Term
    for method, params in TERM_METHODS.items():
        assert tuple(inspect.signature(getattr(Term, method)).parameters)[1:] == params, method
    for prop in TERM_PROPERTIES:
        assert isinstance(inspect.getattr_static(Term, prop), property), prop
    base = FIELDS["Term"]
    for cls_name in TERM_CLASSES:
        cls = getattr(recal, cls_name)
        assert issubclass(cls, Term) and dataclasses.is_dataclass(cls), cls_name
        assert cls.__dataclass_params__.frozen, cls_name  # terms are hashable values
        assert _fields(cls) == base + SUBCLASS_FIELDS.get(cls_name, []), cls_name


def test_a_plugin_built_on_the_public_names_validates() -> None:
    """What docs/api.md shows a plugin author: subclass ``recal.Term``, override a
    contribution; the loader's checks accept it."""

    @dataclasses.dataclass(frozen=True)
    class CrossBias(recal.Term):
        def offset(self, p, ctx):
            return p[:, None, :] * 0.0 + p[:, None, :]

    term = CrossBias("gyro.api_cross", "gyro", ("cx", "cy", "cz"), "deg/h", (0.01,) * 3,
                     (0.0,) * 3, "a constant extra bias")  # fmt: skip
    assert recal.validate_terms([term], "inline") == [term]


# ---- the old paths ------------------------------------------------------------------------------
@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_path_works_and_warns_naming_the_new_one(old: str) -> None:
    name, home = MOVED[old]
    module = importlib.import_module(old.split(":")[0])
    # where the old path is now a package, the package stays: its old names are deprecated
    subject = f"{old}.{name}" if hasattr(module, "__path__") else module.__name__
    pattern = rf"^{re.escape(subject)} is deprecated; import {name} from {re.escape(home)}"
    with pytest.warns(DeprecationWarning, match=pattern + r".* removed in 0\.3\.0$"):
        value = getattr(module, name)
    assert value is getattr(importlib.import_module(home), name)


def test_an_old_import_statement_warns_at_its_own_line() -> None:
    with pytest.warns(DeprecationWarning) as record:
        from recal.terms import Term  # noqa: F401 - the old path is the point
    (w,) = [w for w in record if "recal.terms" in str(w.message)]
    assert Path(w.filename) == Path(__file__)
    assert str(w.message) == (
        "recal.terms is deprecated; import Term from recal.model.terms (or recal) — "
        "it will be removed in 0.3.0"
    )


def test_an_old_star_import_gives_the_old_names() -> None:
    namespace: dict = {}
    with pytest.warns(DeprecationWarning):
        exec("from recal.terms import *", namespace)
    assert {"Term", "ColumnBiasTerm", "catalogue_terms", "MISALIGNMENT_NAMES"} <= set(namespace)
    assert "np" not in namespace and "dataclass" not in namespace


def test_the_new_paths_do_not_warn() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        from recal import Term  # noqa: F401
        from recal.diagnose import drift, effects  # noqa: F401 - submodules, not old names
        from recal.model import terms  # noqa: F401
        from recal.model.terms import ColumnBiasTerm  # noqa: F401


OLD_STYLE_PLUGIN = '''
"""A plugin written for the 0.1.0 layout (recal.terms), before the modules moved."""
from dataclasses import dataclass

from recal.terms import ColumnBiasTerm, Term


@dataclass(frozen=True)
class CrossBias(Term):
    def nonlinear(self, p, x, ctx):
        out = 0 * x
        out[..., 2] = p[:, None, 0] * x[..., 0]
        return out


TERMS = [
    CrossBias("gyro.old_cross", "gyro", ("c",), "1", (1e-4,), (0.0,), "z bias from x rate"),
    ColumnBiasTerm("accel.old_drift", "accel", ("dx", "dy", "dz"), "g/h", (5e-2,) * 3,
                   (0.0,) * 3, "warm-up", needs=frozenset({"time_h"}), column="time_h"),
]
'''


def test_an_old_style_plugin_loads_with_the_warning(tmp_path: Path) -> None:
    from service.cli.common import load_plugin

    plugin = tmp_path / "old_style.py"
    plugin.write_text(OLD_STYLE_PLUGIN)
    with pytest.warns(DeprecationWarning, match=r"^recal\.terms is deprecated") as record:
        terms = load_plugin(str(plugin))
    assert [t.name for t in terms] == ["gyro.old_cross", "accel.old_drift"]
    assert isinstance(terms[0], recal.Term)
    assert {Path(w.filename) for w in record if "recal.terms" in str(w.message)} == {plugin}


def test_the_command_line_shows_an_old_style_plugins_warning_once(tmp_path: Path) -> None:
    """Python hides DeprecationWarnings outside ``__main__``; a plugin is the user's code, so
    ``recal calibrate --plugin`` shows them (once, though calibrate loads the file twice)."""
    plugin = tmp_path / "old_style.py"
    plugin.write_text(OLD_STYLE_PLUGIN)
    positions = tmp_path / "pos.csv"
    positions.write_text(recal.simulate_positions(recal.CoefficientSet.seed_truth()).to_csv_text())
    argv = ["calibrate", str(positions), "--latitude", "45", "--sensor", "gyro",
            "--plugin", str(plugin), "--effects", "+gyro.old_cross"]  # fmt: skip
    code = f"from service.cli.main import main\nraise SystemExit(main({argv!r}))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stderr.splitlines() if "DeprecationWarning" in line]
    assert lines == [
        f"{plugin}:5: DeprecationWarning: recal.terms is deprecated; import {name} from "
        "recal.model.terms (or recal) — it will be removed in 0.3.0"
        for name in ("ColumnBiasTerm", "Term")
    ], done.stderr


# ---- the version --------------------------------------------------------------------------------
def test_one_version_in_one_place() -> None:
    """pyproject.toml reads the version from ``recal.__version__``; CHANGELOG.md's newest
    release is that version, under an "Unreleased" heading for what comes next."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "recal.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", recal.__version__)
    headings = re.findall(r"^## (.+)$", (ROOT / "CHANGELOG.md").read_text(), re.MULTILINE)
    assert headings[0] == "Unreleased"
    assert re.fullmatch(rf"{re.escape(recal.__version__)} \(\d{{4}}-\d\d-\d\d\)", headings[1])
