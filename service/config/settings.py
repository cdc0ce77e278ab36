"""The daemon's settings: the top-level keys, one field per section, and the rules that span
sections (the latitude of a hull-fixed unit, the state directory's paths, the fleet prior)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import Field, model_validator

from service.config.api import ApiSettings
from service.config.detector import DetectorSettings
from service.config.device import DeviceSettings
from service.config.gate import GateSettings
from service.config.nav import NavSettings
from service.config.scheduler import SchedulerSettings
from service.config.section import TomlFileSettings, check_keys
from service.config.site import STILL_DEFAULT_LATITUDE_DEG, SiteSettings
from service.config.state_dir import default_state_dir
from service.config.sync import SyncSettings


class Settings(TomlFileSettings):
    """Everything the daemon needs; see the module docstring for the file layout."""

    # str once loaded: unset, they are filled in under state_dir (see _state_paths)
    database_url: str | None = Field(
        None,
        description="where windows, calibrations and events are kept: sqlite:///FILE or "
        "postgresql+psycopg://user@host/db (its schema is upgraded at start; unset: "
        "sqlite:///STATE_DIR/recal.db)",
    )
    publish_path: str | None = Field(
        None,
        description="JSON file the accepted coefficients are published to (unset: "
        "STATE_DIR/coefficients.json)",
    )
    prior_path: str | None = Field(
        None, description="coefficients JSON the first calibration starts from (unset: none)"
    )
    spool_dir: str | None = Field(
        None,
        description="folder where each detected window is made durable until the database has "
        "it (unset: FILE.spool beside a SQLite FILE; else STATE_DIR/spool/HOST_PORT_DB)",
    )
    state_dir: str | None = Field(
        None,
        description="folder for every file the daemon writes whose own setting is unset (the "
        "SQLite database, the published file, the spool); never the working folder (unset: "
        "$STATE_DIRECTORY, which systemd sets from StateDirectory=, else "
        "$XDG_STATE_HOME/recal or ~/.local/state/recal)",
    )
    device: DeviceSettings = Field(DeviceSettings(), description="the IMU and its link")
    site: SiteSettings = Field(SiteSettings(), description="where the unit is")
    detector: DetectorSettings = Field(
        DetectorSettings(), description="the static detector (finds the still windows)"
    )
    scheduler: SchedulerSettings = Field(
        SchedulerSettings(), description="when and how recalibrations run"
    )
    gate: GateSettings = Field(
        GateSettings(), description="what a calibration must pass to be published"
    )
    api: ApiSettings = Field(ApiSettings(), description="the HTTP API")
    sync: SyncSettings = Field(
        SyncSettings(), description="fleet sync to the shore service (docs/fleet.md)"
    )
    nav: NavSettings = Field(
        NavSettings(), description="the ship's GNSS and heading (NMEA 0183; docs/service.md)"
    )

    @model_validator(mode="before")
    @classmethod
    def _no_unknown_keys(cls, data: Any) -> Any:
        if isinstance(data, Mapping):
            check_keys(cls, data, section=None)
        return data

    @model_validator(mode="after")
    def _latitude(self) -> Settings:
        """A hull-fixed unit's latitude is never assumed: from [nav], else [site]."""
        if (
            self.detector.motion == "hull"
            and not self.nav.enabled
            and self.site.latitude_deg is None
        ):
            raise ValueError(
                'with [detector] motion = "hull" the latitude must come from the ship\'s sensors '
                "or be given: set [nav] url (e.g. udp://:10110) or [site] latitude_deg"
            )
        return self

    @property
    def site_latitude_deg(self) -> float | None:
        """``[site] latitude_deg``; unset, 45 for a still unit without ``[nav]`` (the default
        before it could be unset), else None: the ship's sensors give it."""
        if self.site.latitude_deg is not None:
            return self.site.latitude_deg
        if self.detector.motion == "still" and not self.nav.enabled:
            return STILL_DEFAULT_LATITUDE_DEG
        return None

    @model_validator(mode="after")
    def _state_paths(self) -> Settings:
        """Resolve ``state_dir`` (absolute) and put the unset database and published file in
        it: a daemon started from any folder writes to the same place, never to that folder.
        Paths given explicitly are kept as they are."""
        state = Path(self.state_dir).expanduser() if self.state_dir else default_state_dir()
        state = state.absolute()
        self.state_dir = str(state)
        if self.database_url is None:
            self.database_url = f"sqlite:///{state / 'recal.db'}"
        if self.publish_path is None:
            self.publish_path = str(state / "coefficients.json")
        return self

    def fetched_fleet_prior(self) -> Path | None:
        """Where the sync client keeps the fleet prior it fetched from shore
        (``STATE_DIR/fleet_prior.json``); None without ``[sync]`` or with ``[sync]
        fleet_prior = false``."""
        if not (self.sync.enabled and self.sync.fleet_prior):
            return None
        return Path(self.state_dir or default_state_dir()) / "fleet_prior.json"

    def gate_fleet_prior(self) -> str | None:
        """The fleet prior file the gate uses: ``[gate] fleet_prior`` when set, else the one
        fetched from shore once it exists (None: the gate allows no ageing)."""
        if self.gate.fleet_prior is not None:
            return self.gate.fleet_prior
        fetched = self.fetched_fleet_prior()
        return str(fetched) if fetched is not None and fetched.is_file() else None
