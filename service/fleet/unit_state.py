"""What ingest keeps on a unit's row (shore migrations 0007 and 0009): its current version
(number, time, instance) and the row ids of its newest rows, looked up again when a batch stores
versions or drift events (GET /fleet/units and service/fleet/overview.py read them; the link's
days are summed under ``service.store.codec.utc_day``)."""

from __future__ import annotations

from typing import Any

from sqlalchemy import select

from service.fleet.schema import EventRow, VersionRow


def newest_row(table: Any, unit_id: int, *where: Any, column: Any = None) -> Any:
    """The shore row id (or ``column``) of a unit's newest row of ``table`` matching ``where``:
    by time, then vessel row id (not row id alone: a rebuilt vessel's ids start at 1 again)."""
    return (
        select(table.id if column is None else column)
        .where(table.unit_id == unit_id, *where)
        .order_by(table.at.desc(), table.vessel_id.desc())
        .limit(1)
        .scalar_subquery()
    )


def newest_rows(unit_id: int, *, versions: bool, drift: bool) -> dict[str, Any]:
    """The unit's row ids the overview shows (migration 0009), looked up again when a batch
    stored versions or drift events: rows may arrive out of order (a backlog, another
    instance), so the newest is found, not assumed to be the one just stored."""
    out: dict[str, Any] = {}
    if versions:
        # the current version: the newest accepted by creation time, whichever instance made
        # it (a rebuilt vessel's version numbers start at 1 again); its number, time and
        # instance (migration 0007, GET /fleet/units) from the same row as its row id
        accepted = VersionRow.accepted.is_(True)
        out["current_row"] = newest_row(VersionRow, unit_id, accepted)
        for name, column in (("current_version", VersionRow.vessel_id),
                             ("current_at", VersionRow.at),
                             ("current_instance", VersionRow.instance)):  # fmt: skip
            out[name] = newest_row(VersionRow, unit_id, accepted, column=column)
        out["last_version_row"] = newest_row(VersionRow, unit_id)
        out["rejected_row"] = newest_row(VersionRow, unit_id, VersionRow.accepted.is_(False))
    if drift:
        out["drift_row"] = newest_row(EventRow, unit_id, EventRow.kind == "drift")
    return out
