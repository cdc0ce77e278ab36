"""``recal predict``: the static navigation error a coefficient set allows, without a recording.

    recal predict NEW.json [--from OLD.json] --latitude DEG [--height M] [--attitude R,P,Y]
                  [--hours H] [--json]

``NEW.json`` is a ``recal calibrate --json`` output (coefficients and 1-sigma uncertainties) or a
coefficients file (section 5 layout; then only the change from ``--from`` can be predicted).
The linear psi-angle error model of :mod:`recal.nav.ins_error` gives, at the site's latitude and
the IMU's attitude (default level, x north): the 1-sigma horizontal error after ``--hours`` that
the new set's uncertainty allows (independent 1-sigmas: the file carries no covariance), and
with ``--from`` the error the old set leaves if the new one is right ("loading B instead of A
changes the predicted 24 h static error from 4.5 to 1.2 nmi").

Only argparse is imported to build the parser; numpy and recal are imported by run().
"""

from __future__ import annotations

import argparse
import json
from typing import Any


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "predict",
        help="predict the static navigation error of coefficients (no recording needed)",
        description="Predict the horizontal position error of a static INS using these "
        "coefficients (linear psi-angle model, after alignment): the 1-sigma error their "
        "uncertainty allows, and with --from the error the old coefficients leave if the new "
        "ones are right.",
    )
    p.add_argument(
        "new",
        metavar="NEW.json",
        help="`recal calibrate --json` output (with uncertainties) or a coefficients file",
    )
    p.add_argument(
        "--from",
        dest="old",
        metavar="OLD.json",
        help="the coefficients in use now (calibrate JSON or coefficients file)",
    )
    p.add_argument("--latitude", type=float, required=True, help="site latitude, deg")
    p.add_argument("--height", type=float, default=0.0, help="site height, m (default 0)")
    p.add_argument(
        "--attitude",
        metavar="R,P,Y",
        help="the IMU's roll, pitch, yaw in north-east-down, deg (default 0,0,0: level, x north)",
    )
    p.add_argument("--hours", type=float, default=24.0, help="prediction horizon, h (default 24)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)
    return p


def _load(path: str) -> tuple[Any, dict[str, Any] | None]:
    """(CoefficientSet, the calibrate JSON's uncertainty section or None)."""
    from recal.errors import RecalInputError
    from recal.model.coefficient_schema import parse_json
    from recal.model.coefficients import read_coefficients
    from service.cli.common import read_text

    data = parse_json(read_text(path, "coefficients file"), path)
    if not isinstance(data, dict):
        raise RecalInputError(f"{path}: expected a JSON object")
    cs = read_coefficients(data, source=path)  # calibrate --json, or the section 5 layout itself
    return cs, data.get("uncertainty") if isinstance(data.get("uncertainty"), dict) else None


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from recal.errors import RecalInputError
    from recal.nav.alignment import parse_attitude
    from recal.nav.ins_impact import complete_seed_set, navigation_impact
    from recal.nav.ins_uncertainty import SEED_PARAMETERS, SEED_TERMS, seed_sigma, sigma_from_doc
    from recal.nav.navigation import NMI_M

    if not -90.0 <= args.latitude <= 90.0:
        raise RecalInputError(f"--latitude {args.latitude} is outside [-90, 90] deg")
    if not (np.isfinite(args.height) and 0 < args.hours <= 720):
        raise RecalInputError("--height must be finite and --hours in (0, 720]")
    attitude = (0.0, 0.0, 0.0) if args.attitude is None else parse_attitude(args.attitude)
    new, sigma_doc = _load(args.new)
    old = _load(args.old)[0] if args.old else None
    if sigma_doc is None and old is None:
        raise RecalInputError(
            f"{args.new} has no uncertainties (no 'uncertainty' beside the coefficients): give "
            "--from OLD.json to predict the change, or pass a file `recal calibrate -o` or "
            "--json wrote"
        )
    new, filled = complete_seed_set(new, old)
    var = seed_sigma(sigma_doc) ** 2 if sigma_doc else np.zeros(SEED_PARAMETERS)
    exact = ["all (no uncertainties given)"]
    if sigma_doc:
        sigma = sigma_from_doc(sigma_doc)
        exact = [n for n in SEED_TERMS if n not in sigma or not np.any(sigma[n])]
    if old is not None:
        old, _ = complete_seed_set(old, new)
    impact = navigation_impact(new, np.diag(var), args.latitude, args.height, attitude,
                               args.hours, exact, old, args.old)  # fmt: skip
    doc = impact.to_json_dict()
    doc["new"], doc["from"] = args.new, args.old
    doc["filled_from_old"] = filled
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    h = f"{args.hours:g} h"
    lines = [f"recal predict: {h} static error at {args.latitude:g} deg, IMU attitude "
             f"{', '.join(f'{a:g}' for a in attitude)} deg (linear psi-angle model, aligned)"]  # fmt: skip
    if sigma_doc:
        lines.append(f"  {args.new}: 1-sigma {impact.error_nmi_1sigma:.3f} nmi "
                     f"({impact.error_m_1sigma:.0f} m) from its uncertainty")  # fmt: skip
    if old is not None and impact.old_error_m is not None:
        lines.append(f"  {args.old}: {impact.old_error_m / NMI_M:.3f} nmi "
                     f"({impact.old_error_m:.0f} m) if {args.new} is right")  # fmt: skip
        if sigma_doc:
            verdict = "a real change" if impact.significant else "within the new uncertainty"
            lines.append(f"  the difference is {verdict}")
    if exact and sigma_doc:
        lines.append(f"  counted as exact (held or no uncertainty): {', '.join(exact)}")
    if filled:
        lines.append(f"  taken from {args.old or 'the neutral model'}: {', '.join(filled)}")
    print("\n".join(lines))
    return 0
