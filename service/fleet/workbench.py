"""The workbench at fleet scale (issue 37): each unit's stored windows re-fitted with and without
a candidate effect, and per model whether the effect is ``systematic``, ``local`` or ``absent``.

Per unit (:func:`refit_unit`, in a Dask worker; everything it needs comes with the task, so a
worker needs no database): the windows become a :class:`recal.model.positions.Positions`, the
unit's current version is the prior (the start, and the value of what the windows cannot show),
and the model of that version (the seed terms plus the catalogue or plugin effects it holds)
is the model *without*. Then

* ``chi2_red_before``: :func:`recal.solve.calibrate.calibrate` of that model (``method``, LM by
  default); ``chi2_red_after``, ``estimate`` and ``sigma`` (1-sigma, null where the windows do
  not pin a parameter): the same with the effect added;
* ``significant``, ``p_adjusted``, ``delta_bic``: recal diagnose's own test of a candidate
  effect, :func:`recal.diagnose.effects.diagnose` with the effects asked for as its candidates
  (delta BIC below 0 and the family-wise p below 0.01, against a bias wander or an excess of
  noise explaining the misfit instead; docs/reference.md#effects). Several effects given are one
  family: the p-value is adjusted for trying all of them.

Per model and effect (:func:`verdicts`, in the client): ``systematic`` when the effect is
significant in more than half of the units tested and their estimates are consistent with one
value (a chi-square homogeneity test of the significant units' estimates with their
covariances, p >= 0.01); ``local`` when it is significant in more units than chance gives
(a one-sided binomial test of the count against the per-unit false-alarm rate 0.01, p < 0.01),
or in a majority whose values differ; else ``absent``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

#: The per-unit false-alarm rate of diagnose's test, and the level of the fleet's own tests.
ALPHA = 0.01
#: Fewest windows a unit's refit reads (fewer: the unit is listed with an error).
MIN_WINDOWS = 6
#: Columns a window of the shore may lack on some rows (the ship's sensors): NaN there.
SHIP_COLUMNS = ("latitude_deg", "sog_kn", "heading_deg")


def window_columns(rows: Sequence[Mapping[str, Any]]) -> dict[str, np.ndarray]:
    """The positions file's columns of stored window rows (``fleet_windows.data``, oldest
    first): the numeric columns every row has (not ``session``), and the ship's columns where
    any row has them (NaN where a row has not)."""
    if not rows:
        return {}
    first = rows[0]
    names = [k for k, v in first.items() if _number(v) and k != "session"]
    names = [k for k in names if all(_number(r.get(k)) for r in rows)]
    cols = {k: np.array([float(r[k]) for r in rows]) for k in names}
    for k in SHIP_COLUMNS:
        if k not in cols and any(_number(r.get(k)) for r in rows):
            cols[k] = np.array([float(r[k]) if _number(r.get(k)) else math.nan for r in rows])
    return cols


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def plugin_terms(plugins: Sequence[tuple[str, str]]) -> list[Any]:
    """The terms of ``(path, source)`` plugins (recal diagnose --plugin's loader, run where the
    task runs: a worker gets the source, not the file)."""
    from recal.model.plugins import load_plugin_source

    return [t for path, source in plugins for t in load_plugin_source(source, path)]


def check_effects(effects: Sequence[str], plugins: Sequence[tuple[str, str]]) -> None:
    """An unknown effect name is an input error before any task is sent."""
    from recal.errors import RecalInputError
    from recal.model.terms import catalogue_terms

    known = {**catalogue_terms(), **{t.name: t for t in plugin_terms(plugins)}}
    unknown = [e for e in effects if e not in known]
    if unknown:
        raise RecalInputError(
            f"unknown effect(s) {', '.join(unknown)}: catalogue names (docs/reference.md#effects) "
            "or a --plugin's terms"
        )
    if not effects:
        raise RecalInputError("no effect to try: give --effects +NAME or --plugin FILE.py")


def refit_unit(
    columns: Mapping[str, np.ndarray],
    current: Mapping[str, Any] | None,
    spec: Mapping[str, Any],
    source: str = "shore",
) -> dict[str, Any]:
    """One unit's windows re-fitted with and without each of ``spec["effects"]`` (module doc).
    ``spec``: ``effects``, ``plugins`` [(path, source)], ``method``, ``mc``, ``seed``. A unit the
    refit cannot use (too few windows, a design that shows nothing) answers ``error``."""
    from recal.diagnose.effects import diagnose
    from recal.errors import RecalInputError
    from recal.model.coefficients import CoefficientSet
    from recal.model.positions import Positions
    from recal.model.terms import catalogue_terms
    from recal.solve.calibrate import CalibrationOptions, calibrate

    effects = list(spec["effects"])
    n = len(next(iter(columns.values()))) if columns else 0
    out: dict[str, Any] = {"windows": n, "chi2_red_before": None, "effects": {}, "error": None}
    if n < MIN_WINDOWS:
        out["error"] = f"{n} windows: the refit needs at least {MIN_WINDOWS}"
        return out
    try:
        terms = plugin_terms(spec.get("plugins", ()))
        known = {**catalogue_terms(), **{t.name: t for t in terms}}
        positions = Positions.from_columns(columns, source=source)
        latitude, height = _site(columns, current)
        prior = None
        if current and current.get("coefficients"):
            prior = CoefficientSet.from_json_dict(current["coefficients"], known, source=source)
        held = [k for k in (prior.values if prior else {}) if k in known and k not in effects]
        opt = CalibrationOptions(
            method=spec.get("method", "lm"),
            mc_runs=int(spec.get("mc", 100)),
            seed=int(spec.get("seed", 0)),
            latitude_deg=latitude,
            height_m=height,
            prior=prior,
            effects=held,
            plugin_terms=terms,
        )
        before = calibrate(positions, opt)
        out["chi2_red_before"] = _num(before.chi2_red)
        tested = diagnose(positions, opt, candidates=effects, max_rounds=1)
        judged = {c.effect: c for c in tested.candidates}
        for name in effects:
            out["effects"][name] = _with_effect(positions, opt, held, name, judged.get(name))
    except RecalInputError as exc:
        out["error"] = str(exc)
    return out


def _with_effect(positions: Any, opt: Any, held: list[str], name: str, cand: Any) -> dict:
    """The model with ``name`` added: its chi2_red, the effect's estimate, 1-sigma and
    covariance, and diagnose's judgement of it (``cand``)."""
    from recal.errors import RecalInputError
    from recal.model.terms import catalogue_terms
    from recal.solve.calibrate import calibrate

    out: dict[str, Any] = {"chi2_red_after": None, "estimate": None, "sigma": None,
                           "covariance": None, "significant": False, "p_adjusted": None,
                           "delta_bic": None, "reason": ""}  # fmt: skip
    if cand is not None:
        out["significant"] = bool(cand.significant)
        out["p_adjusted"] = _num(cand.p_adjusted)
        out["delta_bic"] = _num(cand.delta_bic)
        out["reason"] = cand.reason
    try:
        after = calibrate(positions, replace(opt, effects=[*held, name]))
    except RecalInputError as exc:
        out["reason"] = out["reason"] or str(exc)
        return out
    term = {**catalogue_terms(), **{t.name: t for t in opt.plugin_terms}}[name]
    sl = after.layout.term_slices()[name]
    values = np.asarray(after.coefficients.values[name], float)
    sd = np.asarray(after.uncertainty[name], float)
    out["chi2_red_after"] = _num(after.chi2_red)
    out["estimate"] = {p: _num(v) for p, v in zip(term.params, values, strict=True)}
    out["sigma"] = {p: _num(v) for p, v in zip(term.params, sd, strict=True)}
    cov = np.asarray(after.covariance, float)[sl, sl]
    out["covariance"] = [[_num(v) for v in row] for row in cov]
    return out


