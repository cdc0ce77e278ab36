"""User effects (plugins): checks on load and the context a term is evaluated with.

A plugin is a Python file defining ``TERMS = [MyTerm(...), ...]`` of :class:`recal.model.terms.Term`
subclasses. :func:`validate_terms` checks each term when the file is loaded (name, sizes,
``typical``, ``neutral``, a trial evaluation on a small context) so a mistake is one line naming
the file, the term and the problem instead of a traceback from inside a solver.

Context keys a term may declare in ``needs`` (see :data:`CONTEXT_KEYS`); per position values are
arrays of M rows, in the order of the positions file:

* from the positions table: ``temperature_c`` (M,), ``temperature_rate_c_per_h`` (M,),
  ``time_h`` (M,, window middle) and ``specific_force_g`` (M, 3; the calibrated accelerometer
  reading at the prior);
* attitude-free site quantities: ``gravity_direction`` (M, 3; unit vector of the measured
  specific force in body axes, pointing up), ``earth_rate_direction`` (M, 3; unit vector of the
  measured rate), ``north`` and ``east`` (M, 3; body-axis unit vectors, from the horizontal
  part of Earth rate; they need both triads), ``latitude_deg``, ``gravity_g`` (local normal
  gravity in g) and ``earth_rate_deg_h`` (scalars);
* any other column of the positions CSV named in ``needs`` (M,), e.g. ``mag_x``.

The measured directions come from the outputs corrected with the prior's scale and bias: no
attitude is needed, so a hull-fixed field (a magnetic field, a vibration axis) can be expressed
in body axes per position as ``B_N north + B_E east + B_U gravity_direction``.
"""

from __future__ import annotations

import sys
import types
import warnings
from collections import ChainMap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.error_model import Model, ParameterLayout
from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H, normal_gravity_g
from recal.model.terms import Term, catalogue_terms, seed_terms

#: Keys the problem itself builds from the positions (recal.solve.problem.Problem.build).
TABLE_CONTEXT = ("temperature_c", "temperature_rate_c_per_h", "time_h", "specific_force_g")
#: Attitude-free site quantities (this module); vectors are (M, 3) in body axes.
SITE_VECTORS = ("gravity_direction", "earth_rate_direction", "north", "east")
SITE_SCALARS = ("latitude_deg", "gravity_g", "earth_rate_deg_h")
CONTEXT_KEYS = TABLE_CONTEXT + SITE_VECTORS + SITE_SCALARS
SENSORS = ("gyro", "accel")


def builtin_names() -> frozenset[str]:
    """Names of the seed terms and catalogue effects (a plugin may not reuse them)."""
    seed = {t.name for s in SENSORS for t in seed_terms(s)}
    return frozenset(seed | set(catalogue_terms()))


def plugin_file(term: Term) -> str | None:
    """The file a plugin term was loaded from, or None for a built-in term."""
    if term.name in builtin_names():
        return None
    cls = type(term.inner if isinstance(term, BoundTerm) else term)
    module = sys.modules.get(cls.__module__)
    return getattr(module, "__file__", None) or cls.__module__


# ------------------------------------------------------------------ validation on load
def load_plugin_source(source: str, path: str) -> list[Term]:
    """The checked ``TERMS`` of a plugin whose Python ``source`` (already read from ``path`` by
    the caller) is run as module ``recal_plugin_<stem>``. Not Python, a syntax error, an
    exception while it runs or a missing or bad ``TERMS``: a one-line RecalInputError."""
    stem = path.replace("\\", "/").rsplit("/", 1)[-1].split(".", 1)[0]
    name = f"recal_plugin_{stem}"
    try:
        code = compile(source, path, "exec")
    except SyntaxError as exc:
        where = f" on line {exc.lineno}" if exc.lineno else ""
        raise RecalInputError(f"plugin {path} is not valid Python: {exc.msg}{where}") from None
    except ValueError:  # NUL bytes: a binary file
        raise RecalInputError(f"plugin {path} is not Python source (it has NUL bytes)") from None
    module = types.ModuleType(name)
    module.__file__ = path
    # what it warned about is remembered per file: `recal calibrate` loads a plugin twice
    module.__dict__["__warningregistry__"] = _WARNED.setdefault(path, {})
    # registered so dataclasses, pickling and the coefficients file can find the term's file
    sys.modules[name] = module
    try:
        _show_plugin_deprecations()
        exec(code, module.__dict__)  # noqa: S102 - running the user's plugin is the point
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - user code: report, don't crash
        sys.modules.pop(name, None)
        raise RecalInputError(
            f"plugin {path} failed to load: {type(exc).__name__}: {exc}"
        ) from None
    terms = getattr(module, "TERMS", None)
    if not isinstance(terms, list | tuple) or not terms:
        sys.modules.pop(name, None)
        raise RecalInputError(f"plugin {path} must define TERMS = [recal.model.terms.Term, ...]")
    return validate_terms(terms, path)


