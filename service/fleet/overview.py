"""What the fleet manager sees: one row per unit (``GET /fleet/overview``) and fleet totals.

A row is built from what the vessels sent (docs/fleet.md): the versions (the current one is
the newest accepted; its age, its gyrocompass heading error from its document's
``navigation.after``), the rejected ones (their count, the last one's reasons), the last
version's trigger, the unit's latest ``drift`` event (service/scheduler.py: ``alarm_window``
set means drift was declared against ``version``), the ingest log (last contact, bytes per day
over the last 7 days, the backlog the vessel last reported) and its model's fleet prior (is the
unit an outlier). Units that need a person come first (``attention``): a rejected last
version, drift declared against the current version, an outlier of its model, a stale link.

The whole overview is two SQL statements (and the priors'), whatever the number of units, and
none reads a version's document or looks a unit's newest rows up: ingest keeps on the unit's
row its counts, the backlog of its newest batch and the row ids of its current, newest and
newest rejected version and of its newest drift event (migration 0009); what a version shows
(the heading error, the reasons) is kept in narrow columns of its row (migration 0008); and
the link is per unit and UTC day in ``fleet_link_days``, summed by ingest. So one statement
joins the units to those rows by primary key, and the other reads 7 link rows a unit
(docs/fleet.md#scale: 0.99 s p95 at 1000 units x 5 years reading two 30 kB documents a unit,
0.40 s with 0008's columns and per-unit lookups). "Newest" is by time, not by vessel row id: a
vessel whose database was made again (another ``instance``) numbers its rows from 1 again.
Conflicts (rows received whose key was stored with other content, docs/fleet.md) are counted
on the unit's row and need a person.
"""

from __future__ import annotations

from collections import defaultdict
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import aliased

from service.fleet.priors import FleetPriors
from service.fleet.schema import EventRow, LinkDayRow, UnitRow, VersionRow
from service.fleet.store import FleetStore, iso_time
from service.store.codec import utc_day

#: Days of traffic in a row's ``bytes_per_day``.
LINK_DAYS = 7
#: A unit not heard from for longer is ``stale`` (hours).
STALE_HOURS = 48.0
#: The order of ``attention`` (and of the rows: the first reason ranks a unit).
ATTENTION = ("rejected", "drift", "outlier", "conflicts", "stale", "never")