def _site(columns: Mapping[str, np.ndarray], current: Mapping[str, Any] | None) -> tuple:
    """Latitude (the windows' own, from the ship's GNSS; else the current version's; else 45)
    and height (the current version's, else 0)."""
    lat = columns.get("latitude_deg")
    if lat is not None and np.isfinite(lat).any():
        latitude = float(np.nanmedian(lat))
    else:
        latitude = float((current or {}).get("latitude_deg", 45.0) or 45.0)
    return latitude, float((current or {}).get("height_m", 0.0) or 0.0)


def _num(v: Any) -> float | None:
    """JSON has no NaN: an undefined figure is null."""
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


# ---- the fleet's verdict ---------------------------------------------------------------------
def homogeneity(
    estimates: Sequence[Mapping[str, float | None]],
    covariances: Sequence[Sequence[Sequence[float | None]] | None],
) -> dict[str, Any] | None:
    """Are these units' estimates of one effect one value? The generalised-least-squares common
    value m = (sum W_i)^-1 sum W_i x_i (W_i the inverse of unit i's covariance, over the
    parameters every unit pins down) and chi2 = sum (x_i - m)' W_i (x_i - m), on
    (units - 1) x parameters degrees of freedom. None for fewer than two units."""
    from scipy import stats

    if len(estimates) < 2:
        return None
    params = list(estimates[0])
    ok = [
        j
        for j, p in enumerate(params)
        if all(e.get(p) is not None for e in estimates)
        and all(c is not None and c[j][j] is not None and c[j][j] > 0 for c in covariances)
    ]
    if not ok:
        return None
    X = np.array([[e[params[j]] for j in ok] for e in estimates], float)
    W = []
    for c in covariances:
        C = np.array([[c[i][j] for j in ok] for i in ok], float)  # type: ignore[index]
        W.append(np.linalg.pinv(np.nan_to_num(C), hermitian=True))
    W = np.array(W)
    total = W.sum(axis=0)
    cov_m = np.linalg.pinv(total, hermitian=True)
    m = cov_m @ np.einsum("uij,uj->i", W, X)
    d = X - m
    chi2 = float(np.einsum("ui,uij,uj->", d, W, d))
    dof = (len(estimates) - 1) * len(ok)
    return {
        "value": {params[j]: _num(v) for j, v in zip(ok, m, strict=True)},
        "sigma": {params[j]: _num(v) for j, v in zip(ok, np.sqrt(np.diag(cov_m)), strict=True)},
        "chi2": round(chi2, 3),
        "dof": dof,
        "p_value": _num(stats.chi2.sf(chi2, dof)),
    }


