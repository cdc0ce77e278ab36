"""``[gate]``: what a calibration must pass to be published."""

from __future__ import annotations

from typing import Literal

from pydantic import ConfigDict, Field

from service.config.section import Section


class GateSettings(Section):
    """The acceptance gate's limits (:func:`service.gate.gate` takes this object itself, as
    ``service.gate.GateConfig``): one definition for the file, the environment and the code."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_chi2_red: float = Field(
        4.0, gt=0, description="reject a fit whose residuals exceed the window noise this much"
    )
    max_change_sigma: float = Field(
        6.0, gt=0, description="reject a coefficient moving more sigmas from the current version"
    )
    max_relative_scale_sigma: float = Field(
        2e-3, gt=0, description="reject an estimated scale factor less certain than this (relative)"
    )
    require_verdict: Literal["partial", "full"] = Field(
        "partial",
        description="weakest observability verdict published: partial (some coefficients held "
        "at the prior) or full",
    )
    publish_observable_part: bool = Field(
        False,
        description="hull-fixed unit: publish what the windows show when some scale and bias "
        "cannot be separated (verdict insufficient counts as partial), the rest held at the "
        "prior, with a note naming the held coefficients",
    )
    allow_jump: bool = Field(
        False, description="accept changes beyond max_change_sigma (after a repair), with a note"
    )
    allow_unconfirmed_effects: bool = Field(
        False,
        description="accept a fit whose effects moved the core coefficients by more than 3 sigma "
        "(recal diagnose's trust rule), with a note",
    )
    refuse_worse_navigation: bool = Field(
        False,
        description="reject a version whose predicted static navigation error (1 sigma, from its "
        "uncertainty) exceeds the accepted version's by more than navigation_margin_nmi",
    )
    navigation_margin_nmi: float = Field(
        0.0, ge=0, description="tolerance of refuse_worse_navigation (nautical miles)"
    )
    fleet_prior: str | None = Field(
        None,
        description="fleet prior JSON (recal.fleet_prior/N, from the shore's GET /fleet/prior): "
        "its change over the months since the current version replaces the datasheet's typical "
        "change in the jump limit and the held coefficients' 1-sigma (unset: no ageing allowed)",
    )
