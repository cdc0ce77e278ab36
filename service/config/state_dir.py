"""The state directory: where the daemon keeps the files whose own setting is unset."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path


def default_state_dir(environ: Mapping[str, str] | None = None) -> Path:
    """Where the daemon keeps its files when ``state_dir`` is unset: ``$STATE_DIRECTORY`` (the
    first, if several: systemd sets it from the unit's ``StateDirectory=``), else the user's
    state folder, ``$XDG_STATE_HOME/recal`` (an absolute ``XDG_STATE_HOME`` only, as the XDG
    base directory specification says) or ``~/.local/state/recal``. A user-level default keeps
    a hand-started daemon's database and spool in one known place, whatever folder it was
    started from."""
    env = os.environ if environ is None else environ
    systemd = env.get("STATE_DIRECTORY", "").split(":")[0]
    if systemd:
        return Path(systemd)
    xdg = env.get("XDG_STATE_HOME", "")
    if xdg and os.path.isabs(xdg):
        return Path(xdg) / "recal"
    return Path.home() / ".local" / "state" / "recal"
