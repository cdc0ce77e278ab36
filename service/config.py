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

import dataclasses
import ipaddress
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar
from urllib.parse import urlsplit

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SecretStr,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from recal.errors import RecalInputError

T = TypeVar("T")
S = TypeVar("S", bound=BaseSettings)

#: Shortest ``[api] token`` accepted.
MIN_TOKEN_LENGTH = 16
_ORIGIN = re.compile(
    r"https?://[A-Za-z0-9.\-]+(:[0-9]{1,5})?|https?://\[[0-9A-Fa-f:.]+\](:[0-9]{1,5})?"
)


#: A unit's serial, as the shore registers it (docs/fleet.md, "Commands").
_SERIAL = re.compile(r"[A-Za-z0-9._-]{1,64}")


def is_loopback(host: str) -> bool:
    """True when ``host`` only accepts connections from this machine."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:  # a host name: it may resolve to anything
        return False


class Section(BaseModel):
    """A configuration section: a key it does not define is an error, not silently ignored."""

    model_config = ConfigDict(extra="forbid")


def servable_formats() -> list[str]:
    """The registered formats the daemon can read from one port (not a pair of files)."""
    from drivers.registry import input_formats

    return [f.name for f in input_formats() if f.inputs == 1]


class DeviceSettings(Section):
    url: str = Field(
        "loop://",
        description="serial port (/dev/ttyUSB0), socket://host:port, or "
        "replay:///path/capture.bin?speed=1 to replay a recording",
    )
    format: str = Field(
        "kvh-a",
        description="input format, one registered in drivers.registry (recal positions --help "
        "lists them: KVH binary frames, csv lines, ...)",
        json_schema_extra={"choices": lambda: servable_formats()},
    )
    baudrate: int = Field(921600, gt=0, description="serial line speed (bit/s)")
    rate_hz: float = Field(
        1000.0,
        gt=0,
        le=5000,
        description="samples per second the unit sends (csv without a time column: time = "
        "row / rate_hz)",
    )
    gyro_output: Literal["delta", "rate"] = Field(
        "delta",
        description="KVH: delta: angle per sample (the device default); rate: per second",
    )
    gyro_units: Literal["rad", "deg"] = Field("rad", description="KVH: unit of the gyro output")
    temperature_units: Literal["degC", "centi"] = Field(
        "degC", description="KVH: centi: hundredths of a degC (the device's C_100)"
    )
    columns: str | None = Field(
        None,
        description="csv: the stream's own column names for the standard ones, NEW=OLD,... as "
        "recal positions --columns (e.g. accel_x=ax,accel_y=ay,accel_z=az,time_s=t)",
    )
    header: str | None = Field(
        None,
        description="csv: the header row, for a stream joined after its header went by (then "
        "every line read is data)",
    )

    @field_validator("format")
    @classmethod
    def _registered(cls, value: str) -> str:
        from drivers.registry import get_input_format

        fmt = get_input_format(value)  # InputError naming the registered formats
        if fmt.inputs != 1:
            raise ValueError(f"{fmt.name} is read from {fmt.inputs} files; a port carries one")
        return fmt.name

    @model_validator(mode="after")
    def _options_of_the_format(self) -> DeviceSettings:
        from drivers.registry import check_options

        check_options(self.format, {k: getattr(self, k) for k in ("columns", "header")})
        return self

    def format_options(self) -> dict[str, Any]:
        """The settings the format's parser takes (drivers.registry), by name."""
        from drivers.registry import get_input_format

        return {
            name: getattr(self, name)
            for name in get_input_format(self.format).option_names
            if getattr(self, name, None) is not None
        }


#: The latitude a still (laboratory) unit is taken at when ``[site] latitude_deg`` is unset, as
#: before the setting could be unset; a hull-fixed unit never assumes one (Settings._latitude).
STILL_DEFAULT_LATITUDE_DEG = 45.0


