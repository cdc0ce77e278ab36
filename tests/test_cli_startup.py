"""Building the parser imports no numpy, scipy, engine or drivers; each command imports its own.

Structural checks in fresh interpreters (sys.modules), not timings: the timings are in
benchmarks/bench_cli_startup.py.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

# drivers.registry (the --format choices) is light; the parsers and decoders are not.
DRIVERS_HEAVY = ("drivers.bulk", "drivers.decoder", "drivers.csv_log", "drivers.reader")
HEAVY = ("numpy", "scipy", "recal.solve.calibrate", "recal.detect.static_detector", "recal.model.positions", "tqdm",
         *DRIVERS_HEAVY)  # fmt: skip


def modules_after(code: str) -> set[str]:
    """The top-level and recal/drivers modules a fresh interpreter holds after running code."""
    script = f"{code}\nimport sys, json; print(json.dumps(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", script], check=True, capture_output=True, text=True
    ).stdout
    return set(json.loads(out.splitlines()[-1]))


def test_building_the_parser_imports_nothing_heavy():
    loaded = modules_after("import service.cli.main as m\nm.build_parser()")
    assert "service.cli.positions" in loaded and "service.cli.calibrate" in loaded
    assert not [name for name in HEAVY if name in loaded]


def test_help_imports_nothing_heavy():
    code = (
        "import service.cli.main as m\n"
        "try:\n    m.main(['positions', '--help'])\nexcept SystemExit:\n    pass"
    )
    loaded = modules_after(code)
    assert not [name for name in HEAVY if name in loaded]


def test_a_command_imports_only_what_it_needs(tmp_path):
    pos = tmp_path / "pos.csv"
    code = f"import service.cli.main as m\nassert m.main(['simulate', '-o', {str(pos)!r}]) == 0"
    loaded = modules_after(code)
    assert "numpy" in loaded and "recal.sim.simulate" in loaded
    assert not {"scipy", "recal.solve.calibrate", "recal.detect.static_detector"} & loaded
    # only the input-error base (drivers.errors, which recal.errors subclasses) and the light
    # format registry (the --format choices), no reader
    assert {m for m in loaded if m.startswith("drivers.")} <= {"drivers.errors", "drivers.registry"}


@pytest.mark.parametrize(
    ("module", "constant", "source"),
    [
        ("service.cli.simulate_args", "DESIGNS", "recal.sim.simulate:DESIGNS"),
        (
            "service.cli.simulate_args",
            "DEFAULT_ARW_DEG_RT_H",
            "recal.sim.simulate:NoiseSpec.arw_deg_rt_h",
        ),
        (
            "service.cli.simulate_args",
            "DEFAULT_VRW_UG_RT_HZ",
            "recal.sim.simulate:NoiseSpec.vrw_ug_rt_hz",
        ),
        ("service.cli.simulate_args", "DEFAULT_WINDOW_S", "recal.sim.simulate:NoiseSpec.window_s"),
        ("service.cli.simulate_args", "DEFAULT_SLEW_S", "recal.sim.simulate:NoiseSpec.slew_s"),
        ("service.cli.simulate_args", "DEFAULT_RATE_HZ", "recal.sim.simulate:NoiseSpec.rate_hz"),
        (
            "service.cli.simulate_args",
            "DEFAULT_TEMP_START_C",
            "recal.sim.simulate:TemperatureSpec.start_c",
        ),
        (
            "service.cli.simulate_args",
            "DEFAULT_TEMP_SLOPE_C_PER_H",
            "recal.sim.simulate:TemperatureSpec.slope_c_per_h",
        ),
        ("service.cli.record", "DEFAULT_BAUD", "drivers.transport:DEFAULT_BAUD"),
    ],
)
def test_constants_repeated_for_the_parser_match_their_source(module, constant, source):
    import importlib

    where, attr = source.split(":")
    value = importlib.import_module(where)
    for part in attr.split("."):
        value = getattr(value, part)
    assert getattr(importlib.import_module(module), constant) == value


def test_record_formats_are_the_registered_ones():
    """``recal record --format`` takes its choices from drivers.formats when it is used, not
    from a list written in the CLI: a format registered after the parser was built counts."""
    import dataclasses

    from drivers.formats import format_names, get_format, register, unregister
    from service.cli.main import build_parser
    from service.cli.record import FORMATS

    assert list(FORMATS) == format_names()
    parser = build_parser()
    toy = dataclasses.replace(get_format("kvh-a"), name="toy-frames", aliases=())
    register(toy)
    try:
        assert "toy-frames" in FORMATS
        args = parser.parse_args(["record", "loop://", "out.bin", "--format", "toy-frames"])
        assert args.format == "toy-frames"
    finally:
        unregister("toy-frames")
    assert "toy-frames" not in FORMATS


def test_recal_simulate_is_split_by_idea() -> None:
    """Issue 38: ``recal simulate`` keeps the session in service/cli/simulate.py and its options,
    writers, vessel and navigation recording in modules beside it, each under 600 lines."""
    import importlib
    from pathlib import Path

    for part in ("simulate", "simulate_args", "simulate_writers", "simulate_vessel",
                 "simulate_trajectory"):  # fmt: skip
        module = importlib.import_module(f"service.cli.{part}")
        assert len(Path(module.__file__).read_text().splitlines()) < 600, part
