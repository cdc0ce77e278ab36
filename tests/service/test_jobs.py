"""JobRunner: every way a job ends is reported once, and no worker outlives its job or daemon."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from service.jobs import JobEnd, JobRunner


def _ok(x: int) -> int:
    return 2 * x


def _raise() -> None:
    raise ValueError("bad design\nsecond line")


def _sleep(seconds: float) -> None:
    time.sleep(seconds)


def _sleep_with_child(seconds: float, pidfile: str) -> None:
    """A job that forks a helper (like the swarm's workers) and waits."""
    child = subprocess.Popen([sys.executable, "-c", f"import time; time.sleep({seconds})"])
    with open(pidfile, "w") as fh:
        fh.write(f"{os.getpid()} {child.pid}")
    time.sleep(seconds)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie still answers kill(0): look at its state
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _run(runner: JobRunner, fn, *args) -> JobEnd:
    done = threading.Event()
    ends: list[JobEnd] = []

    def on_end(end: JobEnd) -> None:
        ends.append(end)
        done.set()

    runner.submit(fn, args, on_end)
    assert done.wait(60), "the job never ended"
    assert len(ends) == 1
    return ends[0]


@pytest.fixture
def runner():
    r = JobRunner(timeout_s=30)
    yield r
    r.shutdown()


def test_result_error_and_the_next_job(runner: JobRunner) -> None:
    end = _run(runner, _ok, 21)
    assert end.ok and end.result == 42 and end.job == 1
    end = _run(runner, _raise)
    assert end.status == "error" and end.message == "ValueError: bad design"
    assert _run(runner, _ok, 1).result == 2  # still usable


def test_busy_while_a_job_runs(runner: JobRunner) -> None:
    runner.submit(_sleep, (1.0,), lambda end: None)
    assert runner.busy
    with pytest.raises(RuntimeError, match="already running"):
        runner.submit(_ok, (1,), lambda end: None)


def test_a_killed_worker_is_reported_and_the_runner_recovers(runner: JobRunner) -> None:
    done = threading.Event()
    ends: list[JobEnd] = []
    runner.submit(_sleep, (60.0,), lambda end: (ends.append(end), done.set()))
    deadline = time.monotonic() + 30
    while runner._running is None or runner._running.process.pid is None:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    os.kill(runner._running.process.pid, signal.SIGKILL)  # the OOM killer's way
    assert done.wait(30)
    assert ends[0].status == "died" and "signal 9" in ends[0].message
    assert not runner.busy
    assert _run(runner, _ok, 5).result == 10


def test_timeout_kills_the_job_and_its_children(tmp_path) -> None:
    runner = JobRunner(timeout_s=3.0)
    pidfile = tmp_path / "pids"
    try:
        end = _run(runner, _sleep_with_child, 120.0, str(pidfile))
    finally:
        runner.shutdown()
    assert end.status == "timeout" and "3 s" in end.message
    worker, child = map(int, pidfile.read_text().split())
    time.sleep(0.2)
    assert not _alive(worker) and not _alive(child)


def test_shutdown_waits_then_cancels(tmp_path) -> None:
    runner = JobRunner(timeout_s=60)
    ends: list[JobEnd] = []
    runner.submit(_sleep, (0.5,), ends.append)
    runner.shutdown(wait_s=10)  # a short job finishes
    assert [e.status for e in ends] == ["ok"]
    runner = JobRunner(timeout_s=60)
    ends = []
    runner.submit(_sleep, (60.0,), ends.append)
    t0 = time.monotonic()
    runner.shutdown(wait_s=0.5)  # a long one is abandoned
    assert time.monotonic() - t0 < 10
    assert [e.status for e in ends] == ["cancelled"]
    assert "stopped" in ends[0].message
    with pytest.raises(RuntimeError, match="stopping"):
        runner.submit(_ok, (1,), ends.append)


def test_a_job_ending_during_shutdown_chains_nothing() -> None:
    """The end of the last job may try to chain the next one (new windows arrived): once the
    service is stopping that is refused, not started and then killed as 'died'."""
    runner = JobRunner(timeout_s=60)
    ends: list[JobEnd] = []
    chained: list[str] = []

    def on_end(end: JobEnd) -> None:
        ends.append(end)
        try:
            runner.submit(_sleep, (30.0,), ends.append)
        except RuntimeError as exc:
            chained.append(str(exc))

    runner.submit(_sleep, (0.5,), on_end)
    t0 = time.monotonic()
    runner.shutdown(wait_s=10)
    assert time.monotonic() - t0 < 10
    assert [e.status for e in ends] == ["ok"]
    assert chained == ["the service is stopping: no new job starts"]


def test_no_worker_outlives_a_killed_daemon(tmp_path) -> None:
    """kill -9 of the process that owns the runner: its worker (and the worker's children)
    die with it (PR_SET_PDEATHSIG plus the worker's process group)."""
    pidfile = tmp_path / "pids"
    script = tmp_path / "owner.py"  # a file: spawned workers re-import their main module
    script.write_text(
        textwrap.dedent(
            f"""
            import os, subprocess, sys, time
            from service.jobs import JobRunner

            def job(seconds, pidfile):
                child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(300)"])
                with open(pidfile, "w") as fh:
                    fh.write(f"{{os.getpid()}} {{child.pid}}")
                time.sleep(seconds)

            if __name__ == "__main__":
                r = JobRunner(timeout_s=600)
                r.submit(job, (300.0, {str(pidfile)!r}), lambda end: None)
                time.sleep(300)
            """
        )
    )
    owner = subprocess.Popen([sys.executable, str(script)], cwd=os.getcwd())
    try:
        deadline = time.monotonic() + 60
        while not pidfile.exists() or len(pidfile.read_text().split()) < 2:
            assert time.monotonic() < deadline, "the job did not start"
            time.sleep(0.1)
        worker, child = map(int, pidfile.read_text().split())
        assert _alive(worker) and _alive(child)
        owner.kill()
        owner.wait(10)
        deadline = time.monotonic() + 10
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(worker)
        while _alive(child) and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        if owner.poll() is None:
            owner.kill()
    assert not _alive(child), "a job's child process outlived the daemon"


def test_busy_until_the_end_is_handled_and_the_handler_may_chain(runner: JobRunner) -> None:
    seen: list[bool] = []
    chained: list[JobEnd] = []
    done = threading.Event()

    def first_end(end: JobEnd) -> None:
        seen.append(runner.busy)  # storing the result: a trigger now must wait
        refused: list[Exception] = []

        def other() -> None:
            try:
                runner.submit(_ok, (1,), print)
            except RuntimeError as exc:
                refused.append(exc)

        t = threading.Thread(target=other)
        t.start()
        t.join()
        seen.append(bool(refused))
        runner.submit(_ok, (3,), lambda e: (chained.append(e), done.set()))  # the chain

    runner.submit(_ok, (1,), first_end)
    assert done.wait(60)
    assert seen == [True, True] and chained[0].result == 6


def test_cancel_right_after_start_leaves_no_worker() -> None:
    """A job cancelled while its worker is still starting (before it has a process group)."""
    for _ in range(3):
        runner = JobRunner(timeout_s=60)
        ends: list[JobEnd] = []
        runner.submit(_sleep, (60.0,), ends.append)
        deadline = time.monotonic() + 30
        while runner._running is None:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        process = runner._running.process
        runner.shutdown(wait_s=0)
        assert [e.status for e in ends] == ["cancelled"]
        assert not process.is_alive()


def test_a_stop_signal_to_a_starting_worker_does_not_end_it(runner: JobRunner) -> None:
    """A group SIGTERM (systemctl stop) reaches the workers too. Forked from the fork server,
    which ignores it (service.job_server), a worker ignores it from its first instruction, so
    even one still starting up is not killed by it: the daemon decides how a job ends (at
    shutdown it cancels the job, service/test_supervision.py)."""
    done = threading.Event()
    ends: list[JobEnd] = []
    runner.submit(_sleep, (0.5,), lambda end: (ends.append(end), done.set()))
    while runner._running is None:
        time.sleep(0.001)
    os.kill(runner._running.process.pid, signal.SIGTERM)  # at once: it is still starting
    assert done.wait(30)
    assert ends[0].status == "ok", ends[0]
