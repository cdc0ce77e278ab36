"""Supervised jobs: each recalibration runs in a fresh worker process, watched from one thread.

A process pool was the first design, and it failed the way a vessel fails it: a worker killed by
the OOM killer left either a future that never completed or a pool that refused all later work,
and nothing noticed. Here every job gets its own process (forked from a fork server that has the engine imported)
and a pipe for its result. One
long-lived supervisor thread starts the processes and watches them, and reports exactly one
:class:`JobEnd` per job:

* the result arrived: ``ok``;
* the function raised: ``error`` with the exception in one line;
* the process died without a result (killed, out of memory, crashed): ``died`` with the exit
  code or signal;
* it ran past ``timeout_s``: it is killed (its whole process group) and reported ``timeout``;
* :meth:`JobRunner.cancel` (shutdown): killed and reported ``cancelled``.

The worker ignores SIGINT and SIGTERM (a Ctrl-C or a ``systemctl stop`` reaches the whole
process group; the daemon decides how a job ends). It leads a process group of its own, which
its children (the swarm's forked workers) join, and a watcher thread in it kills that whole group
as soon as the daemon is gone, so nothing outlives a ``kill -9`` of the daemon. (The kernel's
``PR_SET_PDEATHSIG`` would kill the worker alone and orphan its children.)
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import queue
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

log = logging.getLogger("recal.jobs")

#: How often the worker checks that the daemon still lives, s.
PARENT_CHECK_S = 0.25
#: How often the supervisor looks at a running job, s (also the latency of a result).
POLL_S = 0.1
#: Least interval between two progress messages of a worker, s.
PROGRESS_EVERY_S = 0.5


@dataclass(frozen=True)
class JobEnd:
    """How a job ended. ``status``: ok, error, died, timeout or cancelled."""

    job: int
    status: str
    result: Any = None
    message: str = ""
    duration_s: float = 0.0

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's (the pid was reused): not ours any more
        return False
    return True


def die_with_parent(parent: int) -> None:
    """In a child process: kill this process's whole group as soon as ``parent`` (the pid of
    the daemon that asked for it) is gone, or this process's parent changes (its fork server
    exited with the daemon), which is at once if either died while this one was starting up.

    Call it in a process that leads its own group (``os.setpgid(0, 0)``) so that the group is
    the job and its children, nothing else.
    """

    # Forked by the daemon's fork server, this process's parent is that server, which exits
    # when the daemon does: either the parent changing or the daemon's pid going away ends it.
    first = os.getppid()

    def watch() -> None:
        while os.getppid() == first and _alive(parent):
            time.sleep(PARENT_CHECK_S)
        os.killpg(0, signal.SIGKILL)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


_PROGRESS_CONN: Any = None  # in a worker: the pipe to the supervisor
_PROGRESS_SENT = [0.0]  # monotonic time of the last progress message


def report_progress(done: float, total: float) -> None:
    """From a job function: ``done`` of ``total`` units (Monte Carlo runs) are finished. Sent to
    the supervisor at most every :data:`PROGRESS_EVERY_S` (and at completion); a no-op outside a
    worker. :meth:`JobRunner.progress` then shows it."""
    now = time.monotonic()
    if _PROGRESS_CONN is None or (now - _PROGRESS_SENT[0] < PROGRESS_EVERY_S and done < total):
        return
    _PROGRESS_SENT[0] = now
    try:
        _PROGRESS_CONN.send(("progress", (float(done), float(total))))
    except (OSError, ValueError):  # the supervisor is gone: the parent watch ends this process
        pass


def _worker_main(conn: Any, fn: Callable[..., Any], args: tuple[Any, ...], parent: int) -> None:
    global _PROGRESS_CONN
    os.setpgid(0, 0)  # the job's own group: the supervisor kills it whole (swarm children too)
    _PROGRESS_CONN = conn
    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        result = fn(*args)
    except BaseException as exc:  # noqa: BLE001 - reported to the daemon, not raised here
        first = str(exc).splitlines()[0] if str(exc) else ""
        conn.send(("error", f"{type(exc).__name__}: {first}".rstrip(": ")))
    else:
        conn.send(("ok", result))
    conn.close()


@dataclass
class _Running:
    job: int
    process: Any
    conn: Any
    started: float
    deadline: float
    on_end: Callable[[JobEnd], None]
    done: tuple[float, float] | None = None  # (done, total) last reported by the worker


#: Modules the fork server imports once for every job worker (service.job_server: the
#: recalibration job's modules, and SIGTERM/SIGINT ignored so a group-wide stop cannot kill the
#: server under a job that is starting).
WORKER_PRELOAD = ("service.job_server",)


class JobRunner:
    """Runs one job at a time in its own process; see the module docstring."""

    def __init__(self, timeout_s: float = 1800.0, start_method: str = "forkserver") -> None:
        self.timeout_s = float(timeout_s)
        self._ctx = multiprocessing.get_context(start_method)
        if start_method == "forkserver":
            # A fresh interpreter per job (spawn) imported numpy, scipy and the engine every
            # time: about 2 s of CPU before the job's first step. The fork server imports them
            # once and forks each worker from that clean, single-threaded process, so a worker
            # is still fresh (no daemon threads or locks inherited) and starts in milliseconds.
            # It exits when the daemon does (its pipe from the daemon closes).
            self._ctx.set_forkserver_preload(list(WORKER_PRELOAD))
        self._requests: queue.Queue[tuple[int, Callable[..., Any], tuple, Callable] | None] = (
            queue.Queue()
        )
        self._lock = threading.Lock()
        self._running: _Running | None = None
        self._queued = 0  # submitted, not yet started
        self._cancel: str | None = None
        self._ending = False  # on_end of the running job is being called (it may chain a job)
        self._jobs = 0
        self._closed = False
        self._stopping = False  # shutdown has begun: the running job may finish, none starts
        self.last_beat = time.monotonic()  # the supervisor's heartbeat (health, watchdog)
        self._thread = threading.Thread(target=self._supervise, name="job-supervisor", daemon=True)
        self._thread.start()

    # ---- public ---------------------------------------------------------------------------
    @property
    def busy(self) -> bool:
        with self._lock:
            return self._running is not None or self._queued > 0

    @property
    def alive(self) -> bool:
        """The supervisor thread runs and has looked at its job within the last few seconds."""
        return self._thread.is_alive() and time.monotonic() - self.last_beat < 5.0

    def running_for_s(self) -> float | None:
        with self._lock:
            r = self._running
            return None if r is None else time.monotonic() - r.started

    def progress(self) -> dict[str, Any] | None:
        """The running job: {"job", "elapsed_s", "timeout_s", "done", "total"} (done/total as
        the worker last reported them, :func:`report_progress`; None before any), or None."""
        with self._lock:
            r = self._running
            if r is None:
                return None
            done, total = r.done if r.done is not None else (None, None)
            return {"job": r.job, "elapsed_s": round(time.monotonic() - r.started, 1),
                    "timeout_s": self.timeout_s, "done": done, "total": total}  # fmt: skip

    def submit(
        self, fn: Callable[..., Any], args: tuple[Any, ...], on_end: Callable[[JobEnd], None]
    ) -> int:
        """Start ``fn(*args)`` in a new worker process; ``on_end`` is called once, from the
        supervisor thread, when it ends. Raises RuntimeError when busy or closed."""
        with self._lock:
            if self._closed or self._stopping:
                # not even a job chained by the end of the last one: it would be killed at once
                raise RuntimeError("the service is stopping: no new job starts")
            # a job stays "running" until its end is handled (stored, published), so nothing
            # starts from a stale prior; only its own end handler may chain the next one
            chaining = self._ending and threading.current_thread() is self._thread
            if (self._running is not None and not chaining) or self._queued:
                raise RuntimeError("a job is already running")
            self._jobs += 1
            self._queued += 1
            self._cancel = None
            job = self._jobs
        self._requests.put((job, fn, args, on_end))
        return job

    def cancel(self, reason: str = "cancelled") -> None:
        """Kill the running job (if any); it ends with status ``cancelled``."""
        with self._lock:
            self._cancel = reason

    def stop_starting(self) -> None:
        """From now on :meth:`submit` refuses (shutdown has begun); a running job goes on."""
        with self._lock:
            self._stopping = True

    def shutdown(self, wait_s: float = 0.0) -> None:
        """Let the running job finish for up to ``wait_s``, then kill it; stop the supervisor."""
        deadline = time.monotonic() + max(0.0, wait_s)
        self.stop_starting()
        while self.busy and time.monotonic() < deadline:
            time.sleep(POLL_S)
        with self._lock:
            self._closed = True
            if self._running is not None or self._queued:
                self._cancel = "the service stopped before the job finished"
        self._requests.put(None)
        self._thread.join(timeout=10)
        r = self._running
        if r is not None:  # the supervisor did not get to it: never leave a worker behind
            self._reap(r)

    # ---- supervisor thread ------------------------------------------------------------------
    def _supervise(self) -> None:
        while True:
            self.last_beat = time.monotonic()
            r = self._running
            if r is None:
                try:
                    item = self._requests.get(timeout=1.0)
                except queue.Empty:
                    continue
                if item is None:
                    return
                self._start(*item)
                continue
            end = self._check(r)
            if end is not None:
                self._ending = True
                try:
                    r.on_end(end)
                except Exception:  # noqa: BLE001 - the supervisor must outlive a bad callback
                    log.exception("job %d: handling its end failed", r.job)
                finally:
                    with self._lock:
                        self._ending = False
                        self._running = None

    def _start(self, job: int, fn: Callable[..., Any], args: tuple, on_end: Callable) -> None:
        now = time.monotonic()
        with self._lock:
            cancelled = self._cancel
        if cancelled:
            self._unqueue()
            on_end(JobEnd(job, "cancelled", message=cancelled))
            return
        try:
            recv, send = self._ctx.Pipe(duplex=False)
            process = self._ctx.Process(
                target=_worker_main, args=(send, fn, args, os.getpid()), name=f"recal-job-{job}"
            )
            process.start()
            send.close()
        except Exception as exc:  # noqa: BLE001 - e.g. out of memory or process limits
            self._unqueue()
            on_end(JobEnd(job, "died", message=f"cannot start a worker: {exc}"))
            return
        with self._lock:  # queued until running: busy never reads False while a worker starts
            self._running = _Running(job, process, recv, now, now + self.timeout_s, on_end)
            self._queued -= 1

    def _unqueue(self) -> None:
        with self._lock:
            self._queued -= 1

    def _check(self, r: _Running) -> JobEnd | None:
        elapsed = time.monotonic() - r.started
        status = "progress"
        while status == "progress" and r.conn.poll(POLL_S):
            try:
                status, value = r.conn.recv()
            except (EOFError, OSError):  # the pipe closed: the worker died before answering
                return self._died(r, elapsed)
            except Exception as exc:  # noqa: BLE001 - a result that cannot be unpickled
                self._reap(r)
                return JobEnd(r.job, "error", message=f"unreadable job result: {exc}",
                              duration_s=elapsed)  # fmt: skip
            if status == "progress":
                with self._lock:
                    r.done = value
                continue
            self._reap(r, grace_s=5.0)
            if status == "ok":
                return JobEnd(r.job, "ok", result=value, duration_s=elapsed)
            return JobEnd(r.job, "error", message=str(value), duration_s=elapsed)
        if not r.process.is_alive():
            return self._died(r, elapsed)
        cancel = self._cancel_reason()
        if cancel:
            self._reap(r)
            return JobEnd(r.job, "cancelled", message=cancel, duration_s=elapsed)
        if time.monotonic() > r.deadline:
            self._reap(r)
            return JobEnd(r.job, "timeout", duration_s=elapsed,
                          message=f"ran longer than the job time limit ({self.timeout_s:g} s)")  # fmt: skip
        return None

    def _died(self, r: _Running, elapsed: float) -> JobEnd:
        r.process.join(5.0)
        code = r.process.exitcode
        self._reap(r)
        if code is not None and -code in (signal.SIGTERM, signal.SIGINT):
            # a running worker ignores both: this one was still starting when a stop signal
            # reached the whole process group (systemctl stop with KillMode=control-group)
            return JobEnd(r.job, "cancelled", duration_s=elapsed,
                          message=f"stopped by signal {-code} sent to the service's process "
                          "group while the worker was starting")  # fmt: skip
        how = f"signal {-code}" if code is not None and code < 0 else f"exit code {code}"
        cancel = self._cancel_reason()
        if cancel:  # shutdown (or cancel) reaped it first, e.g. while this thread was slow
            return JobEnd(r.job, "cancelled", message=f"{cancel} (the worker ended by {how})",
                          duration_s=elapsed)  # fmt: skip
        if code == -signal.SIGKILL:
            how += ": killed, by the kernel's out-of-memory killer or by an operator"
        return JobEnd(r.job, "died", message=f"the worker process died ({how})",
                      duration_s=elapsed)  # fmt: skip

    def _cancel_reason(self) -> str | None:
        """Why the running job must stop: cancelled, or the runner closed (a job started while
        :meth:`shutdown` looked, between leaving the queue and becoming the running one)."""
        with self._lock:
            if self._cancel is None and self._closed:
                self._cancel = "the service stopped before the job finished"
            return self._cancel

    def _reap(self, r: _Running, grace_s: float = 0.0) -> None:
        """Make sure the worker and its process group are gone, and close the pipe."""
        r.process.join(grace_s)
        pid = r.process.pid
        if pid is not None:
            try:
                os.killpg(pid, signal.SIGKILL)  # the worker leads its group (swarm children)
            except (ProcessLookupError, PermissionError):
                pass
            if r.process.is_alive():  # still starting up: it has no group of its own yet
                r.process.kill()
        r.process.join(5.0)
        r.conn.close()
