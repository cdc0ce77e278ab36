"""The acceptance gate: may a new calibration replace the current coefficients?

A calibration is rejected when its design is not observable enough, its residuals exceed the
noise, a scale factor is poorly determined, an estimated coefficient jumped too far from the
current accepted version, or effects beyond the seed model moved the core coefficients by more
than diagnose trusts without a check (:func:`recal.diagnose.effects.effects_check`). Every decision
carries plain-English reasons. ``publish_observable_part`` lets a hull-fixed unit's fit (some scale
and bias not separable: verdict insufficient) through with a note naming what it held.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from recal.nav.navigation import NMI_M
from recal.solve.result import CalibrationResult
from service.config import GateSettings
from service.store.records import CalibrationRecord

if TYPE_CHECKING:
    from recal.nav.ins_impact import NavigationImpact

#: Verdicts of recal.solve.observability from worst to best.
VERDICTS = ("insufficient", "partial", "full")
#: Seed categories stored under the sensor key (docs/reference.md#coefficients); the rest are
#: effects.
_SEED_KEYS = ("scale", "bias", "misalignment", "quadratic")
#: How many jumping coefficients a rejection names before summarising the rest.
_MAX_LISTED = 5


#: The acceptance limits are the ``[gate]`` settings themselves (one definition: the file, the
#: environment and ``gate()`` cannot drift apart); see docs/service.md.
GateConfig = GateSettings


@dataclass
class GateDecision:
    accepted: bool
    reasons: list[str] = field(default_factory=list)


def gate(
    result: CalibrationResult,
    previous: CalibrationRecord | None,
    config: GateConfig | None = None,
    impact: NavigationImpact | None = None,
    effects_check: Mapping[str, Any] | None = None,
    change_expected: str | None = None,
    ageing: Mapping[str, float] | None = None,
    ageing_source: str | None = None,
) -> GateDecision:
    """Accept or reject ``result`` against the current accepted record ``previous``.

    ``impact``: the version's predicted navigation impact (:mod:`recal.nav.ins_error`), checked when
    ``refuse_worse_navigation`` is set and summarised in the notes otherwise.
    ``effects_check``: :func:`recal.diagnose.effects.effects_check` of a fit with effects; an untrusted
    one is refused (a note with ``allow_unconfirmed_effects``).
    ``change_expected``: why a jump beyond ``max_change_sigma`` is expected (the drift test
    declared a change at its configured false-alarm rate, and the fit uses only the windows
    since it); the jump is then a note, as with ``allow_jump``, and every other limit applies.
    ``ageing``: flat name -> the 1-sigma change expected from ageing since ``previous`` (the
    fleet prior's figure for the months of service between them, issue 28), added in
    quadrature to both versions' 1-sigma; ``ageing_source`` names it in the reasons. Without it
    the gate allows no ageing at all (the coefficients must agree within their measurement
    errors).
    Rejected: ``reasons`` says every limit broken. Accepted: ``reasons`` holds notes.
    """
    cfg = config or GateConfig()
    names = result.layout.names
    values = dict(zip(names, (float(v) for v in result.theta), strict=True))
    estimated, sigma = _flat_result(result)
    problems, partial = _check_verdict(result, cfg, names, estimated)
    problems += _check_chi2(result, cfg)
    problems += _check_scales(names, values, estimated, sigma, cfg)
    problems += _check_navigation(impact, cfg)
    unconfirmed = _check_effects(effects_check)
    allowed = partial  # notes on what the settings allowed (else they are reasons to refuse)
    if cfg.allow_unconfirmed_effects:
        allowed += [f"{u}; allowed (allow_unconfirmed_effects)" for u in unconfirmed]
    else:
        problems += unconfirmed
    if previous is None:
        first = ["no accepted calibration yet: nothing to compare against"]
        return GateDecision(not problems, problems or first + allowed)
    jumps = _jumps(names, values, estimated, sigma, previous, ageing)
    limit = cfg.max_change_sigma
    moved = sorted(((n, s) for n, s in jumps if s > limit), key=lambda item: -item[1])
    aged = f", ageing allowed: {ageing_source}" if ageing and ageing_source else ""
    lines = [
        f"{n} moved {s:.1f} sigma from version {previous.version} (limit {limit:g}{aged})"
        for n, s in moved[:_MAX_LISTED]
    ]
    if len(moved) > _MAX_LISTED:
        lines.append(f"{len(moved) - _MAX_LISTED} more coefficients moved beyond {limit:g} sigma")
    notes = []
    if cfg.allow_jump or change_expected:
        why = change_expected or "allow_jump"
        notes = [f"{line}; allowed ({why})" for line in lines]
    else:
        problems += lines
    if jumps and not moved:
        name, change = max(jumps, key=lambda item: item[1])
        notes.append(
            f"largest change from version {previous.version}: {name} {change:.1f} sigma "
            f"(limit {limit:g}{aged})"
        )
    if impact is not None and impact.from_version is not None:
        notes.append(impact.sentence())
    notes += allowed
    return GateDecision(accepted=not problems, reasons=problems or notes)


def _check_effects(check: Mapping[str, Any] | None) -> list[str]:
    """An effect fit that moved the core coefficients beyond what diagnose trusts is not an
    improvement on the seed model until checked."""
    if not check or check.get("trustworthy", True):
        return []
    return [str(check.get("warning") or f"effects {check.get('effects')} are not confirmed")]


def _check_verdict(
    result: CalibrationResult, cfg: GateConfig, names: list[str], estimated: Mapping[str, bool]
) -> tuple[list[str], list[str]]:
    """(reasons to refuse, notes). With ``publish_observable_part`` an insufficient verdict (a
    hull-fixed unit: some scale and bias not separable) counts as partial when something is
    estimated; the note names what was held at the prior."""
    verdict = result.observability.verdict
    if VERDICTS.index(verdict) >= VERDICTS.index(cfg.require_verdict):
        return [], []
    said = f"observability verdict is {verdict} ({result.observability.message})"
    held = [n for n in names if not estimated[n]]
    observable_part = verdict == "insufficient" and cfg.require_verdict == "partial"
    if cfg.publish_observable_part and observable_part and len(held) < len(names):
        return [], [
            f"{said}; the observable part is published (publish_observable_part): "
            f"{len(held)} coefficient(s) held at the prior: {', '.join(held)}"
        ]
    why = f"{cfg.require_verdict} or better is required"
    if cfg.publish_observable_part and observable_part:
        why = "nothing is estimated, so there is no observable part to publish"
    return [f"{said}; {why}"], []


def _check_navigation(impact: NavigationImpact | None, cfg: GateConfig) -> list[str]:
    if impact is None or not cfg.refuse_worse_navigation:
        return []
    if not impact.worse_than_accepted(cfg.navigation_margin_nmi):
        return []
    accepted = (impact.accepted_error_m_1sigma or 0.0) / NMI_M
    return [
        f"predicted {impact.hours:g} h static error {impact.error_nmi_1sigma:.2f} nmi (1 sigma, "
        f"from this version's uncertainty) is worse than accepted version "
        f"{impact.from_version}'s {accepted:.2f} nmi by more than "
        f"{cfg.navigation_margin_nmi:g} nmi (refuse_worse_navigation)"
    ]


def _check_chi2(result: CalibrationResult, cfg: GateConfig) -> list[str]:
    if math.isfinite(result.chi2_red) and result.chi2_red <= cfg.max_chi2_red:
        return []
    if not math.isfinite(result.chi2_red):
        return [
            "exactly determined: no redundant equation, so the residuals cannot check this fit; "
            "it needs more positions (or orientations) before it can be accepted"
        ]
    return [
        f"chi2_red {result.chi2_red:.3g} exceeds {cfg.max_chi2_red:g}: the residuals exceed "
        "the window noise (wrong latitude or units, motion in a window, or a missing effect)"
    ]


def _check_scales(
    names: list[str],
    values: Mapping[str, float],
    estimated: Mapping[str, bool],
    sigma: Mapping[str, float],
    cfg: GateConfig,
) -> list[str]:
    """Estimated scale factors whose relative 1-sigma exceeds the limit."""
    out = []
    for name in names:
        if ".scale." not in name or not estimated[name]:
            continue
        relative = sigma[name] / abs(values[name]) if values[name] else math.inf
        if not relative <= cfg.max_relative_scale_sigma:  # NaN sigma fails too
            out.append(
                f"{name} 1-sigma is {relative:.2g} of its value "
                f"(limit {cfg.max_relative_scale_sigma:g})"
            )
    return out


def _jumps(
    names: list[str],
    values: Mapping[str, float],
    estimated: Mapping[str, bool],
    sigma: Mapping[str, float],
    previous: CalibrationRecord,
    ageing: Mapping[str, float] | None = None,
) -> list[tuple[str, float]]:
    """(name, change in combined sigmas) for every estimated coefficient the previous has;
    the combined sigma includes ``ageing`` (flat name -> 1-sigma) where it is given."""
    doc = previous.document
    before = _flat_document(doc.get("coefficients") or {}, names)
    before_sigma = _flat_document(doc.get("uncertainty") or {}, names)
    out = []
    for name in names:
        old = before.get(name)
        if not estimated[name] or old is None:
            continue  # held now, or absent before (e.g. the previous had no accel triad)
        # A coefficient held last time has no sigma of its own: only the new one counts.
        aged = (ageing or {}).get(name)
        aged = aged if aged is not None and math.isfinite(aged) else 0.0
        combined = math.hypot(sigma[name], before_sigma.get(name) or 0.0, aged)
        if combined > 0:
            out.append((name, abs(values[name] - old) / combined))
    return out


def _flat_result(result: CalibrationResult) -> tuple[dict[str, bool], dict[str, float]]:
    """Per flat parameter: estimated or not, and its 1-sigma (NaN where held)."""
    estimated: dict[str, bool] = {}
    sigma: dict[str, float] = {}
    for term in (t for m in result.layout.models for t in m.terms):
        status, sd = result.status[term.name], result.uncertainty[term.name]
        for p, st, s in zip(term.params, status, sd, strict=True):
            estimated[f"{term.name}.{p}"] = st == "estimated"
            sigma[f"{term.name}.{p}"] = float(s)
    return estimated, sigma


def _flat_document(section: Mapping[str, Any], names: list[str]) -> dict[str, float]:
    """Numeric leaves of a section 5 layout (coefficients or uncertainty) by flat name."""
    out: dict[str, float] = {}
    position: dict[str, int] = {}
    for name in names:
        term, param = name.rsplit(".", 1)
        sensor, key = term.split(".", 1)
        i = position[term] = position.get(term, -1) + 1
        if key in _SEED_KEYS:
            entry = (section.get(sensor) or {}).get(key)
        else:
            entry = (section.get("effects") or {}).get(term)
        leaf = entry.get(param) if isinstance(entry, Mapping) else None
        if isinstance(entry, list) and i < len(entry):
            leaf = entry[i]
        if isinstance(leaf, int | float) and math.isfinite(leaf):
            out[name] = float(leaf)
    return out
