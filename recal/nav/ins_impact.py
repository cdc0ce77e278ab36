"""What loading a calibration version is predicted to do to a static INS: :class:`NavigationImpact`
(its 1-sigma error and the error the accepted version leaves), from a fit's covariance re-indexed
to the seed layout (:func:`seed_covariance`, :func:`complete_seed_set`), and
:func:`describe_change`'s one sentence comparing two sets.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from recal.model.coefficients import CoefficientSet
from recal.nav.ins_static import DEFAULT_STEP_S, predict_static_error
from recal.nav.ins_uncertainty import SEED_SIZES, SEED_TERMS, predict_from_uncertainty, seed_sigma
from recal.nav.navigation import NMI_M


# ---------------------------------------------------------------------------- a version's impact
@dataclass(frozen=True)
class NavigationImpact:
    """What loading a calibration version is predicted to do to a static INS (all in metres).

    ``error_m_1sigma``: the 1-sigma (DRMS) horizontal error after ``hours`` that this version's
    own uncertainty allows. ``old_error_m``: the error the previously accepted version leaves if
    this one is the truth (their difference, propagated); ``accepted_error_m_1sigma``: the
    accepted version's own 1-sigma figure, for a like-for-like comparison. ``exact`` names the
    coefficients counted as exactly known (held with no earlier uncertainty, or not calibrated).
    """

    latitude_deg: float
    height_m: float
    attitude_rpy_deg: tuple[float, float, float]
    hours: float
    error_m_1sigma: float
    max_error_m_1sigma: float
    exact: tuple[str, ...] = ()
    from_version: int | str | None = None  # a stored version, or a file name
    old_error_m: float | None = None
    accepted_error_m_1sigma: float | None = None

    @property
    def error_nmi_1sigma(self) -> float:
        return self.error_m_1sigma / NMI_M

    @property
    def significant(self) -> bool:
        """The accepted version's error (if this one is right) exceeds this one's 1-sigma: the
        recalibration changes the predicted error by more than it is unsure of."""
        return self.old_error_m is not None and self.old_error_m > self.error_m_1sigma

    def worse_than_accepted(self, margin_nmi: float = 0.0) -> bool:
        """True when this version's 1-sigma error exceeds the accepted one's by ``margin_nmi``."""
        if self.accepted_error_m_1sigma is None:
            return False
        return self.error_m_1sigma > self.accepted_error_m_1sigma + margin_nmi * NMI_M

    def sentence(self, this: str = "this version") -> str:
        h = f"{self.hours:g} h"
        text = (
            f"the calibration uncertainty of {this} allows a {h} static error of "
            f"{self.error_nmi_1sigma:.2f} nmi (1 sigma) at {self.latitude_deg:.1f} deg"
        )
        if self.from_version is not None and self.old_error_m is not None:
            v = self.from_version
            name = f"version {v}" if isinstance(v, int) else v
            text = (
                f"loading {this} instead of {name} changes the predicted {h} static error "
                f"from {self.old_error_m / NMI_M:.2f} to {self.error_nmi_1sigma:.2f} nmi; " + text
            )
            if not self.significant:
                text += (
                    f"; the two differ by less than this uncertainty: {name} is as good, "
                    "within what this calibration can tell"
                )
        if self.exact:
            text += f" ({len(self.exact)} coefficient(s) counted as exact: {', '.join(self.exact)})"
        return text

    def to_json_dict(self) -> dict[str, Any]:
        nmi = self.error_nmi_1sigma
        change = None
        if self.from_version is not None and self.old_error_m is not None:
            old = self.old_error_m / NMI_M
            accepted = self.accepted_error_m_1sigma
            change = {
                "from_version": self.from_version,
                "old_error_nmi": old,
                "new_error_nmi": nmi,
                "delta_nmi": nmi - old,
                "significant": self.significant,
                "accepted_error_nmi_1sigma": None if accepted is None else accepted / NMI_M,
            }
        return {
            "latitude_deg": self.latitude_deg,
            "height_m": self.height_m,
            "attitude_rpy_deg": list(self.attitude_rpy_deg),
            "hours": self.hours,
            "static_24h_error_m_1sigma": self.error_m_1sigma,
            "static_24h_error_nmi_1sigma": nmi,
            "max_error_nmi_1sigma": self.max_error_m_1sigma / NMI_M,
            "counted_as_exact": list(self.exact),
            "change": change,
            "summary": self.sentence(),
        }


def seed_covariance(
    term_slices: Mapping[str, slice],
    covariance: np.ndarray,
    fallback_sigma: Mapping[str, np.ndarray] | None = None,
) -> tuple[np.ndarray, list[str]]:
    """A fit's flat covariance re-indexed to the (27, 27) :data:`SEED_TERMS` layout.

    Parameters the fit held (zero variance) or lacks take ``fallback_sigma`` (term name -> 1-sigma,
    e.g. the version they were held at) on the diagonal; those still without an uncertainty are
    returned by flat name ("accel.quadratic.K2x") as counted exact.
    """
    cov_in = np.asarray(covariance, float)
    idx = np.concatenate(
        [np.arange(term_slices[n].start, term_slices[n].stop) if n in term_slices
         else np.full(SEED_SIZES[n.split(".")[1]], -1) for n in SEED_TERMS]
    )  # fmt: skip
    have = idx >= 0
    cov = np.zeros((idx.size, idx.size))
    cov[np.ix_(have, have)] = cov_in[np.ix_(idx[have], idx[have])]
    fallback = np.concatenate(
        [np.nan_to_num(np.asarray((fallback_sigma or {}).get(n, np.zeros(SEED_SIZES[n.split(".")[1]])),
                                  float)) for n in SEED_TERMS]
    )  # fmt: skip
    known = np.diag(cov) > 0
    fill = ~known & (fallback > 0)
    cov[fill, fill] = fallback[fill] ** 2
    names = [f"{t.name}.{p}" for t in _seed_term_objects() for p in t.params]
    exact = [nm for nm, k, f in zip(names, known, fill, strict=True) if not (k or f)]
    return cov, exact


def navigation_impact(
    new: CoefficientSet,
    covariance: np.ndarray,
    latitude_deg: float,
    height_m: float = 0.0,
    attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
    hours: float = 24.0,
    exact: Sequence[str] = (),
    old: CoefficientSet | None = None,
    from_version: int | str | None = None,
    accepted_error_m_1sigma: float | None = None,
    step_s: float = DEFAULT_STEP_S,
) -> NavigationImpact:
    """The predicted navigation impact of loading ``new`` (both triads, (27, 27) covariance in
    :data:`SEED_TERMS` order), and of replacing ``old`` (version ``from_version``) by it."""
    att = tuple(float(a) for a in attitude_rpy_deg)
    u = predict_from_uncertainty(
        None, new, latitude_deg, height_m, att, hours, covariance=covariance, step_s=step_s
    )
    old_m = None
    if old is not None:
        old_m = predict_static_error(old, new, latitude_deg, height_m, att, hours, True, step_s)
        old_m = old_m.final_m
    sd = u.sigma_horizontal_m
    return NavigationImpact(
        latitude_deg, height_m, att, hours, float(sd[-1]), float(sd.max()), tuple(exact),
        from_version, old_m, accepted_error_m_1sigma,
    )  # fmt: skip


def complete_seed_set(
    coeffs: CoefficientSet, fallback: CoefficientSet | None = None
) -> tuple[CoefficientSet, list[str]]:
    """``coeffs`` with every :data:`SEED_TERMS` entry: missing ones from ``fallback``, else the
    term's neutral value (no error). Returns the set and the names filled in."""
    neutral = {t.name: np.asarray(t.neutral, float) for t in _seed_term_objects()}
    out = coeffs.copy()
    filled = []
    for n in SEED_TERMS:
        if out.get(n) is None:
            v = None if fallback is None else fallback.get(n)
            out.values[n] = np.array(neutral[n] if v is None else v, float)
            filled.append(n)
    return out, filled