#: The warnings registry of each plugin file (see load_plugin_source).
_WARNED: dict[str, dict] = {}
#: Module names the loader gives plugins (``recal_plugin_<stem>``), as a warnings filter pattern.
_PLUGIN_MODULES = r"recal_plugin_"


def _show_plugin_deprecations() -> None:
    """Show the DeprecationWarnings a plugin's own lines cause (an old import path such as
    ``recal.terms``), once per line of the file. A plugin file is the user's code, like a script's
    ``__main__``, for which Python shows them; but it runs as module ``recal_plugin_<stem>``,
    for which Python's default filters hide them, and its author would learn of the old path
    only when it is gone. The filter is added only when missing (adding one resets what the
    warnings registries remember) and never against ``-W`` options (``sys.warnoptions``),
    which decide alone."""
    if sys.warnoptions:
        return
    for action, _, category, module, _ in warnings.filters:
        pattern = getattr(module, "pattern", module)  # Python's own filters hold plain strings
        if (action, category, pattern) == ("default", DeprecationWarning, _PLUGIN_MODULES):
            return
    warnings.filterwarnings("default", category=DeprecationWarning, module=_PLUGIN_MODULES)


def validate_terms(terms: Sequence[Any], path: str) -> list[Term]:
    """The plugin's terms, checked; raises :class:`RecalInputError` naming file, term, problem."""
    seen: set[str] = set()
    builtin = builtin_names()
    out = []
    for i, t in enumerate(terms):
        label = getattr(t, "name", f"TERMS[{i}]")
        problem = _term_problem(t, builtin, seen)
        if problem:
            raise RecalInputError(f"plugin {path}: term {label}: {problem}")
        seen.add(t.name)
        out.append(t)
    return out


def _term_problem(t: Any, builtin: frozenset[str], seen: set[str]) -> str | None:
    if not isinstance(t, Term):
        return f"is a {type(t).__name__}, not a recal.model.terms.Term"
    if not isinstance(t.name, str) or t.name.count(".") != 1:
        return "name must be 'sensor.effect' with one dot, e.g. 'gyro.magnetic'"
    prefix = t.name.split(".", 1)[0]
    if t.sensor not in SENSORS or prefix != t.sensor:
        return f"name must start with its sensor ('gyro.' or 'accel.'), sensor is {t.sensor!r}"
    if t.name in builtin:
        return "the name is a built-in term or catalogue effect; choose another"
    if t.name in seen:
        return "defined twice"
    params = t.params
    if not isinstance(params, tuple) or not params or not all(isinstance(p, str) for p in params):
        return "params must be a non-empty tuple of names"
    if len(set(params)) != len(params):
        return "params has repeated names"
    n = len(params)
    for what in ("typical", "neutral"):
        v = np.asarray(getattr(t, what), dtype=float) if _is_numbers(getattr(t, what)) else None
        if v is None or v.shape != (n,):
            return f"{what} must have one number per parameter ({n}), got {getattr(t, what)!r}"
        if not np.all(np.isfinite(v)):
            return f"{what} must be finite"
    if np.any(np.asarray(t.typical, float) <= 0):
        return "typical must be positive (the typical change of each parameter)"
    if not isinstance(t.units, str) and (not isinstance(t.units, tuple) or len(t.units) != n):
        return f"units must be one string or one per parameter ({n})"
    if not isinstance(t.needs, (frozenset, set)) or not all(isinstance(k, str) for k in t.needs):
        return "needs must be a frozenset of context keys or column names"
    return _trial_problem(t)


def _is_numbers(v: Any) -> bool:
    try:
        np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return False
    return not isinstance(v, str)


def _trial_context(needs: frozenset[str], m: int) -> dict[str, Any]:
    """A small plausible context with exactly the declared keys."""
    rng = np.random.default_rng(0)
    ctx: dict[str, Any] = {}
    for k in needs:
        if k in SITE_VECTORS or k == "specific_force_g":
            v = rng.normal(size=(m, 3))
            ctx[k] = v / np.linalg.norm(v, axis=1, keepdims=True)
        elif k in SITE_SCALARS:
            ctx[k] = {"latitude_deg": 45.0, "gravity_g": 1.0, "earth_rate_deg_h": OMEGA_IE_DEG_H}[k]
        else:
            ctx[k] = rng.uniform(10.0, 30.0, m)
    return ctx


