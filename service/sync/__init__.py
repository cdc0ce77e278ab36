"""Fleet sync, the vessel side (docs/fleet.md): the daemon's thread that sends the outbox to
the shore service.

- :mod:`~service.sync.batch`: the next batch from the outbox, in the wire format, gzip;
- :mod:`~service.sync.client`: the HTTP link (``POST /fleet/ingest``, timeouts, abort);
- :mod:`~service.sync.loop`: :class:`SyncThread`, the loop with its back-off;
- :mod:`~service.sync.stats`: the ``sync`` block of ``/health`` and the traffic per day.

The outbox itself is the Store's (:mod:`service.store.outbox`).
"""

from __future__ import annotations

from service.sync.loop import SyncThread
from service.sync.stats import off_block

__all__ = ["SyncThread", "off_block"]