def verdict(units: Sequence[Mapping[str, Any]], effect: str) -> dict[str, Any]:
    """One model's verdict on ``effect`` from its units' refits (module doc): ``verdict``,
    units ``tested`` and ``significant``, the binomial ``p_chance`` of as many significant
    units from false alarms alone, and the significant units' ``homogeneity``."""
    from scipy import stats

    fits = [u["effects"][effect] for u in units if not u.get("error") and effect in u["effects"]]
    tested = len(fits)
    hits = [f for f in fits if f["significant"] and f["estimate"] is not None]
    k = sum(bool(f["significant"]) for f in fits)
    p_chance = float(stats.binom.sf(k - 1, tested, ALPHA)) if tested and k else 1.0
    same = homogeneity([f["estimate"] for f in hits], [f["covariance"] for f in hits])
    consistent = same is not None and same["p_value"] is not None and same["p_value"] >= ALPHA
    if tested and k * 2 > tested and len(hits) >= 2 and consistent:
        call = "systematic"
    elif k and (p_chance < ALPHA or k * 2 > tested):
        call = "local"
    else:
        call = "absent"
    return {
        "verdict": call,
        "units": len(units),
        "tested": tested,
        "significant": k,
        "p_chance": _num(p_chance),
        "homogeneity": same,
    }


def verdicts(units: Sequence[Mapping[str, Any]], effects: Sequence[str]) -> dict[str, Any]:
    """Per model (``model`` of each unit; null as ""), per effect: :func:`verdict`."""
    models = sorted({u.get("model") or "" for u in units})
    return {
        m: {e: verdict([u for u in units if (u.get("model") or "") == m], e) for e in effects}
        for m in models
    }