class SiteSettings(Section):
    latitude_deg: float | None = Field(
        None,
        ge=-90,
        le=90,
        description="where the unit is: gravity and Earth rate follow it; unset: from [nav] "
        "(the windows' latitude); a still unit without [nav] is taken at 45; with motion = "
        '"hull", [nav] url or this is required',
    )
    height_m: float = Field(0.0, description="height above the WGS-84 ellipsoid (m)")
    imu_attitude_rpy_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0),
        description="the IMU's roll, pitch, yaw in north-east-down at berth (deg): where its axes "
        "point decides which coefficient errors reach the predicted navigation error",
    )
    navigation_hours: float = Field(
        24.0, gt=0, le=720, description="horizon of the predicted static navigation error (h)"
    )


class DetectorSettings(Section):
    """The static detector. Durations left unset follow the device rate (recal.detect.static); the
    thresholds come, in this order, from explicit values, the noise floor stored for the device
    (reused after a restart: the unit may be moving then), an initial still period
    (init_still_s), or the quietest stretches of the first ``learn_s`` seconds."""

    window_s: float | None = Field(
        None, gt=0, description="moving-variance window (s; unset: about 100 frames)"
    )
    min_duration_s: float | None = Field(
        None, gt=0, description="shortest static window kept (s; unset: max(window_s, 0.5 s))"
    )
    edge_trim_s: float | None = Field(
        None, ge=0, description="dropped at both ends of a window (s; unset: window_s / 2)"
    )
    init_still_s: float | None = Field(
        None,
        gt=0,
        description="the unit starts still for this long: learn the noise floor there (s)",
    )
    learn_s: float = Field(
        120.0,
        gt=0,
        description="else learn it from the quietest stretches of the first learn_s (s)",
    )
    learn_quiet_s: float = Field(
        10.0,
        gt=0,
        description="learning ends sooner, from the frames held, when the stream sends nothing "
        "for this long (s of wall time), after learn_s of wall time, or when the input ends",
    )
    threshold_k: float = Field(5.0, gt=0, description="threshold = threshold_k x noise floor")
    accel_threshold: float | None = Field(
        None, ge=0, description="explicit accel threshold on the moving variance ((m/s^2)^2)"
    )
    gyro_threshold: float | None = Field(
        None, ge=0, description="explicit gyro threshold on the moving variance (gyro units^2)"
    )
    max_gap_frames: int = Field(
        5, ge=0, description="longest run of lost or invalid frames a window may contain"
    )
    # the hull detector (recal.detect.hull); the defaults are recal.detect.hull.HullConfig's
    motion: Literal["still", "hull"] = Field(
        "still",
        description="still: windows where the moving variance is low (a unit at rest); hull: "
        "quasi-static windows of a hull that rolls, pitches and swings at berth "
        "(recal.detect.hull: no noise floor is learned; the hull_* keys tune it)",
    )
    hull_min_window_s: float = Field(
        120.0, gt=0, description="hull: shortest quasi-static window (s; many wave periods)"
    )
    hull_max_window_s: float = Field(
        900.0, gt=0, description="hull: a longer quiet stretch is cut into windows this long (s)"
    )
    hull_turn_window_s: float = Field(
        60.0,
        ge=40,
        description="hull: span the rate is averaged over to find heading turns (s; at least "
        "two of the longest wave periods, 40 s)",
    )
    hull_max_swing_deg: float = Field(
        1.0, ge=0, description="hull: largest heading swing at berth that is not a turn (deg)"
    )
    hull_trim_s: float = Field(
        30.0, ge=0, description="hull: dropped at both ends of a quiet stretch (s)"
    )
    hull_lever_arm_max_m: float = Field(
        10.0,
        ge=0,
        description="hull: largest distance of the IMU from the hull's centre of rotation (m): "
        "its centripetal acceleration is carried in the accel uncertainty",
    )

    @model_validator(mode="after")
    def _hull_windows(self) -> DetectorSettings:
        if self.hull_min_window_s > self.hull_max_window_s:
            raise ValueError(
                f"hull_min_window_s {self.hull_min_window_s:g} exceeds hull_max_window_s "
                f"{self.hull_max_window_s:g}"
            )
        return self

    def hull_config(self) -> Any:
        """The hull detector's :class:`recal.detect.hull.HullConfig` from the hull_* keys."""
        from recal.detect.hull import HullConfig

        return HullConfig(
            turn_window_s=self.hull_turn_window_s,
            max_swing_deg=self.hull_max_swing_deg,
            trim_s=self.hull_trim_s,
            min_window_s=self.hull_min_window_s,
            max_window_s=self.hull_max_window_s,
            lever_arm_max_m=self.hull_lever_arm_max_m,
            max_gap_frames=self.max_gap_frames,
        )


