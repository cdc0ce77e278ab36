"""One registry of input formats (drivers.registry): a toy format registered here is read by
``recal positions`` and served by the daemon; the daemon serves a CSV line stream made from the
real Xsens MEMS recording and stores its windows in SQLite."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from drivers import FrameBatch, FrameReader, LineSplitter, replay_url
from drivers.registry import (
    FormatOption,
    InputFormat,
    get_input_format,
    input_format_names,
    register,
    unregister,
)
from service.cli.main import main
from service.config import DetectorSettings, DeviceSettings, SchedulerSettings, Settings
from service.daemon import build_service
from service.store.repository import Store

ACC, GYRO = "xsens_static_poses_acc.txt", "xsens_static_poses_gyro.txt"
RATE = 100.0  # Hz, the Xsens recording's


# ---- the toy format: "T <t>|<ax> <ay> <az>|<gx> <gy> <gz>" lines, with a scale option --------
class ToyParser:
    """Whole lines in, FrameBatch out; ``scale`` multiplies every sample."""

    triads = ("gyro", "accel")
    has_temperature = False
    gyro_limits = None
    byte_rate = None

    def __init__(self, name: str, source: str = "<toy>", scale: float = 1.0) -> None:
        from drivers.frames import DecoderCounters

        self.name, self.scale, self.sample_rate_hz = name, scale, None
        self.counters = DecoderCounters()

    def feed(self, data: bytes, host_time: float = float("nan"), part: int = 0) -> FrameBatch:
        rows = [line.split("|") for line in data.decode().splitlines() if line.startswith("T ")]
        self.counters.frames += len(rows)
        if not rows:
            return FrameBatch.empty(self.name)
        t = np.array([float(r[0][2:]) for r in rows])
        accel = np.array([r[1].split() for r in rows], float) * self.scale
        gyro = np.array([r[2].split() for r in rows], float) * self.scale
        return FrameBatch.from_samples(self.name, t, gyro, accel, host_time=host_time)

    def flush(self, host_time: float = float("nan")) -> FrameBatch:
        return FrameBatch.empty(self.name)

    def finish(self) -> None:
        pass

    def notes(self) -> list[str]:
        return [f"toy: {self.counters.frames} lines"]


TOY = InputFormat(
    "toy-lines",
    "a toy line format registered by a test",
    "lines",
    ToyParser,
    (FormatOption("scale", "multiplies every sample", float, flag="--scale"),),
)


@pytest.fixture
def toy():
    register(TOY)
    yield TOY
    unregister(TOY.name)


@pytest.fixture(scope="module")
def xsens(shared_data) -> np.ndarray:
    """The real MEMS recording: (N, 7) time_s, accel x y z, gyro x y z (raw counts)."""
    acc = np.loadtxt(shared_data / ACC)
    gyro = np.loadtxt(shared_data / GYRO)
    assert np.array_equal(acc[:, 0], gyro[:, 0])
    return np.column_stack([acc, gyro[:, 1:]])


def toy_text(rows: np.ndarray) -> str:
    return "".join(
        f"T {r[0]:.6f}|{r[1]:g} {r[2]:g} {r[3]:g}|{r[4]:g} {r[5]:g} {r[6]:g}\n" for r in rows
    )


def csv_text(rows: np.ndarray, header: bool = True) -> str:
    """A CSV line stream with the logger's own names (mapped back with ``columns``)."""
    head = "t,ax,ay,az,gx,gy,gz\n" if header else ""
    return head + "".join(",".join(f"{v:.9g}" for v in r) + "\n" for r in rows)


COLUMNS = "time_s=t,accel_x=ax,accel_y=ay,accel_z=az,gyro_x=gx,gyro_y=gy,gyro_z=gz"


def serve_replay(tmp_path: Path, device: DeviceSettings, n_frames: int) -> tuple[int, dict]:
    """Build the daemon from settings, let its reader play the file to the end, close it (the
    open window is stored); returns (windows stored in SQLite, reader health as a dict)."""
    db = tmp_path / "recal.db"
    settings = Settings(
        database_url=f"sqlite:///{db}",
        publish_path=str(tmp_path / "c.json"),
        device=device,
        detector=DetectorSettings(init_still_s=50),
        scheduler=SchedulerSettings(min_positions=1000, min_new_positions=1000),
    )
    service = build_service(settings)
    try:
        service.reader.start()
        deadline = time.monotonic() + 120
        while service.ingest.frames < n_frames:
            assert time.monotonic() < deadline, f"{service.ingest.frames} of {n_frames} frames"
            assert service.reader.health().running, service.reader.health().last_error
            time.sleep(0.1)
        health = service.health()["reader"]
    finally:
        service.close(wait_s=0)
    store = Store(f"sqlite:///{db}")
    try:
        return store.count_positions(), health
    finally:
        store.close()


# ---- the registry is the one list -------------------------------------------------------------
def test_cli_choices_and_config_follow_the_registry(toy, capsys):
    assert "toy-lines" in input_format_names()
    with pytest.raises(SystemExit):
        main(["positions", "--help"])
    out = capsys.readouterr().out
    for fmt in input_format_names():
        assert fmt in out
    assert "a toy line format registered by a test" in " ".join(out.split())
    assert DeviceSettings(format="toy-lines").format == "toy-lines"
    with pytest.raises(ValueError, match="known: kvh-a, kvh-b, kvh-c, xsens-text, csv, toy"):
        DeviceSettings(format="nmea")
    with pytest.raises(ValueError, match="columns does not apply to format kvh-a"):
        DeviceSettings(format="kvh-a", columns="accel_x=ax")