@lru_cache(maxsize=1)
def _seed_term_objects() -> tuple[Any, ...]:
    """The seed model's terms in :data:`SEED_TERMS` order."""
    from recal.model.terms import seed_terms

    terms = {t.name: t for s in ("gyro", "accel") for t in seed_terms(s)}
    return tuple(terms[n] for n in SEED_TERMS)


def describe_change(
    old: CoefficientSet,
    new: CoefficientSet,
    latitude_deg: float,
    height_m: float = 0.0,
    attitude_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
    hours: float = 24.0,
    sigma_new: CoefficientSet | Mapping[str, Any] | None = None,
    old_name: str = "A",
    new_name: str = "B",
) -> str:
    """One sentence comparing the predicted static errors of loading ``new`` instead of
    ``old``, taking ``new`` as the truth (its own error is then its uncertainty, ``sigma_new``,
    taken as independent 1-sigmas)."""
    if sigma_new is None:
        p_old = predict_static_error(old, new, latitude_deg, height_m, attitude_rpy_deg, hours)
        return (
            f"with {new_name} as the truth, {old_name} gives a predicted {hours:g} h static "
            f"error of {p_old.final_nmi:.2f} nmi (max {p_old.max_nmi:.2f}); loading {new_name} "
            f"removes it (0 nmi if {new_name} is exact)"
        )
    cov = np.diag(seed_sigma(sigma_new) ** 2)
    impact = navigation_impact(new, cov, latitude_deg, height_m, attitude_rpy_deg, hours,
                               old=old, from_version=old_name)  # fmt: skip
    return impact.sentence(new_name)