class NavSettings(Section):
    """The ship's GNSS and heading over NMEA 0183 (docs/service.md, `[nav]`);
    without ``url`` (no ``[nav]`` section) none are read."""

    url: str | None = Field(
        None,
        description="where the sentences come from: udp://:10110 (the marine default: UDP "
        "broadcasts on port 10110), tcp://HOST:PORT, or a serial port as [device] url takes; "
        "unset: no ship's sensors",
    )
    log: str | None = Field(
        None,
        description="instead of url, for a replayed capture ([device] url = replay://...): a "
        "file of the sentences logged beside it, its first sentence at the capture's first "
        "frame (as recal positions --nmea aligns it); the windows are joined to it on the "
        "capture's own clock, whatever the replay's speed",
    )
    baudrate: int = Field(
        4800, gt=0, description="serial line speed (bit/s; NMEA 0183: 4800, high-speed 38400)"
    )
    max_sog_kn: float = Field(
        1.0,
        ge=0,
        description="a window whose mean speed over ground exceeds this is rejected as "
        "underway (kn); below it the transport rate of its net displacement is added to its "
        "gyro sigma (docs/service.md, 'The ship's sensors')",
    )

    @field_validator("url")
    @classmethod
    def _openable(cls, url: str | None) -> str | None:
        if url is None or url.strip() == "":
            return None
        from drivers.transport import check_url

        check_url(url.strip(), must_exist=False)  # DriverInputError naming the known schemes
        return url.strip()

    @field_validator("log")
    @classmethod
    def _readable(cls, log: str | None) -> str | None:
        if log is None or log.strip() == "":
            return None
        from pathlib import Path

        if not Path(log.strip()).is_file():
            raise ValueError(f"{log.strip()} is not a file")
        return log.strip()

    @model_validator(mode="after")
    def _one_source(self) -> NavSettings:
        if self.url is not None and self.log is not None:
            raise ValueError("give url (a live talker) or log (a replayed one), not both")
        return self

    @property
    def enabled(self) -> bool:
        return self.url is not None or self.log is not None


Trigger = Literal["drift", "information", "count"]


