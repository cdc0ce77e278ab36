"""Imported once, by the job fork server alone (``service.jobs.WORKER_PRELOAD``): it makes the
server ignore SIGTERM and SIGINT, as the job workers do.

``systemctl stop`` (KillMode=control-group) or a Ctrl-C signals every process of the daemon's
group, the fork server included. Had the server died then, a job starting during the shutdown
would fail with a broken pipe instead of being cancelled by the daemon. It still exits with the
daemon: its pipe from the daemon closes. It also imports the recalibration job's modules, so
that each worker forked from it starts with the engine loaded.
"""

from __future__ import annotations

import signal

# first: a group-wide stop may come while the engine below is still being imported (seconds)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
signal.signal(signal.SIGINT, signal.SIG_IGN)

import service.recalibration  # noqa: E402, F401 - loaded once here, for every worker forked after
