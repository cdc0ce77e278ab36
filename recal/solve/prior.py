"""The prior of a calibration: what it is, true to its values (:func:`describe_prior`), and how
uncertain: the 1-sigma a held coefficient carries into the covariance and the observability bar
(:class:`HeldUncertainty`, :func:`prior_uncertainty`; the defaults are in
:mod:`recal.solve.consider`)."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from recal.model.coefficients import CoefficientSet
from recal.model.error_model import ParameterLayout
from recal.model.positions import Positions
from recal.solve.consider import prior_sigma, sensor_class
from recal.solve.earth_rate import MIN_EARTH_RATE_CONTRAST
from recal.solve.options import CalibrationOptions
from recal.solve.start import DataPrior


class HeldUncertainty(NamedTuple):
    """The prior's 1-sigma that the held coefficients carry into ``CalibrationResult.covariance``."""

    sensor_class: str  # which defaults a data-derived prior used (recal.solve.consider)
    source: dict[str, str]  # term name -> where its prior sigma came from
    sigma: np.ndarray  # (D,) prior 1-sigma per parameter
    #: the fleet prior that aged it (label, version, months), or None (issue 28)
    fleet: dict[str, Any] | None = None

    def to_json_dict(self) -> dict[str, Any]:
        out = {"sensor_class": self.sensor_class, "prior_sigma_source": dict(self.source)}
        if self.fleet is not None:
            out["fleet_prior"] = dict(self.fleet)
        return out

    def bar(self, layout: ParameterLayout, typical: np.ndarray) -> np.ndarray:
        """(D,) the observability bar (recal.solve.observability.analyze ``bar``): a prior
        file's 1-sigma over the typical change where it is looser, else 1. Class defaults and a
        data-derived start's own 1-sigma are guesses, not knowledge: they never lower it."""
        out = np.ones(len(typical))
        for name, sl in layout.term_slices().items():
            if self.source.get(name, "").startswith("prior file"):
                out[sl] = np.maximum(self.sigma[sl] / typical[sl], 1.0)
        return out


def describe_prior(
    layout: ParameterLayout,
    theta0: np.ndarray,
    how: dict[str, str],
    given: CoefficientSet | None = None,
    gyro_from_slews: bool = False,
) -> str:
    """What the prior ``theta0`` is, true to its values: the given file and the terms it lacks
    (taken from the data), how each triad's scale and bias were derived from the data (``how``,
    :class:`recal.solve.start.DataPrior`: an ellipsoid fit, or a common scale from the median
    norm when the positions cannot support one; the slews for a gyro blind to Earth rate), and
    which other terms start at zero."""
    slices = layout.term_slices()
    from_data = [t for m in layout.models for t in m.terms
                 if given is None or given.values.get(t.name) is None]  # fmt: skip
    parts = []
    for m in layout.models:
        if not any(t.name in (f"{m.sensor}.scale", f"{m.sensor}.bias") for t in from_data):
            continue
        if m.sensor == "gyro" and gyro_from_slews:
            parts.append("gyro: common scale from the slews, bias the mean window output")
        else:
            parts.append(f"{m.sensor}: {how[m.sensor]}")
    zero = [t.name for t in from_data if t.group not in ("scale", "bias")
            and np.all(theta0[slices[t.name]] == np.asarray(t.neutral, float))]  # fmt: skip
    if zero:
        parts.append(f"{', '.join(zero)} zero")
    other = [t.name for t in from_data if t.group not in ("scale", "bias") and t.name not in zero]
    if other:
        parts.append(f"{', '.join(other)} from the data")
    if given is None:
        return f"data-derived ({'; '.join(parts)})"
    source = str(given.metadata.get("source", "given prior"))
    return f"{source}" + (f"; terms it lacks from the data ({'; '.join(parts)})" if parts else "")


def gyro_prior_sigma(
    positions: Positions,
    layout: ParameterLayout,
    theta0: np.ndarray,
    opt: CalibrationOptions,
    start: DataPrior,
) -> dict[str, np.ndarray]:
    """The gyro's prior 1-sigma (bias deg/h, scale in its units) as the held coefficients get it
    (:func:`prior_uncertainty`), for the Earth-rate heading check of closed turns."""
    own = start.sigma if opt.prior is None and start.sigma.shape == theta0.shape else None
    held = prior_uncertainty(positions, layout, theta0, layout.typical(theta0), opt, own)
    sl = layout.term_slices()
    return {n: held.sigma[sl[n]] for n in ("gyro.bias", "gyro.scale")}


def prior_uncertainty(
    positions: Positions,
    layout: ParameterLayout,
    theta0: np.ndarray,
    typical: np.ndarray,
    opt: CalibrationOptions,
    start_sigma: np.ndarray | None = None,
) -> HeldUncertainty:
    """The prior's 1-sigma per parameter (recal.solve.consider.prior_sigma) and where it came from."""
    cls = sensor_class(positions, layout, theta0, MIN_EARTH_RATE_CONTRAST)
    given = opt.prior.uncertainty if opt.prior else None
    sigma, source = prior_sigma(layout, theta0, typical, given, cls, start_sigma)
    fleet = getattr(opt, "fleet_prior", None)
    months = getattr(opt, "prior_age_months", None)
    if fleet is None or months is None or opt.prior is None:
        return HeldUncertainty(cls, source, sigma)
    sigma, source = aged_sigma(layout, theta0, sigma, source, fleet, months, given)
    used = {"model": fleet.model, "version": fleet.version, "created_at": fleet.created_at,
            "months": float(months)}  # fmt: skip
    return HeldUncertainty(cls, source, sigma, used)


def aged_sigma(
    layout: ParameterLayout,
    theta0: np.ndarray,
    sigma: np.ndarray,
    source: dict[str, str],
    fleet: Any,
    months: float,
    given: Any = None,
) -> tuple[np.ndarray, dict[str, str]]:
    """A prior file's 1-sigma aged by the fleet prior over ``months`` of service (issue 28):
    where the file states its 1-sigma (the accepted version's measurement error), the fleet's
    change over the months is added in quadrature; where it has none (the datasheet's typical
    change stood in), the fleet's change replaces it. ``given``: the file's uncertainty by term
    (NaN where it has none). Coefficients the fleet has no figure for keep theirs."""
    change = fleet.typical_change(layout.names, months, theta0)
    out, src = sigma.copy(), dict(source)
    what = f"fleet prior {fleet.model} v{fleet.version} over {months:.3g} months"
    for name, sl in layout.term_slices().items():
        c = change[sl]
        ok = np.isfinite(c)
        if not np.any(ok):
            continue
        own = None if given is None else given.get(name)
        own = np.asarray(own, float) if own is not None else np.full(c.shape, np.nan)
        stated = np.isfinite(own) if own.shape == c.shape else np.zeros(c.shape, bool)
        out[sl] = np.where(ok, np.where(stated, np.hypot(out[sl], c), c), out[sl])
        src[name] = f"{src.get(name)} + {what}" if np.any(stated & ok) else what
    return out, src
