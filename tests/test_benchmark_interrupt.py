"""A benchmark that starts daemons stops them when it is interrupted or times out (issue 38).

Each benchmark runs with a marker in its environment, which every process it starts inherits;
once its daemon answers, the benchmark gets SIGTERM (what ``timeout`` and a CI cancel send), and
afterwards no process carrying the marker may be left (a daemon started in its own session is
not in the benchmark's process group, so only the environment finds it).
"""

from __future__ import annotations

import os
import secrets
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MARK = "RECAL_BENCH_INTERRUPT_MARK"


def _marked(mark: str) -> dict[int, str]:
    """pid -> command line of every process whose environment carries ``mark``."""
    out = {}
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            env = (proc / "environ").read_bytes()
            cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # gone meanwhile, or not ours
            continue
        if f"{MARK}={mark}".encode() in env.split(b"\0"):
            out[int(proc.name)] = cmd
    return out


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs Linux's /proc")
@pytest.mark.parametrize(
    ("script", "args", "daemon"),
    [
        ("fault_sync.py", ["--runs", "3", "--victims", "vessel"], "service.cli.main serve"),
        ("fault_injection.py", ["--runs", "3", "--cases", "outage"], "service.cli.main serve"),
    ],
)
def test_sigterm_stops_the_daemons_the_benchmark_started(
    script: str, args: list[str], daemon: str
) -> None:
    mark = secrets.token_hex(8)
    bench = subprocess.Popen(
        [sys.executable, str(ROOT / "benchmarks" / script), *args],
        env={**os.environ, MARK: mark}, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, start_new_session=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not any(daemon in cmd for cmd in _marked(mark).values()):
            assert bench.poll() is None, f"{script} ended before its daemon started"
            assert time.monotonic() < deadline, f"{script} started no {daemon!r} in 120 s"
            time.sleep(0.2)
        time.sleep(1.0)  # the daemon at work
        bench.send_signal(signal.SIGTERM)
        out, _ = bench.communicate(timeout=90)
        deadline = time.monotonic() + 10
        while (left := _marked(mark)) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not left, f"{script} left running after SIGTERM: {left}\n{out[-2000:]}"
        assert "interrupted" in out, out[-2000:]
    finally:
        for pid in _marked(mark):
            os.kill(pid, signal.SIGKILL)
        if bench.poll() is None:
            bench.kill()