def overview(
    store: FleetStore,
    priors: FleetPriors,
    only: int | None = None,
    now: datetime | None = None,
) -> dict[str, Any]:
    """``{"units": [row, ...], "totals": {...}, "models": {...}, "generated_at"}`` (rows in
    order of attention, then serial); ``only``: one unit's id (a unit's token)."""
    now = now or datetime.now(UTC)
    unit_filter = [] if only is None else [UnitRow.id == only]

    # 1. each unit with its counts and the rows it shows, by the row ids ingest keeps on the
    #    unit's row (migration 0009): its current (newest accepted), newest and newest
    #    rejected version and its newest drift evaluation
    cur, last, rej = (aliased(VersionRow) for _ in range(3))
    q_units = (
        select(
            UnitRow.id, UnitRow.serial, UnitRow.model, UnitRow.instance, UnitRow.last_contact,
            UnitRow.n_versions, UnitRow.n_rejected, UnitRow.n_windows, UnitRow.n_conflicts,
            UnitRow.backlog,
            cur.vessel_id, cur.at, cur.heading_error_deg_rms, cur.trigger, cur.instance,
            last.vessel_id, last.at, last.trigger, last.accepted,
            rej.vessel_id, rej.at, rej.reasons,
            EventRow.at, EventRow.instance, EventRow.data["data"],
        )
        .outerjoin(cur, cur.id == UnitRow.current_row)
        .outerjoin(last, last.id == UnitRow.last_version_row)
        .outerjoin(rej, rej.id == UnitRow.rejected_row)
        .outerjoin(EventRow, EventRow.id == UnitRow.drift_row)
        .where(*unit_filter)
        .order_by(UnitRow.serial)
    )  # fmt: skip
    # 2. the link: bytes and rows per UTC day over the last LINK_DAYS (summed by ingest)
    since = (now - timedelta(days=LINK_DAYS - 1)).replace(hour=0, minute=0, second=0,
                                                          microsecond=0)  # fmt: skip
    q_link = select(LinkDayRow.unit_id, LinkDayRow.day, LinkDayRow.compressed_bytes,
                    LinkDayRow.rows).where(LinkDayRow.day >= utc_day(since))  # fmt: skip
    if only is not None:
        q_link = q_link.where(LinkDayRow.unit_id == only)

    with store._tx() as s:
        # Core, not the ORM's execution: its per-row processing cost 20 ms at 1000 units
        conn = s.connection()
        units = conn.execute(q_units).all()
        traffic: dict[int, dict[str, tuple[int, int]]] = defaultdict(dict)
        for u, d, b, n in conn.execute(q_link):
            traffic[u][d] = (int(b or 0), int(n or 0))

    # 5. the fleet priors of the models shown (their outliers): a fixed number of queries too
    models = sorted({u.model for u in units if u.model})
    current_priors, stale_priors = priors.served(models) if models else ({}, set())
    flagged = {
        (m, o["unit"]): o for m, doc in current_priors.items() for o in doc.get("outliers") or ()
    }

    days = [(since + timedelta(days=i)).strftime("%Y-%m-%d") for i in range(LINK_DAYS)]
    rows = []
    for u in units:
        (cur_id, cur_at, cur_heading, cur_trigger, cur_instance, last_id, last_at, last_trigger,
         last_accepted, rej_id, rej_at, rej_reasons, drift_at, drift_instance,
         drift_data) = u[10:]  # fmt: skip
        row: dict[str, Any] = {
            "unit": u.serial,
            "model": u.model,
            "versions": u.n_versions or 0,
            "windows": u.n_windows or 0,
            "current_version": cur_id,
            "current_instance": cur_instance,
            "current_created_at": iso_time(cur_at),
            "age_days": None if cur_at is None else round(_age_days(now, cur_at), 2),
            "heading_error_deg_rms": _number(cur_heading),
            "rejected": {
                "count": u.n_rejected or 0,
                "last_version": rej_id,
                "last_at": iso_time(rej_at),
                "last_reasons": [str(r) for r in rej_reasons]
                if isinstance(rej_reasons, list)
                else [],
            },  # fmt: skip
            "last_version": last_id,
            "last_accepted": last_accepted,
            "last_trigger": last_trigger,
            "drift": _drift_state(
                None if drift_at is None else (drift_at, drift_data, drift_instance),
                (cur_id, cur_instance, cur_at),
                last_trigger,
                last_accepted,
            ),  # fmt: skip
            "instance": u.instance,
            "conflicts": u.n_conflicts or 0,
            "link": _link(u, traffic.get(u.id, {}), days, u.backlog, now),
            "outlier": _outlier(flagged.get((u.model, u.serial)), current_priors.get(u.model)),
        }
        row["attention"] = _attention(row)
        rows.append(row)
    rows.sort(key=lambda r: (_rank(r["attention"]), r["unit"]))
    return {
        "generated_at": iso_time(now),
        "units": rows,
        "totals": _totals(rows),
        "models": {
            m: {
                "prior_version": d.get("version"),
                "prior_created_at": d.get("created_at"),
                # a unit's token: itself alone (the model's count would tell of the others)
                "outliers": len(d.get("outliers") or ())
                if only is None
                else sum(1 for r in rows if r["model"] == m and r["outlier"]["flagged"]),
                "prior_stale": m in stale_priors,  # its successor is being computed
            }
            for m, d in current_priors.items()
        },  # fmt: skip
    }