class SchedulerSettings(Section):
    min_positions: int = Field(
        12, ge=1, description="stored windows before any automatic recalibration"
    )
    min_new_positions: int = Field(
        4,
        ge=1,
        description="new windows since the last job before the next automatic one by count, "
        "and before another drift or information job when the last one was not accepted",
    )
    trigger: list[Trigger] = Field(
        ["drift", "information"],
        description="what starts an automatic recalibration once one is accepted: 'drift' (the "
        "new windows show the coefficients changed, recal.diagnose.drift), 'information' (they would "
        "sharpen them by min_information_gain, recal.diagnose.information), 'count' (min_new_positions "
        "new windows); a list or one name (the first calibration always waits for "
        "min_positions windows)",
    )
    min_information_gain: float = Field(
        0.25,
        gt=0,
        lt=1,
        description="'information' trigger: run when the new windows would cut some "
        "coefficient's 1-sigma by this fraction",
    )
    drift_false_alarm_days: float = Field(
        30.0, gt=0, description="'drift' trigger: one false alarm per this many days..."
    )
    windows_per_day: float | None = Field(
        None,
        gt=0,
        description="... at this rate of static windows; unset: measured from the stored "
        "windows' device time (24 a day until a day of them is stored)",
    )

    sensor: Literal["gyro", "accel", "both"] = Field("both", description="triads to calibrate")
    method: Literal["lm", "nafsa", "safsa", "oafsa"] = Field(
        "nafsa",
        description="estimator (as recal calibrate --method): MCS-NAFSA, the seeds' method, "
        "by default (seconds with slews, docs/engine.md); lm is the fast fallback",
    )
    mc_runs: int = Field(100, ge=1, description="Monte Carlo runs for the uncertainties")
    use_last_positions: int = Field(
        200, ge=1, description="a job uses at most this many of the most recent windows"
    )
    use_slews: bool = Field(
        True,
        description="calibrate the gyro from the stored motion between windows too (recal.detect.slews)",
    )
    turn_closure_deg: float = Field(
        0.0,
        ge=0,
        lt=180,
        description="declare that slews turning whole revolutions about the vertical close "
        "exactly, with this 1-sigma (deg), as recal calibrate --turn-closure; 0: none declared, "
        "a turn is closed only where the Earth-rate headings check it (a FOG)",
    )
    wander: Literal["auto", "none"] = Field(
        "auto",
        description="bias wander between windows (recal.solve.wander, as recal calibrate "
        "--wander): auto estimates it from each job's residuals where the windows of a session "
        "span an hour or more and keeps it when significant; none takes windows as independent",
    )
    job_timeout_s: float = Field(
        1800.0, gt=0, description="a job running longer is killed and recorded as failed (s)"
    )
    stop_wait_s: float = Field(
        60.0,
        ge=0,
        description="at shutdown a running job may finish for this long, then it is abandoned "
        "(s); keep it below the unit's TimeoutStopSec",
    )

    @field_validator("trigger", mode="before")
    @classmethod
    def _one_or_many(cls, value: Any) -> Any:
        if isinstance(value, str):  # trigger = "drift", or "drift+information"
            value = [v.strip() for v in value.replace(",", "+").split("+") if v.strip()]
        if isinstance(value, list | tuple):
            if not value:
                raise ValueError("name at least one of drift, information, count")
            return list(dict.fromkeys(value))
        return value


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


class ApiSettings(Section):
    host: str = Field(
        "127.0.0.1", description="address the HTTP API listens on (not loopback: needs a token)"
    )
    port: int = Field(8750, ge=0, le=65535, description="its TCP port")
    token: SecretStr | None = Field(
        None,
        description="bearer token the write endpoints require (Authorization: Bearer ...); "
        "without one they are refused, and the API may only listen on a loopback address",
    )
    allowed_origins: list[str] = Field(
        [],
        description="browser origins (scheme://host[:port]) allowed to call the API from their "
        "pages",
    )
    max_event_streams: int = Field(
        32, ge=1, le=10_000, description="open /events streams at once; more are answered 429"
    )

    @field_validator("token")
    @classmethod
    def _strong_token(cls, token: SecretStr | None) -> SecretStr | None:
        if token is None or token.get_secret_value() == "":  # RECAL_API__TOKEN= means unset
            return None
        value = token.get_secret_value()
        if len(value) < MIN_TOKEN_LENGTH or value != value.strip():
            raise ValueError(
                f"must be at least {MIN_TOKEN_LENGTH} characters without surrounding spaces "
                "(recal demo --serve prints a fresh one)"
            )
        return token

    @field_validator("allowed_origins")
    @classmethod
    def _origins(cls, origins: list[str]) -> list[str]:
        for origin in origins:
            if not _ORIGIN.fullmatch(origin):
                raise ValueError(f"{origin!r} is not an origin like http://host:port")
        return [o.lower() for o in origins]

    @model_validator(mode="after")
    def _loopback_without_token(self) -> ApiSettings:
        if self.token is None and not is_loopback(self.host):
            raise ValueError(
                f"host {self.host} is reachable from other machines: set [api] token "
                "(or RECAL_API__TOKEN), or listen on 127.0.0.1"
            )
        return self