def _trial_problem(t: Term) -> str | None:
    """Evaluate every contribution at the neutral and a perturbed parameter vector (P = 2) on
    M = 4 positions: shapes must broadcast to (P, M, 3) ((P, 3, 3) for the matrix), values must
    be finite, and the neutral parameters must make the term vanish."""
    P, M = 2, 4
    neutral = np.asarray(t.neutral, float)
    p = np.stack([neutral, neutral + np.asarray(t.typical, float)])
    x = np.tile(np.array([0.6, -0.3, 0.74]), (P, M, 1))
    ctx = _trial_context(frozenset(t.needs), M)
    calls = {
        "scale": (lambda: t.scale(p, ctx), (P, M, 3), 1.0),
        "matrix": (lambda: t.matrix(p), (P, 3, 3), 0.0),
        "offset": (lambda: t.offset(p, ctx), (P, M, 3), 0.0),
        "nonlinear": (lambda: t.nonlinear(p, x, ctx), (P, M, 3), 0.0),
    }
    contributes = False
    for method, (call, shape, vanish) in calls.items():
        try:
            v = call()
        except KeyError as exc:
            return f"{method}() reads context key {exc} that is not in its needs"
        except Exception as exc:  # noqa: BLE001 - user code: report, don't crash
            return f"{method}() failed on a trial evaluation: {type(exc).__name__}: {exc}"
        if v is None:
            continue
        contributes = True
        v = np.asarray(v, dtype=float)
        try:
            v = np.broadcast_to(v, shape)
        except ValueError:
            return f"{method}() returned shape {v.shape}, which does not broadcast to {shape}"
        if not np.all(np.isfinite(v)):
            return f"{method}() returned NaN or infinity on a trial evaluation"
        if not np.allclose(v[0], vanish, atol=1e-12):
            return f"{method}() does not vanish at the neutral parameters {tuple(neutral)}"
    if not contributes:
        return "contributes nothing: override scale, matrix, offset or nonlinear"
    return None


# ------------------------------------------------------------------ context binding
@dataclass(frozen=True, eq=False)
class BoundTerm(Term):
    """A term with per-session context values the problem does not build (site quantities,
    extra CSV columns) merged into the context it is evaluated with."""

    inner: Term | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def _ctx(self, ctx: Mapping[str, Any]) -> Mapping[str, Any]:
        return ChainMap(dict(self.extra), dict(ctx))

    def scale(self, p: np.ndarray, ctx: Mapping[str, Any]) -> np.ndarray | None:
        return self.inner.scale(p, self._ctx(ctx))  # type: ignore[union-attr]

    def matrix(self, p: np.ndarray) -> np.ndarray | None:
        return self.inner.matrix(p)  # type: ignore[union-attr]

    def offset(self, p: np.ndarray, ctx: Mapping[str, Any]) -> np.ndarray | None:
        return self.inner.offset(p, self._ctx(ctx))  # type: ignore[union-attr]


@dataclass(frozen=True, eq=False)
class BoundNonlinearTerm(BoundTerm):
    """:class:`BoundTerm` of a term with an input-dependent part (kept separate because the
    model treats any overridden ``nonlinear`` as present)."""

    def nonlinear(self, p: np.ndarray, x: np.ndarray, ctx: Mapping[str, Any]) -> np.ndarray | None:
        return self.inner.nonlinear(p, x, self._ctx(ctx))  # type: ignore[union-attr]


