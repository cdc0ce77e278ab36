"""The fleet prior of each model, computed on shore from the stored versions.

:func:`recal.fleet.fleet_prior` does the numerics; this module feeds it the shore's accepted
versions, and those the vessels' gate rejected for a jump alone (issue 37: the gate censors the
largest changes, so the accepted ones alone give a rate biased low; recal.fleet.sequence says
why every sound version is used and how), with their ``accepted`` flag, and their
coefficients and 1-sigma by the conventions' flat names of the seed terms, as ingest
kept them beside each document (``fleet_versions.flat``, :func:`recal.fleet.history.flat_version`,
migration 0006; :meth:`recal.fleet.VersionTable.from_flat`), never the 30 kB documents, and keeps every prior it computed in ``fleet_priors``. A prior's ``version``
is raised only when its inputs changed: the inputs are digested per model as (unit, accepted
versions stored, the newest's shore row id) -- versions are stored once and never changed, so
the digest changes exactly when an accepted version arrives or a unit changes model. A rejected
version alone does not make the prior stale: it enters at the model's next recompute, when any
of its units' next accepted version arrives (a rejected version would otherwise raise the
prior's version even when it is one the prior leaves out). Asking
again with the same inputs answers the stored prior (a process cache spares the database even
that), so a dashboard refresh never recomputes.

Requests never wait for a recompute (:meth:`FleetPriors.served`): a prior whose inputs changed
is recomputed by one background thread, woken by the ingest that stored an accepted version
(:meth:`FleetPriors.refresh_soon`), and until it is done requests answer the stored one and say
it is stale. Only a model's very first prior is computed in the request that asks for it: its
history is then two versions long.

Every call runs a fixed number of SQL statements, whatever the number of units and models.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import re
import threading
from collections import defaultdict
from collections.abc import Iterable
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import case, func, select
from sqlalchemy.exc import IntegrityError

from service.fleet.schema import PriorRow, UnitRow, VersionRow
from service.store.errors import StoreError

log = logging.getLogger(__name__)

#: Units of no registered model are grouped under this name in the overview (no prior).
NO_MODEL = None
#: The reasons service/gate.py gives for a jump beyond ``max_change_sigma``: one line per
#: coefficient ("gyro.scale.Kx moved 7.2 sigma from version 3 (limit 6...)") and a summary
#: ("4 more coefficients moved beyond 6 sigma").
_JUMP = re.compile(r"\S+ moved \S+ sigma from version |\d+ more coefficients moved beyond ")


def learns_from(accepted: bool, reasons: Any) -> bool:
    """Whether the fleet prior learns from a version: an accepted one, or one the gate rejected
    for jumps alone (every reason a jump line). A version rejected for anything else (residuals,
    observability, a scale's sigma, navigation, unconfirmed effects), or without reasons, is left
    out: its estimate is not trusted, and leaving it out depends on no coefficient's value
    (recal.fleet.sequence)."""
    if accepted:
        return True
    if not isinstance(reasons, list) or not reasons:
        return False
    return all(isinstance(r, str) and _JUMP.match(r) for r in reasons)


def coefficient_names() -> list[str]:
    """The conventions' flat names of the seed terms (``gyro.scale.Kx`` ... ``accel.quadratic.K2z``)."""
    return list(_coefficient_names())


@functools.cache
def _coefficient_names() -> tuple[str, ...]:
    from recal.model.plugins import SENSORS
    from recal.model.terms import seed_terms

    return tuple(f"{t.name}.{p}" for s in SENSORS for t in seed_terms(s) for p in t.params)


class FleetPriors:
    """The current prior of each model of one :class:`~service.fleet.store.FleetStore`."""

    def __init__(self, store: Any) -> None:
        self._store = store
        self._cache: dict[str, tuple[str, dict[str, Any]]] = {}  # model -> (inputs, document)
        self._lock = threading.Lock()  # one computation at a time per process
        # the background refresh: woken by refresh_soon, idle when nothing is left to compute
        self._state = threading.Lock()
        self._wake = threading.Event()
        self._idle = threading.Event()
        self._idle.set()
        self._thread: threading.Thread | None = None
        self._closed = False

    def inputs(self, models: Iterable[str] | None = None) -> dict[str, str]:
        """The inputs' digest of every model (or of ``models``) that has units: one query."""
        accepted = (
            select(
                VersionRow.unit_id,
                func.count().label("n"),
                func.max(VersionRow.id).label("newest"),
            )
            .where(VersionRow.accepted.is_(True))
            .group_by(VersionRow.unit_id)
            .subquery()
        )  # grouped first: one pass over the versions, then a join per unit
        query = (
            select(UnitRow.model, UnitRow.serial, accepted.c.n, accepted.c.newest)
            .outerjoin(accepted, accepted.c.unit_id == UnitRow.id)
            .where(UnitRow.model.is_not(None))
            .order_by(UnitRow.model, UnitRow.serial)
        )
        if models is not None:
            query = query.where(UnitRow.model.in_(list(models)))
        per_model: dict[str, list[Any]] = defaultdict(list)
        with self._store._tx() as s:
            for model, serial, n, newest in s.execute(query):
                if n:  # a unit without an accepted version adds nothing to learn from
                    per_model[model].append([serial, n, newest])
                else:
                    per_model.setdefault(model, [])
        return {m: hashlib.sha256(json.dumps(rows).encode()).hexdigest()
                for m, rows in per_model.items()}  # fmt: skip

    def current(self, models: Iterable[str] | None = None) -> dict[str, dict[str, Any]]:
        """The current prior document of every model (or of ``models``) with units, computed
        and stored where its inputs changed; a model without two accepted versions of one
        unit gets none (absent)."""
        return self._current(self.inputs(models))

    def _from_cache(self, digests: dict[str, str]) -> tuple[dict[str, dict[str, Any]], list[str]]:
        """(the cached documents whose inputs still match ``digests``, the other models)."""
        out: dict[str, dict[str, Any]] = {}
        missing = []
        for model, digest in digests.items():
            cached = self._cache.get(model)
            if cached is not None and cached[0] == digest:
                out[model] = cached[1]
            else:
                missing.append(model)
        return out, missing

    def _current(self, digests: dict[str, str]) -> dict[str, dict[str, Any]]:
        """:meth:`current` for the models of ``digests``, their inputs already digested."""
        out, stale = self._from_cache(digests)
        if not stale:
            return {m: d for m, d in out.items() if d}
        with self._lock:
            stored = self._stored(stale)
            todo = [m for m in stale if stored.get(m, (None,))[0] != digests[m]]
            for m in stale:
                if m not in todo:
                    self._cache[m] = (digests[m], stored[m][1])
                    out[m] = stored[m][1]
            if todo:
                documents = self._compute(todo, {m: stored.get(m) for m in todo}, digests)
                for m in todo:
                    self._cache[m] = (digests[m], documents.get(m) or {})
                    out[m] = documents.get(m) or {}
        return {m: d for m, d in out.items() if d}

    def served(
        self, models: Iterable[str] | None = None
    ) -> tuple[dict[str, dict[str, Any]], set[str]]:
        """What a request answers: (the newest prior of every model, or of ``models``, that has
        one; the models among them whose inputs changed since it was computed). A stale prior is
        recomputed in the background (:meth:`refresh_soon`), never here; a model with no stored
        prior yet is computed here (once per model, while its history is short)."""
        digests = self.inputs(models)
        out, unknown = self._from_cache(digests)
        stale: set[str] = set()
        if unknown:
            stored = self._stored(unknown)
            first = [m for m in unknown if m not in stored]
            for m in unknown:
                if m in stored:
                    inputs, document, _ = stored[m]
                    out[m] = document
                    if inputs == digests[m]:
                        self._cache[m] = (inputs, document)
                    else:
                        stale.add(m)
            if first:
                out.update(self._current({m: digests[m] for m in first}))
            if stale:
                self.refresh_soon()
        return {m: d for m, d in out.items() if d}, stale & {m for m, d in out.items() if d}

    def refresh_soon(self) -> None:
        """Recompute every stale prior in the background thread (started on first use)."""
        with self._state:
            if self._closed:
                return
            self._idle.clear()
            self._wake.set()
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._refresh_loop, name="fleet-prior-refresh", daemon=True
                )
                self._thread.start()

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Until no background recompute is pending or running; False after ``timeout`` s."""
        return self._idle.wait(timeout)

    def close(self, timeout: float = 30.0) -> None:
        """Stop the background thread (a recompute under way finishes first)."""
        with self._state:
            self._closed = True
            self._wake.set()
            thread = self._thread
        if thread is not None:
            thread.join(timeout)

    def _refresh_loop(self) -> None:
        while True:
            self._wake.wait()
            with self._state:
                if self._closed:
                    self._idle.set()
                    return
                self._wake.clear()
            try:
                self.current()
            except Exception:  # the database went away: the next ingest or request retries
                log.exception("fleet prior recompute failed")
            with self._state:
                if not self._wake.is_set():
                    self._idle.set()

    def _stored(self, models: list[str]) -> dict[str, tuple[str, dict[str, Any], int]]:
        """The newest stored prior of each of ``models``: (inputs, document, version)."""
        newest = (
            select(PriorRow.model, func.max(PriorRow.version).label("v"))
            .where(PriorRow.model.in_(models))
            .group_by(PriorRow.model)
            .subquery()
        )
        query = select(PriorRow).join(
            newest, (newest.c.model == PriorRow.model) & (newest.c.v == PriorRow.version)
        )
        with self._store._tx() as s:
            return {r.model: (r.inputs, r.document, r.version) for r in s.scalars(query)}

    def _compute(
        self,
        models: list[str],
        previous: dict[str, tuple[str, dict[str, Any], int] | None],
        digests: dict[str, str],
    ) -> dict[str, dict[str, Any]]:
        """Compute and store the priors of ``models`` from their versions (:func:`learns_from`;
        one query for the versions, one transaction for the new rows)."""
        from recal.fleet.compute import fleet_prior
        from recal.fleet.history import VersionTable, flat_version

        names = coefficient_names()
        # the reasons only of the rejected versions (an accepted one's are notes)
        reasons = case((VersionRow.accepted.is_(False), VersionRow.data["reasons"]), else_=None)
        query = (
            select(
                UnitRow.model,
                UnitRow.serial,
                VersionRow.at,
                VersionRow.id,
                VersionRow.flat,
                VersionRow.accepted,
                reasons,
            )  # fmt: skip
            .join(UnitRow, UnitRow.id == VersionRow.unit_id)
            .where(UnitRow.model.in_(models))
            .order_by(UnitRow.model, UnitRow.serial, VersionRow.at, VersionRow.id)
        )
        rows: dict[str, dict[str, list[Any]]] = {m: defaultdict(list) for m in models}
        missing: dict[int, tuple[str, str, int]] = {}  # rows stored without it (not by ingest)
        with self._store._tx() as s:
            for model, serial, at, row_id, flat, accepted, why in s.execute(query):
                if not learns_from(bool(accepted), _json(why)):
                    continue
                if flat is None:
                    missing[row_id] = (model, serial, len(rows[model][serial]))
                rows[model][serial].append((_utc(at), flat, bool(accepted)))
            if missing:  # their documents: one more query, only then
                doc = VersionRow.data["document"]
                found = s.execute(
                    select(VersionRow.id, doc["coefficients"], doc["uncertainty"]).where(
                        VersionRow.id.in_(list(missing))
                    )
                )
                for row_id, coefficients, uncertainty in found:
                    model, serial, k = missing[row_id]
                    document = {"coefficients": _json(coefficients),
                                "uncertainty": _json(uncertainty)}  # fmt: skip
                    time, _, accepted = rows[model][serial][k]
                    rows[model][serial][k] = (time, flat_version(document, names), accepted)
        now = datetime.now(UTC)
        out: dict[str, dict[str, Any]] = {}
        new_rows = []
        for model in models:
            table = VersionTable.from_flat(names, rows[model])
            if len(table.changes()) == 0:
                out[model] = {}  # no unit with two versions to learn from yet: no prior
                continue
            old = previous.get(model)
            version = 1 if old is None else old[2] + 1
            prior = fleet_prior(table, model, version=version,
                                created_at=now.strftime("%Y-%m-%dT%H:%M:%SZ"),
                                metadata={"source": "recal fleet shore",
                                          "units": len(table.units),
                                          "versions": len(table.unit),
                                          "rejected": int((~table.accepted).sum())})  # fmt: skip
            out[model] = prior.to_json_dict()
            new_rows.append(PriorRow(model=model, version=version, created_at=now,
                                     inputs=digests[model], document=out[model]))  # fmt: skip
        if new_rows:
            try:
                with self._store._tx(write=True) as s:
                    s.add_all(new_rows)
            except StoreError as exc:
                if not isinstance(exc.__cause__, IntegrityError):
                    raise
                # another shore process stored these versions meanwhile: theirs stand
                stored = self._stored([r.model for r in new_rows])
                for r in new_rows:
                    out[r.model] = stored[r.model][1]
        return out


def _json(value: Any) -> Any:
    """A JSON value selected out of a document (SQLite may hand it back as text)."""
    if isinstance(value, str):
        try:
            return json.loads(value)
        except ValueError:
            return None
    return value


def _utc(value: datetime) -> datetime:
    return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)
