"""The live pipeline's ingest: frames -> static windows -> positions (:class:`Ingest`).

:class:`Ingest` runs its stages in order on each batch of decoded frames (batched, since a
detector call has a fixed cost), one module each under :mod:`service.ingest`:

* learn (:mod:`service.ingest.learn`): the first noise floor from the frames held;
* detect: the still detector (:mod:`service.ingest.still`, with its noise floor kept per
  device by :mod:`service.ingest.floor_keeper`) or the hull detector (:mod:`service.ingest.hull`);
* rest check (:mod:`service.ingest.rest_check`) and, with ``[nav]``, the underway rule
  (:mod:`service.ingest.underway`);
* store (:mod:`service.ingest.store`): spool, database and events.

What they are built from is read from the settings by :mod:`service.ingest.setup`;
:mod:`service.ingest.thread` runs the ingest in a thread of its own. The scheduler
(:mod:`service.scheduler`) decides when the stored positions are worth a recalibration.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from recal.detect.rest import RestReference
from recal.detect.static_config import DetectorConfig
from recal.detect.windows import Window, windows_to_columns
from service.events import Events
from service.ingest.floor_keeper import FloorKeeper
from service.ingest.hull import HullStage
from service.ingest.learn import Learner
from service.ingest.rest_check import RestCheck
from service.ingest.still import StillStage
from service.ingest.store import WindowStore
from service.ingest.underway import ShipState
from service.spool import Spool

#: Frames buffered before a detector call (4 s at 1 kHz): a call costs ~0.4 ms whatever its size.
DETECTOR_BLOCK = 4096
#: ... but never hold frames longer than this (host time, s), so slow streams are not delayed.
DETECTOR_MAX_WAIT_S = 1.0


class Ingest:
    """Feeds decoded frames to the static detector and stores each closed window.

    With a ``rest`` reference (:func:`rest_reference`) the static detector's windows pass the
    rest check in physics too (:func:`recal.detect.rest.rest_filter`: a steady turn has a quiet
    moving variance but not Earth's rate); those it refuses are counted by reason in
    ``/health`` (``detector.rejected``). With a ``hull`` configuration the hull detector
    (:class:`recal.detect.hull.HullDetector`, which needs ``rest``) finds quasi-static windows
    instead: no noise floor is learned and no slews are kept (a rocking hull's window ends are
    off its mean attitude by the wave's angle).

    Without thresholds or a stored floor, frames are held while the first noise floor is
    learned from the first ``learn_s`` of device time; learning ends sooner, from what is held,
    when the stream sends nothing for ``learn_quiet_s``, after ``learn_s`` of host time (a slow
    or short stream) or at the end of input (:meth:`end_of_input`, :meth:`flush`), so held
    frames always become windows. ``/health`` shows it (:meth:`learning_health`).

    The motion between consecutive windows is kept too (:class:`recal.detect.slew_collect.SlewTracker`,
    bounded memory) and stored with them, so the gyro can be calibrated from the slews.

    With a ``spool`` (:class:`service.spool.Spool`) each detector call's windows are written to
    it durably *before* they count as detected (``detected``) and go to the database; a batch's
    file is deleted once the database committed it. Batches a previous run left in the spool
    are queued first, in order (:meth:`replay`). During a database outage batches wait on disk,
    retried with exponential back-off from :meth:`poll`. When the spool folder refuses a write
    (disk full, permissions) the error is kept in ``spool_error`` and the batch goes straight to
    the database; only when both refuse is it held in memory, bounded (:data:`service.ingest.store.SPOOL_MAX`
    windows, overflow counted in ``windows_dropped``).
    """

    def __init__(
        self,
        store: Any,
        session_id: int,
        config: DetectorConfig,
        on_positions: Callable[[list[int]], None] | None = None,
        events: Events | None = None,
        keeper: FloorKeeper | None = None,
        learn_s: float = 120.0,
        spool: Spool | None = None,
        rest: RestReference | None = None,
        hull: Any = None,
        learn_quiet_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
        nav: Any = None,
        rest_at: Callable[[float], RestReference | None] | None = None,
    ) -> None:
        self._clock = clock  # host time, s (a test's own clock drives the wall-time rules)
        events = events or Events(store)
        self._events = events
        # the ship's sensors (service.nav.ShipSensors): each window's ship state, the underway
        # rule; rest_at(latitude) rebuilds the rest reference when they give the latitude
        self._nav = nav
        self.ship = ShipState(nav)
        self.rest_check = RestCheck(rest, events, rest_at, config.sample_rate_hz)
        self.hull: HullStage | None = None
        self.still: StillStage | None = None
        self.learner = Learner(events, None, learn_s, learn_quiet_s, clock)
        if hull is not None:  # quasi-static windows of a moving hull: nothing to learn
            self.hull = HullStage(rest, hull, rate_hz=config.sample_rate_hz or 1000.0)
        else:
            self.still = StillStage(config, self.learner, keeper)
        self.store = WindowStore(store, session_id, events, spool, on_positions, clock)
        self._pending: list[Any] = []
        self._count = 0
        self._first_pending = 0.0
        self._lock = threading.Lock()
        self.input_ended = False  # end_of_input() was called: no frame will come
        self.frames = 0
        self.last_detector_run = self._clock()

    # ---- the frames in ------------------------------------------------------------------------
    def feed(self, batch: Any) -> list[int]:
        """Take a drivers.FrameBatch; returns the ids of positions stored by this call."""
        with self._lock:
            if len(batch) == 0:
                return []
            if self._nav is not None:  # the frames' device and host times: windows to host time
                self._nav.observe(batch)
            now = self._clock()
            self.learner.saw_frames(now, self.learning)
            if not self._pending:
                self._first_pending = now
            self._pending.append(batch)
            self._count += len(batch)
            self.frames += len(batch)
            if self._count < DETECTOR_BLOCK and not self._stale():
                return []
            return self._run(flush=False)

    def poll(self) -> list[int]:
        """Run the detector on frames held longer than DETECTOR_MAX_WAIT_S, and retry spooled
        windows when their back-off has passed (call periodically)."""
        with self._lock:
            if self._pending and self._stale():
                return self._run(flush=False)
            if self.learning and self.learner.cut(bool(self._pending)) is not None:
                return self._run(flush=False)  # the stream went quiet, or is too slow
            return self.store.drain_if_due()

    def _stale(self) -> bool:
        return self._clock() - self._first_pending >= DETECTOR_MAX_WAIT_S

    def flush(self, why: str = "end_of_input") -> list[int]:
        """End of stream: learn the noise floor from the frames held, if it is still being
        learned, then close the open window, if any. ``why`` (a
        :data:`service.ingest.learn.LEARN_ENDS` code) is what ``/health`` and the events give
        as the end of learning."""
        with self._lock:
            return self._run(flush=True, why=why)

    def end_of_input(self) -> list[int]:
        """No frame will come (a replayed capture read to its end): say so in an ``input``
        event, then :meth:`flush`. Called once per stream; later calls do nothing, so the
        reader's signal and a caller that also knows the stream has ended cannot double it."""
        with self._lock:
            if self.input_ended:
                return []
            self.input_ended = True
            self._events.emit("input", "end of input: the stream has ended; the frames held are "
                              "processed and the open window is closed",
                              {"frames": self.frames})  # fmt: skip
            return self._run(flush=True, why="end_of_input")

    def nav_latitude(self, latitude_deg: float) -> None:
        """The ship's sensors give this latitude (any thread; returns at once): the rest
        reference is rebuilt at it before the detector next runs
        (:meth:`service.ingest.rest_check.RestCheck.nav_latitude`)."""
        self.rest_check.nav_latitude(latitude_deg)

    def replay(self) -> list[int]:
        """Queue the batches earlier runs left in the spool (oldest first, ahead of any new
        window) and store what the database takes now; returns the ids stored."""
        with self._lock:
            return self.store.replay()

    # ---- the stages ---------------------------------------------------------------------------
    def _run(self, flush: bool, why: str = "end_of_input") -> list[int]:
        ref = self.rest_check.follow_latitude()
        if ref is not None and self.hull is not None:
            self.hull.reference(ref)
        self.last_detector_run = self._clock()
        batches, self._pending, self._count = self._pending, [], 0
        if self.hull is not None:
            heading_of = None if self._nav is None else self._nav.heading_of
            windows = self.hull.run(batches, flush, heading_of)
        else:
            windows = self.still.run(batches, flush, why)
            windows = self.rest_check.check(windows, self.still.report)
            self.still.refine(windows)
        windows, ships = self.ship.keep(windows, self.report)
        return self._queue(windows, ships)

    def _queue(self, windows: list[Window], ships: list[Any] | None = None) -> list[int]:
        """Spool a detector call's windows (with the slews between them and, with ``[nav]``, the
        ship over each: its columns, and the transport rate in the gyro sigma) and store what
        the database takes now."""
        if windows:
            slews, period = ([], None) if self.still is None else self.still.slews(windows)
            columns = windows_to_columns(windows)
            if ships is not None:
                ref = self.rest_check.reference
                scale = 0.0 if ref is None else ref.gyro_scale
                columns = self.ship.columns(columns, ships, scale)
            self.store.put(columns, slews, period)
        return self.store.drain_if_due()

    # ---- what /health shows -------------------------------------------------------------------
    @property
    def report(self) -> Any:
        return self.hull.report if self.hull is not None else self.still.report

    @property
    def learning(self) -> bool:
        """Frames are being held to learn the first noise floor (no windows yet)."""
        return self.still is not None and self.still.needs_floor

    def frames_waiting_s(self) -> float | None:
        """How long the oldest frame not yet given to the detector has waited (host s)."""
        with self._lock:
            return self._clock() - self._first_pending if self._pending else None

    def detector_health(self) -> dict[str, Any]:
        """The detector as ``/health`` shows it: ``motion``, the rest check's reference
        (``rest_check``, None without one), windows kept and ``rejected`` by reason (the rest
        check's reasons included); the hull detector's ``blocks`` by state too."""
        stage = self.hull if self.hull is not None else self.still
        return stage.health(self.rest_check.source, self.ship.reasons)

    def learning_health(self) -> dict[str, Any]:
        """The first noise floor's learning as ``/health`` shows it (``detector.learning``,
        :meth:`service.ingest.learn.Learner.health`)."""
        started = self.hull is not None or not self.learning
        source = getattr(self.report, "threshold_source", None)
        return self.learner.health(self.learning, started, source)

    @property
    def learn_ended_by(self) -> str | None:
        return self.learner.ended_by

    @property
    def learn_message(self) -> str | None:
        return self.learner.message

    @property
    def spooled(self) -> int:
        """Windows waiting for the database (on disk or in memory)."""
        return self.store.spooled

    def spool_health(self) -> dict[str, Any]:
        """The spool as ``/health`` shows it."""
        return self.store.spool_health()

    @property
    def windows(self) -> int:
        return self.store.windows

    @property
    def detected(self) -> int:
        return self.store.detected

    @property
    def replayed(self) -> int:
        return self.store.replayed

    @property
    def windows_dropped(self) -> int:
        return self.store.windows_dropped

    @property
    def windows_in_memory(self) -> int:
        return self.store.windows_in_memory

    @property
    def slews(self) -> int:
        return self.store.slews

    @property
    def slews_dropped(self) -> dict[str, int]:
        return self.store.slews_dropped

    @property
    def spool_error(self) -> str | None:
        return self.store.spool_error

    @property
    def store_error(self) -> str | None:
        return self.store.store_error
