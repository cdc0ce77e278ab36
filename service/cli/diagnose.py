"""``recal diagnose``: where the model fails and which physical effect is missing."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from service.cli.calibrate import add_calibration_arguments, announce_slews, options_from_args
from service.cli.common import atomic_write, load_positions, parse_effects, print_json

if TYPE_CHECKING:
    from recal.diagnose.effects import Diagnosis


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "diagnose",
        help="compare the model with the measurements and rank missing physical effects",
        description="Fit the model, compare each invariant's residual with its noise floor, then "
        "try every catalogue (and plugin) effect on top and rank them by delta BIC, F-test "
        "p-value and the share of the excess residual they explain; each is weighed against "
        "a bias wander or an independent excess explaining the misfit instead.",
    )
    add_calibration_arguments(p)
    p.add_argument(
        "--candidates",
        metavar="NAME,...",
        help="only try these effects (default: the whole catalogue for the triads)",
    )
    p.add_argument("--report", metavar="OUT.html", help="write an HTML report with plots")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from recal.diagnose.effects import diagnose
    from recal.report.html import diagnosis_html

    positions = load_positions(args.positions)
    options = options_from_args(args, positions)
    candidates = parse_effects(args.candidates) if args.candidates else None
    result = diagnose(positions, options, candidates)
    base = result.baseline
    announce_slews(args, options.slews, base.problem.slews is not None, base.notes)
    if args.report:
        atomic_write(args.report, diagnosis_html(result, f"recal diagnose {args.positions}"))
        print(f"recal diagnose: wrote the report to {args.report}", file=sys.stderr)
    if args.json:
        print_json(result.to_json_dict())
    else:
        sys.stdout.write(format_diagnosis(result))
    return 0


def _hypotheses_lines(d: Diagnosis) -> list[str]:
    """The hypotheses compared for the leading candidate (recal.diagnose.hypotheses): one figure
    each on one scale, lower explaining better."""
    from recal.diagnose.hypotheses import describe

    top = next((c for c in d.candidates if c.identifiable and c.hypotheses), None)
    if top is None or d.noise is None:
        return []
    h = top.hypotheses

    def fig(v: float | None) -> str:
        return "-" if v is None else f"{v:.1f}"

    none = "none earns its price"
    with_effect = (describe(top.noise) if top.noise is not None else "") or none
    rows = [
        ("nothing beyond the windows' noise", h["nothing"]),
        (f"noise alone ({describe(d.noise) or none})", h["noise"]),
        (top.effect, h["effect"]),
        (f"{top.effect} + noise ({with_effect})", h["effect+noise"]),
    ]
    width = max(len(label) for label, _ in rows)
    return [
        "hypotheses (IC: chi2 - likelihood gain of the noise + prices; lower explains better):",
        *(f"  {label:{width}s}  {fig(v):>10s}" for label, v in rows),
        "",
    ]


def format_diagnosis(d: Diagnosis) -> str:
    doc = d.to_json_dict()
    lines = [f"{'invariant':12s} {'RMS':>11s} {'noise floor':>12s} {'ratio':>7s}"]
    for inv in doc["invariants"]:
        floor = "unknown" if inv["noise_floor"] is None else f"{inv['noise_floor']:.4g}"
        ratio = "" if inv["ratio"] is None else f"{inv['ratio']:.2f}"
        lines.append(f"{inv['name']:12s} {inv['rms']:11.4g} {floor:>12s} {ratio:>7s}  "
                     f"[{inv['unit']}]")  # fmt: skip
    lines += ["", f"{'candidate effect':30s} {'dBIC':>10s} {'p':>9s} {'signif.':>8s} "
              f"{'explained':>9s} core shift (sigma)"]  # fmt: skip
    for c in doc["candidates"]:
        if not c["identifiable"]:
            lines.append(f"{c['effect']:30s} {'-':>10s} {'-':>9s} {'-':>8s} {'-':>9s}  "
                         f"({c['reason']})")  # fmt: skip
            continue
        t = c["trade_off"]
        shift = f"{abs(t['shift_sigma']):.1f} {t['coefficient']}" if t else "-"
        similar = f"  (same as {', '.join(c['similar_to'])})" if c["similar_to"] else ""
        lines.append(
            f"{c['effect']:30s} {c['delta_bic']:10.1f} {c['p_value']:9.2g} "
            f"{'YES' if c['significant'] else 'no':>8s} {c['explained_fraction']:9.2f} "
            f"{shift:>11s}{similar}"
        )
    lines.append("")
    lines += _hypotheses_lines(d)
    if len(doc["ladder"]) > 1:
        lines.append("model ladder: (held out: leave-one-position-out chi2 over its expectation)")
        for r in doc["ladder"]:
            ratios = ", ".join(f"{k} {v:.2f}" for k, v in r["rms_over_floor"].items())
            step = "" if r["delta_bic"] is None else f", dBIC {r['delta_bic']:.1f}"
            chi2 = "n/a" if r["chi2_red"] is None else f"{r['chi2_red']:.3g}"
            if r.get("heldout_chi2_red") is not None:
                chi2 += f" (held out {r['heldout_chi2_red']:.3g})"
            rest = f"; beyond the noise: {r['noise']}" if r.get("noise") else ""
            lines.append(f"  {r['model']:32s} chi2_red {chi2}{step}  (RMS/floor: {ratios}){rest}")
        lines.append("")
    if d.suggested_effects:
        eff = ",+".join(d.suggested_effects)
        unconfirmed = "" if d.trustworthy else "; NOT CONFIRMED: see the verdict"
        lines.append(f"suggested: recal calibrate ... --effects +{eff}   "
                     f"(chi2_red {doc['chi2_red']:.3g} -> {doc['chi2_red_with_suggested']:.3g}"
                     f"{unconfirmed})")  # fmt: skip
        for c in d.candidates:
            if c.effect in d.suggested_effects:
                lines.append(f"  {c.effect}: {c.explanation}")
                sd = ", ".join(f"{k} = {v:.4g} +- {c.uncertainty.get(k, float('nan')):.2g}"
                               for k, v in c.parameters.items())  # fmt: skip
                lines.append(f"    fitted: {sd}")
    for c in d.candidates:
        if c.warning and (c.significant or c.effect in d.suggested_effects):
            lines.append(f"warning: {c.warning}")
    for c in d.candidates[:3]:  # the leading candidates, where the user looks
        if c.disagreement:
            lines.append(f"note: {c.disagreement}")
    seen: set[frozenset[str]] = set()
    for c in d.candidates:
        for o in c.confounded_with if c.significant else []:
            pair = frozenset((c.effect, o["effect"]))
            if pair in seen:
                continue
            seen.add(pair)
            lines.append(
                f"confounded: {c.effect} and {o['effect']} (signature correlation "
                f"{o['signature_correlation']:+.2f}, evidence ratio {o['evidence_ratio']:.3g}): "
                f"{o['advice']}"
            )
    for note in d.notes:
        lines.append(f"note: {note}")
    lines.append(f"verdict: {d.verdict}")
    return "\n".join(lines) + "\n"
