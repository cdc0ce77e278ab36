"""The settings schema and its documentation agree, both ways.

docs/service.md's "Configuration" tables (and any ```[section] key``` it mentions in prose) and
deploy/recal.toml (commented-out keys included) are the documented keys; ``Settings`` (walked
recursively) is the accepted ones. A documented key the daemon refuses, or an accepted key no user
can find, fails here.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest
from pydantic import BaseModel

from service.config import Settings, load_settings
from service.gate import GateConfig

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "service.md"
EXAMPLE = ROOT / "deploy" / "recal.toml"

_HEADING = re.compile(r"^###\s+(?:`\[(\w+)\]`|Top level)", re.M)
_ROW = re.compile(r"^\|\s*`(\w+)`\s*\|", re.M)
_PROSE = re.compile(r"`\[(\w+)\]\s+(\w+)")
#: ``# key = value`` in the example file: a documented, commented-out setting.
_COMMENTED = re.compile(r"^#\s*(\w+\s*=\s*\S.*)$", re.M)


def accepted_keys(model: type[BaseModel] = Settings, prefix: str = "") -> set[str]:
    """Every key ``model`` accepts, sections as ``section.key``."""
    keys = set()
    for name, field in model.model_fields.items():
        sub = field.annotation
        if isinstance(sub, type) and issubclass(sub, BaseModel):
            keys |= accepted_keys(sub, f"{prefix}{name}.")
        else:
            keys.add(prefix + name)
    return keys


def doc_keys(text: str) -> set[str]:
    """Keys of the Configuration tables (### `[section]` then | `key` | rows) and of prose
    mentions like ```[gate] refuse_worse_navigation```."""
    start = text.index("## Configuration")
    end = text.find("\n## ", start + 1)
    part = text[start : end if end > 0 else None]
    keys = set()
    headings = list(_HEADING.finditer(part))
    for i, h in enumerate(headings):
        body = part[h.end() : headings[i + 1].start() if i + 1 < len(headings) else None]
        prefix = f"{h.group(1)}." if h.group(1) else ""
        keys |= {prefix + k for k in _ROW.findall(body) if k != "key"}
    keys |= {f"{s}.{k}" for s, k in _PROSE.findall(text)}
    return keys


def toml_keys(data: dict, prefix: str = "") -> set[str]:
    keys = set()
    for name, value in data.items():
        if isinstance(value, dict):
            keys |= toml_keys(value, f"{prefix}{name}.")
        else:
            keys.add(prefix + name)
    return keys


def example_keys(text: str) -> set[str]:
    """Keys of deploy/recal.toml, its commented-out ``# key = value`` lines included."""
    uncommented = _COMMENTED.sub(r"\1", text)
    return toml_keys(tomllib.loads(uncommented))


def test_the_parsers_read_what_they_should() -> None:
    text = "## Configuration\n### Top level keys\n| key | x |\n| `a` | 1 |\n### `[gate]`: g\n" \
        "| `b` | 2 |\n## Next\n| `c` | 3 |\nsee `[api] token`\n"  # fmt: skip
    assert doc_keys(text) == {"a", "gate.b", "api.token"}
    assert example_keys('x = 1\n[s]\n# y = "z"   # note\n# a comment\n') == {"x", "s.y"}


def test_every_documented_key_is_accepted() -> None:
    documented = doc_keys(DOC.read_text(encoding="utf-8"))
    unknown = sorted(documented - accepted_keys())
    assert not unknown, f"docs/service.md documents keys Settings refuses: {unknown}"


def test_every_accepted_key_is_documented() -> None:
    missing = sorted(accepted_keys() - doc_keys(DOC.read_text(encoding="utf-8")))
    assert not missing, f"keys Settings accepts but docs/service.md does not list: {missing}"


def test_every_key_of_the_example_file_is_accepted() -> None:
    unknown = sorted(example_keys(EXAMPLE.read_text(encoding="utf-8")) - accepted_keys())
    assert not unknown, f"deploy/recal.toml has keys Settings refuses: {unknown}"


def test_the_example_file_loads(tmp_path: Path) -> None:
    settings = load_settings(EXAMPLE)
    assert settings.gate.require_verdict in ("partial", "full")
    # its commented-out keys too (prior_path names a file of the target machine: not checked here)
    text = _COMMENTED.sub(r"\1", EXAMPLE.read_text(encoding="utf-8"))
    # the CSV line options apply with format = "csv" only (a KVH refuses them, by name)
    text = text.replace('format = "kvh-a"', 'format = "csv"').replace(
        "gyro_output", "# gyro_output"
    )
    text = text.replace("gyro_units", "# gyro_units").replace(
        "temperature_units", "# temperature_units"
    )
    (tmp_path / "all.toml").write_text(text, encoding="utf-8")
    assert load_settings(tmp_path / "all.toml").site.latitude_deg == settings.site.latitude_deg


@pytest.mark.parametrize("verdict", ["partial", "full"])
def test_require_verdict_is_read_from_the_file_and_reaches_the_gate(
    tmp_path: Path, verdict: str
) -> None:
    path = tmp_path / "recal.toml"
    path.write_text(f'[gate]\nrequire_verdict = "{verdict}"\n', encoding="utf-8")
    settings = load_settings(path)
    assert isinstance(settings.gate, GateConfig)  # the gate takes the settings as they are
    assert GateConfig(**settings.gate.model_dump()).require_verdict == verdict


def test_a_verdict_the_gate_cannot_use_is_refused(tmp_path: Path) -> None:
    from recal.errors import RecalInputError

    path = tmp_path / "recal.toml"
    path.write_text('[gate]\nrequire_verdict = "insufficient"\n', encoding="utf-8")
    with pytest.raises(RecalInputError, match="gate.require_verdict"):
        load_settings(path)


def test_mirrored_sections_build_their_configs_and_share_defaults() -> None:
    """A section and the lower layer's config it feeds (same field names) must not drift."""
    import dataclasses

    from drivers import DecoderConfig
    from recal.detect.static_config import DetectorConfig
    from service.config import DetectorSettings, DeviceSettings, config_from

    for section, cls in ((DetectorSettings(), DetectorConfig), (DeviceSettings(), DecoderConfig)):
        built = config_from(cls, section)
        shared = {f.name for f in dataclasses.fields(cls)} & set(type(section).model_fields)
        assert shared, f"{cls.__name__} shares no field with {type(section).__name__}"
        for name in shared:
            assert getattr(built, name) == getattr(cls(), name) == getattr(section, name), name
    tuned = config_from(DetectorConfig, DetectorSettings(threshold_k=7.0), sample_rate_hz=200.0)
    assert (tuned.threshold_k, tuned.sample_rate_hz) == (7.0, 200.0)


_DEFAULT_ROW = re.compile(r"^\|\s*`(\w+)`\s*\|\s*`([^`]*)`\s*\|", re.M)


def _documented_defaults(text: str) -> dict[str, str]:
    """``section.key`` -> the default column's TOML literal, where it is one (rows whose
    default is prose, "unset" or "measured", are not compared)."""
    start = text.index("## Configuration")
    end = text.find("\n## ", start + 1)
    part = text[start : end if end > 0 else None]
    out = {}
    headings = list(_HEADING.finditer(part))
    for i, h in enumerate(headings):
        body = part[h.end() : headings[i + 1].start() if i + 1 < len(headings) else None]
        prefix = f"{h.group(1)}." if h.group(1) else ""
        out |= {prefix + k: v for k, v in _DEFAULT_ROW.findall(body)}
    return out


def _default(key: str):
    """The default the daemon uses for ``section.key``."""
    value = Settings()
    for part in key.split("."):
        value = getattr(value, part)
    return value


def test_documented_defaults_are_the_shipped_ones() -> None:
    """docs/service.md's default column against ``Settings()``, side by side: a default that
    changes in the code and not in the documentation (or the reverse) fails here."""
    documented = _documented_defaults(DOC.read_text())
    compared, wrong = 0, []
    for key, literal in documented.items():
        try:
            doc_value = tomllib.loads(f"x = {literal}")["x"]
        except tomllib.TOMLDecodeError:
            continue  # a path or a placeholder, not a literal
        actual = _default(key)
        actual = list(actual) if isinstance(actual, tuple) else actual
        if hasattr(actual, "value"):  # an enum
            actual = actual.value
        compared += 1
        if doc_value != actual and not (
            isinstance(actual, float | int) and isinstance(doc_value, float | int)
            and float(doc_value) == float(actual)
        ):  # fmt: skip
            wrong.append(f"{key}: documented {literal}, shipped {actual!r}")
    assert compared >= 40, compared
    assert not wrong, wrong
