"""drivers.registry: the one list of input formats, and the docs that show it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from drivers.errors import DriverInputError
from drivers.registry import (
    check_options,
    get_input_format,
    input_format_names,
    markdown_table,
)

DOCS = Path(__file__).resolve().parents[2] / "docs" / "drivers.md"


def test_docs_hold_the_registry_table():
    text = DOCS.read_text()
    table = re.search(
        r"<!-- input-formats: begin -->\n(.*?)<!-- input-formats: end -->", text, re.S
    )
    assert table is not None and table.group(1) == markdown_table()
    for name in input_format_names():
        assert f"| `{name}` |" in table.group(1)


def test_unknown_format_and_foreign_options_are_named():
    with pytest.raises(DriverInputError, match="known: kvh-a, kvh-b, kvh-c, xsens-text, csv"):
        get_input_format("nmea")
    with pytest.raises(DriverInputError, match="header does not apply to format kvh-b"):
        check_options("kvh-b", {"header": "t,ax"})
    with pytest.raises(DriverInputError, match="format csv has no option 'gyro_min'"):
        get_input_format("csv").make_parser(gyro_min=0)


def test_the_csv_parser_gives_batches_from_whole_lines():
    parser = get_input_format("csv").make_parser(columns="accel_x=ax,accel_y=ay,accel_z=az",
                                                 rate_hz=10.0, header="ax,ay,az")  # fmt: skip
    batch = parser.feed(b"0,0,1\n0,0,1.5\n")
    assert len(batch) == 2 and batch.time_s.tolist() == [0.0, 0.1]
    assert batch.accel_g[1].tolist() == [0, 0, 1.5] and batch.gyro_dph.tolist() == [[0, 0, 0]] * 2
    assert parser.triads == ("accel",)
