"""Any IMU log: ``recal positions LOG.csv --format csv`` and the streaming parser behind it."""

from __future__ import annotations

import numpy as np
import pytest

from drivers import CsvLogParser, DriverInputError, parse_column_map
from recal.model.positions import Positions
from recal.sim.session import simulate_session
from service.capture_sim import kvh_like_truth
from service.cli.main import main

HEADER = "time_s,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z,temperature_c"


@pytest.fixture(scope="module")
def session():
    return simulate_session(
        kvh_like_truth(3), "24", latitude_deg=50.0, rate_hz=200.0, window_s=10.0, slew_s=3.0,
        seed=2,
    )  # fmt: skip


def write_log(path, columns: dict[str, np.ndarray], delimiter: str = ",") -> None:
    names = list(columns)
    table = np.column_stack([columns[n] for n in names])
    np.savetxt(path, table, delimiter=delimiter, header=delimiter.join(names), comments="",
               fmt="%.12g")  # fmt: skip


def session_columns(s, gyro: bool = True, accel: bool = True) -> dict[str, np.ndarray]:
    cols = {"time_s": s.time_s}
    for on, name, values in (("gyro", gyro, s.gyro_out), ("accel", accel, s.accel_out)):
        if name:
            cols.update({f"{on}_{ax}": values[:, j] for j, ax in enumerate("xyz")})
    cols["temperature_c"] = s.temperature_c
    return cols


def run(capsys, *args) -> tuple[int, str]:
    rc = main(["positions", *map(str, args)])
    return rc, capsys.readouterr().err


# ---- the parser -------------------------------------------------------------------------------
def parse(data: bytes, sizes=None, **kw):
    parser = CsvLogParser(**kw)
    chunks = []
    if sizes is None:
        chunks.append(parser.feed(data))
    else:
        rng = np.random.default_rng(sizes)
        i = 0
        while i < len(data):
            n = int(rng.integers(1, 40))
            chunks.append(parser.feed(data[i : i + n]))
            i += n
    chunks.append(parser.flush())
    chunks = [c for c in chunks if c is not None]
    return parser, {
        k: np.concatenate([getattr(c, k) for c in chunks])
        for k in ("time_s", "gyro", "accel", "temperature_c")
        if getattr(chunks[0], k) is not None
    }


def test_any_chunking_gives_the_same_rows():
    rows = np.random.default_rng(0).normal(size=(300, 8))
    rows[:, 0] = np.arange(300) / 100.0
    text = HEADER + "\n" + "\n".join(",".join(f"{v:.17g}" for v in r) for r in rows)  # no final \n
    _, whole = parse(text.encode())
    _, pieces = parse(text.encode(), sizes=7)
    for k in whole:
        np.testing.assert_array_equal(whole[k], pieces[k])
    np.testing.assert_array_equal(whole["gyro"], rows[:, 1:4])
    np.testing.assert_array_equal(whole["temperature_c"], rows[:, 7])


def test_own_names_semicolons_bom_crlf_and_rate():
    data = "\ufeffacc_x;acc_y;acc_z;label\r\n1;2;3;a\r\n4;5;6;b\r\n".encode()
    mapping = parse_column_map("accel_x=acc_x, accel_y=acc_y,accel_z=acc_z")
    parser, got = parse(data, columns=mapping, rate_hz=50.0)
    assert parser.layout.triads == ("accel",) and not parser.layout.has_time
    np.testing.assert_array_equal(got["accel"], [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(got["time_s"], [0.0, 0.02])
    assert "gyro" not in got


@pytest.mark.parametrize(
    ("text", "kw", "needle"),
    [
        ("time_s,gyro_x,gyro_y\n0,1,2\n", {}, "missing column(s) gyro_z (2 of the 3 gyro axes"),
        ("time_s,temperature_c\n0,1\n", {}, "no gyro_x, gyro_y, gyro_z or accel_x"),
        ("gyro_x,gyro_y,gyro_z\n1,2,3\n", {}, "no time_s column; give the sample rate (--rate"),
        (
            HEADER + "\n0,1,2,3,4,5,6,7\n0.1,1,2,x3,4,5,6,7\n",
            {},
            "line 3, column 'gyro_z' is not a number: 'x3'",
        ),  # fmt: skip
        (HEADER + "\n0,1,2,3,4,5,6,7\n0.1,1,,3,4,5,6,7\n", {}, "line 3, column 'gyro_y' is empty"),
        (HEADER + "\n0,1,2,3,4,5,6,7\n0.1,1,2\n", {}, "line 3 has 3 fields, so no column 'gyro_z'"),
        (
            HEADER + "\n0,1,2,3,4,5,6,7\n0,1,2,3,4,5,6,7\n",
            {},
            "line 3, column 'time_s': time 0.0 s does not come after 0.0 s",
        ),  # fmt: skip
        (HEADER + "\n", {}, "has a header but no data rows"),
        ("", {}, "is empty"),
        (
            "t,gx,gy,gz\n0,1,2,3\n",
            {"columns": {"time_s": "time"}},
            "no column 'time' (mapped to time_s)",
        ),  # fmt: skip
        ("a,a,gyro_x\n", {}, "the header names a twice"),
    ],
)
def test_bad_logs_are_named_precisely(text, kw, needle):
    with pytest.raises(DriverInputError) as exc:
        parse(text.encode(), source="log.csv", **kw)
    assert needle in str(exc.value) and str(exc.value).startswith("log.csv")


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("accel_x", "expected NEW=OLD"),
        ("acc=acc_x", "'acc' is not one of time_s"),
        ("accel_x=a,accel_x=b", "mapped twice"),
    ],  # fmt: skip
)
def test_bad_column_maps(text, needle):
    with pytest.raises(DriverInputError, match=needle):
        parse_column_map(text)