def _age_days(now: datetime, at: datetime) -> float:
    at = at.replace(tzinfo=UTC) if at.tzinfo is None else at
    return (now - at).total_seconds() / 86400.0


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _drift_state(
    latest: tuple[datetime, Any, str] | None,
    current_version: tuple[int | None, str | None, datetime | None],
    last_trigger: str | None,
    last_accepted: bool | None,
) -> dict[str, Any]:
    """``state``: ``drift`` (declared against the current version, not yet recalibrated),
    ``recalibrated`` (declared against an older version, or the last version was a drift job
    that was accepted), ``steady`` (the latest evaluation found none) or ``unknown`` (none
    received); with the latest evaluation's figures. ``latest``: (time, the event's ``data``,
    instance) of the newest drift event. ``current_version``: (number, instance,
    time) of the current version; version numbers compare within one vessel database instance
    only, across two the times do."""
    current, current_instance, current_at = current_version
    out: dict[str, Any] = {"state": "unknown", "at": None, "statistic": None,
                           "threshold": None, "suspect": None, "version": None}  # fmt: skip
    if latest is None:
        if last_trigger == "drift":
            out["state"] = "recalibrated" if last_accepted else "drift"
        return out
    at, data, instance = latest
    inner = data if isinstance(data, dict) else {}
    out.update(at=iso_time(at), statistic=_number(inner.get("statistic")),
               threshold=_number(inner.get("threshold")), suspect=inner.get("suspect"),
               version=inner.get("version"))  # fmt: skip
    if inner.get("alarm_window") is None:
        out["state"] = "steady"
    elif current is None or not isinstance(inner.get("version"), int):
        out["state"] = "drift"
    elif instance != current_instance:  # another database's numbers: by time
        out["state"] = "recalibrated" if current_at is not None and current_at > at else "drift"
    else:
        out["state"] = "drift" if inner["version"] >= current else "recalibrated"
    return out


def _link(
    unit: Any, traffic: dict[str, tuple[int, int]], days: list[str], backlog: int | None,
    now: datetime,
) -> dict[str, Any]:  # fmt: skip
    contact = unit.last_contact
    hours = None
    if contact is not None:
        hours = now - (contact.replace(tzinfo=UTC) if contact.tzinfo is None else contact)
        hours = round(hours.total_seconds() / 3600.0, 2)
    per_day = [{"day": d, "bytes": traffic.get(d, (0, 0))[0], "rows": traffic.get(d, (0, 0))[1]}
               for d in days]  # fmt: skip
    state = "never" if contact is None else ("stale" if hours > STALE_HOURS else "up")
    return {
        "state": state,
        "last_contact": iso_time(contact),
        "hours_since_contact": hours,
        "bytes_per_day": per_day,
        "bytes_7d": sum(d["bytes"] for d in per_day),
        "backlog": backlog,
    }


def _outlier(found: dict[str, Any] | None, prior: dict[str, Any] | None) -> dict[str, Any]:
    if found is None:
        return {"flagged": False, "prior_version": None if prior is None else prior.get("version")}
    return {"flagged": True, "prior_version": prior.get("version") if prior else None,
            "statistic": found.get("statistic"), "dof": found.get("dof"),
            "p_value": found.get("p_value")}  # fmt: skip


def _attention(row: dict[str, Any]) -> list[str]:
    out = []
    if row["last_accepted"] is False:
        out.append("rejected")
    if row["drift"]["state"] == "drift":
        out.append("drift")
    if row["outlier"]["flagged"]:
        out.append("outlier")
    if row["conflicts"]:
        out.append("conflicts")
    if row["link"]["state"] in ("stale", "never"):
        out.append(row["link"]["state"])
    return out


def _rank(attention: list[str]) -> tuple[int, ...]:
    return tuple(sorted(ATTENTION.index(a) for a in attention)) + (len(ATTENTION),)


def _totals(rows: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "units": len(rows),
        "versions": sum(r["versions"] for r in rows),
        "rejected": sum(r["rejected"]["count"] for r in rows),
        "windows": sum(r["windows"] for r in rows),
        "attention": sum(1 for r in rows if r["attention"]),
        "drift": sum(1 for r in rows if r["drift"]["state"] == "drift"),
        "outliers": sum(1 for r in rows if r["outlier"]["flagged"]),
        "conflicts": sum(r["conflicts"] for r in rows),
        "stale": sum(1 for r in rows if r["link"]["state"] != "up"),
        "bytes_7d": sum(r["link"]["bytes_7d"] for r in rows),
        "backlog": sum(r["link"]["backlog"] or 0 for r in rows),
    }