class SyncSettings(Section):
    """Fleet sync to the shore service (docs/fleet.md); without ``url``, ``unit`` and
    ``token`` (no ``[sync]`` section) nothing is sent."""

    url: str | None = Field(
        None,
        description="the shore service's base URL (https://host:port; plain http only to a "
        "loopback address, e.g. a local tunnel); unset: no sync",
    )
    unit: str | None = Field(
        None, description="this unit's serial, unique in the fleet (as registered on shore)"
    )
    token: SecretStr | None = Field(
        None,
        description="this unit's credential, printed by recal fleet add-unit on shore (or "
        "RECAL_SYNC__TOKEN)",
    )
    interval_s: float = Field(
        60.0,
        gt=0,
        description="how often the outbox is offered when the link is up (s); a backlog is "
        "sent batch after batch without waiting",
    )
    fleet_prior: bool = Field(
        True,
        description="fetch the fleet prior of this unit's model from the shore (at start, then "
        "every 6 h the link is up) into state_dir/fleet_prior.json, which the gate uses unless "
        "[gate] fleet_prior names a file",
    )

    @field_validator("url")
    @classmethod
    def _shore_url(cls, url: str | None) -> str | None:
        if url is None or url.strip() == "":
            return None
        parts = urlsplit(url.strip())
        if parts.scheme not in ("https", "http") or not parts.hostname:
            raise ValueError(f"{url!r} is not a URL like https://shore.example:8443")
        if parts.query or parts.fragment or parts.username or parts.password:
            raise ValueError(f"{url!r}: give the base URL only (no user, query or fragment)")
        if parts.scheme == "http" and not is_loopback(parts.hostname):
            raise ValueError(
                f"{url!r} would send the token in clear: use https (plain http only to a "
                "loopback address, e.g. a local tunnel)"
            )
        return url.strip().rstrip("/")

    @field_validator("unit")
    @classmethod
    def _serial(cls, unit: str | None) -> str | None:
        if unit is None or unit == "":
            return None
        if not _SERIAL.fullmatch(unit):  # what recal fleet add-unit registers
            raise ValueError(f"{unit!r}: a serial is 1 to 64 letters, digits, '.', '-', '_'")
        return unit

    @field_validator("token")
    @classmethod
    def _credential(cls, token: SecretStr | None) -> SecretStr | None:
        if token is None or token.get_secret_value() == "":  # RECAL_SYNC__TOKEN= means unset
            return None
        value = token.get_secret_value()
        if value != value.strip() or not value.isprintable() or " " in value:
            raise ValueError("must be printable, without spaces")
        return token

    @model_validator(mode="after")
    def _together(self) -> SyncSettings:
        given = {k: getattr(self, k) is not None for k in ("url", "unit", "token")}
        if any(given.values()) and not all(given.values()):
            missing = ", ".join(k for k, v in given.items() if not v)
            raise ValueError(
                f"url, unit and token go together (missing: {missing}; the token may come "
                "from RECAL_SYNC__TOKEN)"
            )
        return self

    @property
    def enabled(self) -> bool:
        return self.url is not None


class Settings(BaseSettings):
    """Everything the daemon needs; see the module docstring for the file layout."""

    model_config = SettingsConfigDict(env_prefix="RECAL_", env_nested_delimiter="__")

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

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        # keyword arguments > environment > TOML file (``toml_file`` of the model config)
        return init_settings, env_settings, TomlConfigSettingsSource(settings_cls)