# ---- the command ------------------------------------------------------------------------------
def test_log_from_a_simulated_session(session, tmp_path, capsys):
    log = tmp_path / "log.csv"
    write_log(log, session_columns(session))
    out = tmp_path / "pos.csv"
    rc, err = run(capsys, log, "--format", "csv", "-o", out)  # the flags section 8 shows
    assert rc == 0, err
    assert f"csv: {len(session)} rows of gyro and accel, temperature" in err and "24 kept" in err
    table = Positions.from_csv_text(out.read_text())
    assert len(table) == session.n_holds == 24
    holds = [slice(a, b + 1) for a, b in zip(session.hold_first, session.hold_last, strict=True)]
    true_accel = np.array([session.accel_out[h].mean(axis=0) for h in holds])
    np.testing.assert_allclose(table.accel, true_accel, atol=2e-5)
    assert {"temperature_c", "gyro_x_sem"} <= set(table.columns)
    assert main(["calibrate", str(out), "--latitude", "50"]) == 0


def test_accel_only_log_with_own_names_and_no_time(session, tmp_path, capsys):
    cols = session_columns(session, gyro=False)
    del cols["time_s"], cols["temperature_c"]
    log = tmp_path / "acc.csv"
    write_log(log, {f"acc_{k[-1]}": v for k, v in cols.items()}, delimiter=";")
    out = tmp_path / "pos.csv"
    columns = "accel_x=acc_x,accel_y=acc_y,accel_z=acc_z"
    rc, err = run(capsys, log, "--format", "csv", "--rate", "200", "--columns", columns, "-o", out)
    assert rc == 0, err
    assert "accel only (no gyro columns)" in err and "time from --rate 200 Hz" in err
    table = Positions.from_csv_text(out.read_text())
    assert len(table) == 24
    assert not [c for c in table.columns if c.startswith("gyro")]  # the absent triad is left out
    assert "temperature_c" not in table.columns
    assert main(["calibrate", str(out), "--latitude", "50", "--sensor", "accel"]) == 0


def test_gyro_only_log_finds_the_holds(session, tmp_path, capsys):
    """The missing accel is fed as zeros: its variance is 0, so the gyro alone decides."""
    log = tmp_path / "gyro.csv"
    write_log(log, session_columns(session, accel=False))
    out = tmp_path / "pos.csv"
    rc, err = run(capsys, log, "--format", "csv", "-o", out)
    assert rc == 0, err
    table = Positions.from_csv_text(out.read_text())
    assert len(table) == 24 and "accel_x" not in table.columns


@pytest.mark.parametrize(
    ("content", "args", "needle"),
    [
        ("time_s,accel_x,accel_y\n0,1,2\n", (), "missing column(s) accel_z"),
        ("time_s,gyro_x,gyro_y,gyro_z\n0,1,2,3\n0.01,1,2,oops\n", (), "line 3, column 'gyro_z'"),
        (
            "time_s,gyro_x,gyro_y,gyro_z\n0,1,2,3\n0.01,1,2,3\n0.005,1,2,3\n",
            (),
            "line 4, column 'time_s': time 0.005 s does not come after 0.01 s",
        ),  # fmt: skip
        ("gyro_x,gyro_y,gyro_z\n1,2,3\n", (), "no time_s column; give the sample rate"),
        (
            "a,b,c\n1,2,3\n",
            ("--columns", "gyro_x=a,gyro_y=b,gyro_z=d", "--rate", "10"),
            "no column 'd' (mapped to gyro_z)",
        ),  # fmt: skip
        ("gyro_x,gyro_y,gyro_z\n1,2,3\n", ("--rate", "-5"), "sample rate must be a positive"),
    ],
)
def test_bad_log_one_line_exit_2_nothing_written(tmp_path, capsys, content, args, needle):
    log = tmp_path / "log.csv"
    log.write_text(content)
    outdir = tmp_path / "out"
    outdir.mkdir()
    rc, err = run(capsys, log, "--format", "csv", *args, "-o", outdir / "p.csv")
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("recal positions: error: ")
    assert needle in err
    assert list(outdir.iterdir()) == []


def test_columns_flag_needs_csv(shared_data, tmp_path, capsys):
    rc, err = run(capsys, shared_data / "kvh_formatA_sample_frame.bin", "--format", "kvh-a",
                  "--columns", "accel_x=a", "-o", tmp_path / "p.csv")  # fmt: skip
    assert rc == 2 and "--columns applies to --format csv only" in err
