"""What the ingest stages are built from, read from the settings: the static detector's
configuration (:func:`detector_config`), its moving-window length (:func:`window_frames`) and the
rest check's reference (:func:`rest_reference`)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from recal.detect.rest import RestReference
from recal.detect.static_config import DetectorConfig
from service.config.section import config_from
from service.config.settings import Settings


def detector_config(settings: Settings) -> DetectorConfig:
    """The detector as configured (thresholds, if any, not yet from the store)."""
    d = settings.detector
    # explicit thresholds: nothing is learned from a still start
    init_still_s = None if d.accel_threshold is not None else d.init_still_s
    return config_from(DetectorConfig, d, init_still_s=init_still_s,
                       sample_rate_hz=settings.device.rate_hz)  # fmt: skip


def rest_reference(
    settings: Settings, prior: Any = None, latitude_deg: float | None = None
) -> RestReference | None:
    """The rest check's reference (recal.detect.rest) for this unit: from ``prior`` (the accepted
    version, else ``prior_path``), else nominal for a format whose outputs are deg/h and g
    (a KVH); None when the outputs cannot be turned into physics (no rest check then).

    The prior gives the conversion (scale factors, biases); the plausible range is never
    narrower than the navigation class's: an accepted version's own 1-sigma would censor the
    very windows that show the unit has drifted from it. The latitude is ``latitude_deg`` (the
    ship's sensors), else the site's (:attr:`Settings.site_latitude_deg`); with neither, gravity
    anywhere between the equator's and the pole's is at rest until the ship's sensors give it.
    """
    from drivers.registry import get_input_format

    lat = settings.site_latitude_deg if latitude_deg is None else latitude_deg
    known, height = lat is not None, settings.site.height_m
    lat = 45.0 if lat is None else lat
    nominal = RestReference.nominal(lat, height)
    if prior is None:
        physical = tuple(get_input_format(settings.device.format).units) == ("deg/h", "g")
        ref = nominal if physical else None
    else:
        ref = RestReference.from_coefficients(prior, lat, height)
        ref = replace(
            ref,
            scale_sigma=max(ref.scale_sigma, nominal.scale_sigma),
            gyro_bias_sigma_dph=max(ref.gyro_bias_sigma_dph, nominal.gyro_bias_sigma_dph),
            accel_bias_sigma_g=max(ref.accel_bias_sigma_g, nominal.accel_bias_sigma_g),
            misalignment_sigma=max(ref.misalignment_sigma, nominal.misalignment_sigma),
        )
    return ref if ref is None or known else ref.at_unknown_latitude()


def window_frames(config: DetectorConfig, rate_hz: float) -> int:
    """The moving-window length W (frames) the detector uses at ``rate_hz``."""
    window_s = config.durations(rate_hz)[0]
    return 2 * max(1, round(window_s * rate_hz / 2)) + 1
