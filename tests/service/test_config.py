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
    assert s.device.format == "kvh-a" and s.scheduler.method == "lm"  # defaults kept
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