def default_state_dir(environ: Mapping[str, str] | None = None) -> Path:
    """Where the daemon keeps its files when ``state_dir`` is unset: ``$STATE_DIRECTORY`` (the
    first, if several: systemd sets it from the unit's ``StateDirectory=``), else the user's
    state folder, ``$XDG_STATE_HOME/recal`` (an absolute ``XDG_STATE_HOME`` only, as the XDG
    base directory specification says) or ``~/.local/state/recal``. A user-level default keeps
    a hand-started daemon's database and spool in one known place, whatever folder it was
    started from."""
    env = os.environ if environ is None else environ
    systemd = env.get("STATE_DIRECTORY", "").split(":")[0]
    if systemd:
        return Path(systemd)
    xdg = env.get("XDG_STATE_HOME", "")
    if xdg and os.path.isabs(xdg):
        return Path(xdg) / "recal"
    return Path.home() / ".local" / "state" / "recal"


def config_from(cls: type[T], section: BaseModel, **extra: Any) -> T:
    """``cls`` (a dataclass of a lower layer, e.g. ``recal.detect.static.DetectorConfig`` or
    ``drivers.DecoderConfig``) from the fields of a settings ``section`` it shares by name, plus
    ``extra``: no field-by-field copy to fall out of step when either side gains a field."""
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    given = {k: v for k, v in section.model_dump().items() if k in names}
    return cls(**{**given, **extra})


def check_keys(model: type[BaseModel], data: Mapping[str, Any], section: str | None) -> None:
    """Raise ValueError naming the first key of ``data`` that ``model`` (or one of its section
    models, recursively) does not define."""
    fields = model.model_fields
    for key, value in data.items():
        if key not in fields:
            where = f"{section}: " if section else ""
            raise ValueError(
                f"{where}unknown key {key} (known: {', '.join(fields)}){_env_hint(section, key)}"
            )
        sub = fields[key].annotation
        if isinstance(value, Mapping) and isinstance(sub, type) and issubclass(sub, BaseModel):
            check_keys(sub, value, f"{section}.{key}" if section else key)


def _env_hint(section: str | None, key: str) -> str:
    """Where an unknown key came from, when it is an environment variable."""
    parts = [*(section.split(".") if section else []), key]
    name = "RECAL_" + "__".join(parts)
    found = [k for k in os.environ if k.upper() == name.upper()]
    return f" from environment variable {found[0]}" if found else ""


def _one_line(err: Any) -> str:
    """``config: where: message`` for one pydantic error."""
    where = ".".join(str(x) for x in err["loc"])
    ctx = err.get("ctx") or {}
    msg = str(ctx["error"]) if err["type"] == "value_error" and "error" in ctx else err["msg"]
    msg = " ".join(msg.split())
    return f"config: {where}: {msg}" if where else f"config: {msg}"


def load_settings(path: str | os.PathLike[str] | None = None, **overrides: Any) -> Settings:
    """Settings from ``path`` (TOML), the environment and ``overrides``; bad input is a
    one-line :class:`RecalInputError` naming the field."""
    return load_toml_settings(Settings, path, **overrides)


def load_toml_settings(
    settings_cls: type[S], path: str | os.PathLike[str] | None = None, **overrides: Any
) -> S:
    """``settings_cls`` (a :class:`BaseSettings` reading ``toml_file``, as :class:`Settings`
    and the shore's ``service.fleet.config.ShoreSettings``) from ``path``, the environment and
    ``overrides``; bad input is a one-line :class:`RecalInputError` naming the field."""
    cls: type[S] = settings_cls
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise RecalInputError(f"config file {p} does not exist")

        class FileSettings(settings_cls):  # type: ignore[valid-type,misc]
            model_config = SettingsConfigDict(toml_file=p)

        cls = FileSettings
    try:
        return cls(**overrides)
    except ValidationError as exc:
        raise RecalInputError(_one_line(exc.errors()[0])) from None
    except ValueError as exc:  # TOML syntax errors
        raise RecalInputError(f"config {path}: {exc}") from None
