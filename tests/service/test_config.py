"""Settings: TOML file, environment overrides, one-line errors."""

import pytest

from recal.errors import RecalInputError
from service.config import load_settings


def test_toml_then_environment_then_keywords(tmp_path, monkeypatch):
    cfg = tmp_path / "recal.toml"
    cfg.write_text(
        'database_url = "sqlite:///x.db"\n[device]\nurl = "socket://10.0.0.5:4001"\n'
        "[site]\nlatitude_deg = 57.7\n"
    )
    s = load_settings(cfg)
    assert s.device.url == "socket://10.0.0.5:4001" and s.site.latitude_deg == 57.7
    assert s.device.format == "kvh-a" and s.scheduler.method == "nafsa"  # defaults kept
    monkeypatch.setenv("RECAL_SITE__LATITUDE_DEG", "12.5")
    assert load_settings(cfg).site.latitude_deg == 12.5
    assert load_settings(cfg, site={"latitude_deg": -3.0}).site.latitude_deg == -3.0


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[site]\nlatitude_deg = 100\n", "site.latitude_deg"),
        ('[device]\nformat = "kvh-z"\n', "device.format"),
        ("[site\n", "config"),
    ],
)
def test_bad_config_is_one_line(tmp_path, text, message):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    with pytest.raises(RecalInputError, match=message) as info:
        load_settings(cfg)
    assert "\n" not in str(info.value)


def test_missing_config_file(tmp_path):
    with pytest.raises(RecalInputError, match="does not exist"):
        load_settings(tmp_path / "nope.toml")


def test_shipped_example_config_loads():
    from pathlib import Path

    s = load_settings(Path(__file__).resolve().parents[2] / "deploy" / "recal.toml")
    assert s.device.url == "/dev/ttyUSB0" and s.site.latitude_deg == 57.7
    assert s.scheduler.sensor == "both" and s.api.port == 8750


# ---- unknown keys, the API token and host -----------------------------------------------------


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "[scheduler]\nmin_postions = 3\n",
            "config: scheduler: unknown key min_postions (known: min_positions,",
        ),
        ("[device]\nbaud_rate = 9600\n", "config: device: unknown key baud_rate (known: url,"),
        ("[api]\nprot = 9000\n", "config: api: unknown key prot (known: host, port,"),
        ("[detector]\nwindow = 2\n", "config: detector: unknown key window (known: window_s,"),
        (
            'databse_url = "sqlite:///x.db"\n',
            "config: unknown key databse_url (known: database_url,",
        ),
    ],
)
def test_unknown_keys_are_errors_naming_key_and_section(tmp_path, text, message):
    cfg = tmp_path / "typo.toml"
    cfg.write_text(text)
    with pytest.raises(RecalInputError) as info:
        load_settings(cfg)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_misspelt_environment_variable_is_named_unrelated_ones_are_not(monkeypatch):
    monkeypatch.setenv("RECAL_DEBUG", "1")  # the CLI's own, not a setting
    monkeypatch.setenv("RECAL_TEST_POSTGRES", "postgresql://x")
    assert load_settings().scheduler.min_positions == 12
    monkeypatch.setenv("RECAL_SCHEDULER__MIN_POSTIONS", "3")
    with pytest.raises(RecalInputError, match="environment variable RECAL_SCHEDULER__MIN_POSTIONS"):
        load_settings()


TOKEN = "0123456789abcdef-token"


def test_token_from_file_or_environment_is_secret(tmp_path, monkeypatch):
    cfg = tmp_path / "recal.toml"
    cfg.write_text(f'[api]\ntoken = "{TOKEN}"\n')
    s = load_settings(cfg)
    assert s.api.token.get_secret_value() == TOKEN and TOKEN not in repr(s)
    monkeypatch.setenv("RECAL_API__TOKEN", TOKEN + "-env")
    assert load_settings(cfg).api.token.get_secret_value() == TOKEN + "-env"
    monkeypatch.setenv("RECAL_API__TOKEN", "")  # an empty variable means no token
    assert load_settings().api.token is None
    monkeypatch.setenv("RECAL_API__TOKEN", "short")
    with pytest.raises(RecalInputError, match="config: api.token: must be at least 16"):
        load_settings()


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.168.1.20", "bridge.local"])
def test_listening_beyond_loopback_needs_a_token(tmp_path, host):
    cfg = tmp_path / "recal.toml"
    cfg.write_text(f'[api]\nhost = "{host}"\n')
    with pytest.raises(RecalInputError, match=rf"config: api: host {host} is reachable .* token"):
        load_settings(cfg)
    assert load_settings(cfg, api={"host": host, "token": TOKEN}).api.host == host


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.1.1", "localhost", "::1"])
def test_loopback_needs_no_token(host):
    assert load_settings(api={"host": host}).api.token is None


def test_allowed_origins_are_checked(tmp_path):
    ok = load_settings(api={"allowed_origins": ["http://Console.local:8080", "https://[fe80::1]"]})
    assert ok.api.allowed_origins == ["http://console.local:8080", "https://[fe80::1]"]
    with pytest.raises(RecalInputError, match="api.allowed_origins: 'console.local' is not"):
        load_settings(api={"allowed_origins": ["console.local"]})


# ---- declared closed turns --------------------------------------------------------------------


def test_turn_closure_is_off_by_default_and_reaches_the_jobs(tmp_path):
    """[scheduler] turn_closure_deg: 0 (no declared closed turns, only turns Earth rate checks)
    unless set; the scheduler's jobs get it as CalibrationOptions.turn_closure_sigma_deg."""
    from types import SimpleNamespace

    import numpy as np

    from recal.model.coefficients import CoefficientSet
    from recal.sim.simulate import simulate_positions
    from service.scheduler import Scheduler
    from service.store.repository import Store

    assert load_settings().scheduler.turn_closure_deg == 0.0
    cfg = tmp_path / "recal.toml"
    cfg.write_text("[scheduler]\nturn_closure_deg = 0.1\nuse_slews = false\n")
    settings = load_settings(cfg)
    assert settings.scheduler.turn_closure_deg == 0.1
    with pytest.raises(RecalInputError, match="turn_closure_deg"):
        load_settings(cfg, scheduler={"turn_closure_deg": -1.0})

    seed = CoefficientSet.seed_truth().values
    unit = {n: np.ones(3) if n.endswith("scale") else np.zeros_like(v) for n, v in seed.items()}
    positions = simulate_positions(CoefficientSet(unit), seed=1)  # a KVH: deg/h and g
    store = Store(f"sqlite:///{tmp_path / 'recal.db'}")
    store.create_schema()
    store.add_positions(store.add_session("test"), positions.columns)
    submitted = []
    runner = SimpleNamespace(busy=False, submit=lambda fn, args, on_end: submitted.append(args))
    events = SimpleNamespace(emit=lambda *a, **k: None)
    Scheduler(store, settings, None, events=events, runner=runner).trigger("manual")
    (args,) = submitted
    assert args[1].turn_closure_sigma_deg == 0.1
    assert args[1].wander == "auto"  # [scheduler] wander's default reaches the job too
    assert np.all(args[0]["session"] == 1)  # and the session of each window (clocks restart)
