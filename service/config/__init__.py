"""Service settings: a TOML file plus ``RECAL_*`` environment variables (pydantic-settings).

Precedence, highest first: keyword arguments, environment (``RECAL_SITE__LATITUDE_DEG=57.7``,
nested with ``__``), the TOML file, the defaults below. A file the daemon writes whose setting is
unset goes under ``state_dir`` (:func:`default_state_dir`), never into the working folder.
Example file::

    database_url = "sqlite:///var/lib/recal/recal.db"
    publish_path = "/run/recal/coefficients.json"

    [device]
    url = "/dev/ttyUSB0"       # or socket://host:port, replay:///path/capture.bin?speed=1
    format = "kvh-a"
    rate_hz = 1000

    [site]
    latitude_deg = 57.7        # or from the ship's sensors:

    [nav]                      # the ship's GNSS and heading, NMEA 0183; no section: none
    url = "udp://:10110"

    [detector]
    init_still_s = 30

    [scheduler]
    min_positions = 12

    [sync]                     # fleet sync to the shore (docs/fleet.md); no section: none
    url = "https://shore.example:8443"
    unit = "KVH-1750-SN0042"
    token = "..."              # or RECAL_SYNC__TOKEN
"""

from __future__ import annotations

from service.config.api import MIN_TOKEN_LENGTH, ApiSettings
from service.config.detector import DetectorSettings
from service.config.device import DeviceSettings, servable_formats
from service.config.gate import GateSettings
from service.config.hosts import is_loopback
from service.config.loader import load_settings, load_toml_settings
from service.config.nav import NavSettings
from service.config.scheduler import SchedulerSettings, Trigger
from service.config.section import Section, check_keys, config_from
from service.config.settings import Settings
from service.config.site import STILL_DEFAULT_LATITUDE_DEG, SiteSettings
from service.config.state_dir import default_state_dir
from service.config.sync import SyncSettings

__all__ = [
    "MIN_TOKEN_LENGTH",
    "STILL_DEFAULT_LATITUDE_DEG",
    "ApiSettings",
    "DetectorSettings",
    "DeviceSettings",
    "GateSettings",
    "NavSettings",
    "SchedulerSettings",
    "Section",
    "Settings",
    "SiteSettings",
    "SyncSettings",
    "Trigger",
    "check_keys",
    "config_from",
    "default_state_dir",
    "is_loopback",
    "load_settings",
    "load_toml_settings",
    "servable_formats",
]