def test_a_toy_format_is_read_by_positions_and_served_by_the_daemon(toy, xsens, tmp_path, capsys):
    path = tmp_path / "rec.toy"
    path.write_text(toy_text(xsens))
    out = tmp_path / "toy.csv"
    rc = main(["positions", str(path), "--format", "toy-lines", "--scale", "2",
               "--init-still", "50", "--no-slews", "-o", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 0, err
    assert f"toy: {len(xsens)} lines" in err
    header, *rows = out.read_text().splitlines()
    assert len(rows) == 38  # the recording's poses (tests/test_cli_positions.py)
    accel_x = [float(r.split(",")[header.split(",").index("accel_x")]) for r in rows]
    assert min(np.abs(accel_x)) > 2 * 2e4  # the scale option reached the parser (counts x 2)

    rc = main(["positions", str(path), "--format", "toy-lines", "--columns", "a=b", "-o",
               str(tmp_path / "x.csv")])  # fmt: skip
    assert rc == 2 and "--columns applies to --format csv only" in capsys.readouterr().err

    device = DeviceSettings(url=replay_url(path, speed="max"), format="toy-lines", rate_hz=RATE)
    stored, health = serve_replay(tmp_path, device, len(xsens))
    assert stored >= 30, health  # the daemon's detector runs live, with its own defaults
    assert health["counters"]["frames"] == len(xsens)


def test_the_daemon_serves_a_csv_line_stream_of_the_real_mems_recording(xsens, tmp_path):
    path = tmp_path / "mems.csv"
    path.write_text(csv_text(xsens))
    # small random reads: lines are cut anywhere and carried across reads
    url = replay_url(path, speed="max", chunk="random", chunk_max=700, seed=3)
    device = DeviceSettings(url=url, format="csv", columns=COLUMNS, rate_hz=RATE)
    stored, health = serve_replay(tmp_path, device, len(xsens))
    assert stored >= 30, health
    assert health["counters"]["frames"] == len(xsens) and health["diagnosis"] is None


def test_a_csv_stream_joined_after_its_header_uses_the_configured_one(xsens, tmp_path):
    """The stream starts mid-line (a port opened mid-stream): that line is skipped, counted."""
    text = csv_text(xsens, header=False)
    path = tmp_path / "joined.csv"
    path.write_text(text[text.index("\n") // 2 :])
    got: list[FrameBatch] = []
    reader = FrameReader(replay_url(path, speed="max", chunk=333), "csv", on_batch=got.append,
                         options={"columns": COLUMNS, "header": "t,ax,ay,az,gx,gy,gz"})  # fmt: skip
    with reader:
        deadline = time.monotonic() + 60
        while sum(map(len, got)) < len(xsens) - 1 and time.monotonic() < deadline:
            time.sleep(0.05)
    batch = FrameBatch.concat(got)
    assert len(batch) == len(xsens) - 1
    np.testing.assert_allclose(batch.accel_g, xsens[1:, 1:4])
    np.testing.assert_allclose(batch.gyro_dph, xsens[1:, 4:7])
    assert reader.lines_skipped == 1 and "line" in reader.health().diagnosis


def test_line_splitter_carries_partial_lines():
    s = LineSplitter()
    assert s.feed(b"a,b\n1,") == b"a,b\n"
    assert s.feed(b"2\n3") == b"1,2\n"
    assert s.pending == 1 and s.flush() == b"3"


def test_xsens_saturation_limits_are_options():
    fmt = get_input_format("xsens-text")
    assert fmt.make_parser(source=("a", "g")).gyro_limits == (0.0, 65535.0)
    assert fmt.make_parser(source=("a", "g"), gyro_min=-32768, gyro_max=32767).gyro_limits == (
        -32768.0,
        32767.0,
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_csv_config_with_require_verdict_full_starts(xsens, tmp_path):
    """``recal serve`` with [device] format = "csv" and [gate] require_verdict = "full"."""
    path = tmp_path / "mems.csv"
    path.write_text(csv_text(xsens))
    port = _free_port()
    config = tmp_path / "recal.toml"
    config.write_text(
        f'database_url = "sqlite:///{tmp_path / "r.db"}"\npublish_path = "{tmp_path / "c.json"}"\n'
        f'[device]\nurl = "{replay_url(path, speed="max")}"\nformat = "csv"\n'
        f'columns = "{COLUMNS}"\nrate_hz = {RATE}\n'
        "[detector]\ninit_still_s = 50\n"
        "[scheduler]\nmin_positions = 1000\n"
        f'[gate]\nrequire_verdict = "full"\n[api]\nport = {port}\n'
    )
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "serve", "--config", str(config)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        health = None
        while (
            health is None or health["service"]["frames"] < len(xsens) or health["positions"] < 30
        ):
            assert proc.poll() is None, proc.communicate()[1]
            assert time.monotonic() < deadline, health
            time.sleep(0.5)
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=5) as r:
                    health = json.load(r)
            except OSError:
                continue
        assert health["service"]["reader"]["diagnosis"] is None
        os.killpg(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
        assert "internal error" not in err
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