def _measured_input(
    positions: Positions, sensor: str, values: Mapping[str, np.ndarray]
) -> np.ndarray | None:
    """(M, 3) input estimate N / K - b from the prior's scale and bias (raw output when the
    triad is not calibrated); only its direction is used."""
    if not getattr(positions, f"has_{sensor}"):
        return None
    out = positions.gyro if sensor == "gyro" else positions.accel
    K = values.get(f"{sensor}.scale")
    b = values.get(f"{sensor}.bias")
    x = out / (np.asarray(K, float) if K is not None else 1.0)
    return x - (np.asarray(b, float) if b is not None else 0.0)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def site_context(
    positions: Positions, values: Mapping[str, np.ndarray], latitude_deg: float, height_m: float
) -> dict[str, Any]:
    """The attitude-free site quantities available from these positions (see module doc)."""
    ctx: dict[str, Any] = {
        "latitude_deg": float(latitude_deg),
        "gravity_g": float(normal_gravity_g(latitude_deg, height_m)),
        "earth_rate_deg_h": OMEGA_IE_DEG_H,
    }
    f = _measured_input(positions, "accel", values)
    w = _measured_input(positions, "gyro", values)
    if f is not None:
        ctx["gravity_direction"] = _unit(f)
    if w is not None:
        ctx["earth_rate_direction"] = _unit(w)
    if f is not None and w is not None:
        up = ctx["gravity_direction"]
        horizontal = w - np.sum(w * up, axis=1, keepdims=True) * up  # Omega cos(L) north
        ctx["north"] = _unit(horizontal)
        ctx["east"] = np.cross(ctx["north"], up)  # ENU: north x up = east
    return ctx


def bind_context(
    models: Sequence[Model],
    positions: Positions,
    values: Mapping[str, np.ndarray],
    latitude_deg: float,
    height_m: float,
    with_slews: bool = False,
) -> tuple[Model, ...]:
    """``models`` with every term that needs a site quantity or an extra CSV column bound to
    its values for these positions; a need nothing provides is an input error."""
    site: dict[str, Any] | None = None
    out = []
    for m in models:
        terms = []
        for t in m.terms:
            extra_keys = sorted(set(t.needs) - set(TABLE_CONTEXT))
            if not extra_keys or isinstance(t, BoundTerm):
                terms.append(t)
                continue
            if site is None:
                site = site_context(positions, values, latitude_deg, height_m)
            extra = {}
            for k in extra_keys:
                if k in site:
                    extra[k] = site[k]
                elif k in CONTEXT_KEYS:
                    raise RecalInputError(
                        f"effect {t.name} needs '{k}', which needs both gyro and accel columns"
                    )
                elif k in positions.columns:
                    extra[k] = np.asarray(positions.columns[k], dtype=float)
                else:
                    raise RecalInputError(
                        f"effect {t.name} needs '{k}': not a column of {positions.source} nor a "
                        f"context key ({', '.join(CONTEXT_KEYS)})"
                    )
            if with_slews:
                raise RecalInputError(
                    f"effect {t.name} needs per-position context ({', '.join(extra_keys)}), "
                    "which slews cannot carry: calibrate with --no-slews"
                )
            cls = BoundNonlinearTerm if type(t).nonlinear is not Term.nonlinear else BoundTerm
            base = {f.name: getattr(t, f.name) for f in _term_fields()}
            terms.append(cls(**base, inner=t, extra=extra))
        out.append(replace(m, terms=tuple(terms)))
    return tuple(out)


def _term_fields():
    from dataclasses import fields

    return fields(Term)


def values_by_term(layout: ParameterLayout, theta: np.ndarray) -> dict[str, np.ndarray]:
    return {n: theta[sl] for n, sl in layout.term_slices().items()}


def true_site_context(C_nb: np.ndarray, latitude_deg: float, height_m: float = 0.0) -> dict:
    """The site context from true body-to-ENU rotations (M, 3, 3): for simulating a plugin
    effect as hidden truth (the engine itself only sees the measured directions)."""
    rows = np.swapaxes(C_nb, 1, 2)  # C_bn: its columns are the ENU axes in body axes
    return {
        "latitude_deg": float(latitude_deg),
        "gravity_g": float(normal_gravity_g(latitude_deg, height_m)),
        "earth_rate_deg_h": OMEGA_IE_DEG_H,
        "east": rows[:, :, 0],
        "north": rows[:, :, 1],
        "gravity_direction": rows[:, :, 2],
        "earth_rate_direction": rows @ _unit_earth_rate(latitude_deg),
    }


def _unit_earth_rate(latitude_deg: float) -> np.ndarray:
    lat = np.radians(latitude_deg)
    return np.array([0.0, np.cos(lat), np.sin(lat)])


def hidden_plugin(term: Term, C_nb: np.ndarray, latitude_deg: float) -> Term:
    """``term`` bound to the true site context of ``C_nb``: a hidden effect for
    :func:`recal.sim.simulate.simulate_positions`."""
    extra = {k: v for k, v in true_site_context(C_nb, latitude_deg).items() if k in term.needs}
    cls = BoundNonlinearTerm if type(term).nonlinear is not Term.nonlinear else BoundTerm
    base = {f.name: getattr(term, f.name) for f in _term_fields()}
    return cls(**base, inner=term, extra=extra)
