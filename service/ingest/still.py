"""The still detector's stage of the ingest (:class:`StillStage`): frames in, the windows the
static detector closed out, with the noise floor it needs (stored, learned from the frames held,
or from an initial still period) and the motion between windows kept for the slews."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from recal.detect.floor import NoiseFloor, NoiseFloorEstimator
from recal.detect.slew_collect import SlewTracker
from recal.detect.static_config import DetectorConfig
from recal.detect.static_detector import StaticDetector
from recal.detect.windows import Window
from service.ingest.floor_keeper import FloorKeeper
from service.ingest.learn import Learner


class StillStage:
    """The static detector (:class:`recal.detect.static_detector.StaticDetector`) of a unit at
    rest between moves.

    Its thresholds come from ``config`` when given, else from the floor ``keeper`` stored for
    the device (it wins over learning again: the unit may be moving now), else from an initial
    still period, else from the frames ``learner`` holds until it has learned the floor. A
    floor learned here is stored by ``keeper`` and refined from the windows that pass
    (:meth:`refine`). The frames the detector takes go to a slew tracker (bounded memory), which
    gives the motion between consecutive windows (:meth:`slews`)."""

    def __init__(
        self, config: DetectorConfig, learner: Learner, keeper: FloorKeeper | None = None
    ) -> None:
        self.learner = learner
        self.keeper = keeper
        explicit = config.accel_threshold is not None and config.gyro_threshold is not None
        stored = keeper.load() if keeper is not None and not explicit else None
        if stored is not None:  # the stored floor wins over learning again (maybe in motion)
            config = replace(config, noise_floor=stored, init_still_s=None)
        self.config = config
        self.detector: StaticDetector | None = None
        self._learned_from_still = False
        self._tracker: SlewTracker | None = None
        self._fed = 0  # frames given to the detector
        if config.has_thresholds:
            self._start()
        else:
            learner.estimate_with(NoiseFloorEstimator(config.window_s, config.sample_rate_hz))

    @property
    def needs_floor(self) -> bool:
        """No thresholds yet: the frames are held to learn the noise floor."""
        return self.detector is None

    @property
    def report(self) -> Any:
        return None if self.detector is None else self.detector.report

    def _start(self) -> None:
        self.detector = StaticDetector(self.config)
        cfg = self.config
        self._learned_from_still = (
            self.keeper is not None and cfg.init_still_s is not None and cfg.noise_floor is None
        )

    def run(self, batches: list[Any], flush: bool, why: str = "end_of_input") -> list[Window]:
        """The windows closed by the frames of ``batches`` (drivers.FrameBatch) and, with
        ``flush`` (no frame will come; ``why`` a learning-end code), the open one."""
        from drivers import FrameBatch

        windows: list[Window] = []
        if self.detector is None:
            batch = FrameBatch.concat(batches) if batches else None
            floor, batches = self.learner.learn(batch, final=flush, why=why)
            if floor is not None:
                self.config = replace(self.config, noise_floor=floor)
                self._start()
                if self.keeper is not None:
                    self.keeper.save(floor, floor.source)
        if batches and self.detector is not None:
            b = FrameBatch.concat(batches)
            windows += self.detector.feed(
                b.time_s, b.gyro_dph, b.accel_g, b.temperature_c, b.valid, b.lost_before
            )
            self._track(b)
        if flush and self.detector is not None:
            windows += self.detector.flush()
        if self.detector is not None and self._learned_from_still:
            rep = self.detector.report
            if rep.accel_threshold is not None:  # the initial still period is over: store it
                self._learned_from_still = False
                k = self.config.threshold_k
                floor = NoiseFloor(rep.accel_threshold / k, rep.gyro_threshold / k,
                                   rep.window_samples, rep.threshold_source)  # fmt: skip
                self.keeper.save(floor, rep.threshold_source or "initial still period")
        return windows

    def refine(self, windows: list[Window]) -> None:
        """The windows that passed every check refine the stored floor."""
        if windows and self.keeper is not None:
            self.keeper.refine(windows)

    def _track(self, b: Any) -> None:
        """Give the frames the detector just took to the slew tracker (created once the frame
        rate is known; frames before it cannot be part of a slew)."""
        if self._tracker is None:
            rate = self.detector.report.sample_rate_hz or self.config.sample_rate_hz
            if rate:
                self._tracker = SlewTracker(1.0 / rate, start_index=self._fed)
        if self._tracker is not None:
            self._tracker.feed(b.gyro_dph, b.valid, b.lost_before)
        self._fed += len(b)

    def slews(self, windows: list[Window]) -> tuple[list[tuple[int, int, Any]], float | None]:
        """The motion before each of ``windows`` (the windows kept, in order) as ``(k - 1, k,
        reduced slew)``, and the sample period (None before the frame rate is known)."""
        if self._tracker is None:
            return [], None
        slews = []
        for k, w in enumerate(windows):
            r = self._tracker.window(w)
            if r is not None:
                slews.append((k - 1, k, r))
        return slews, self._tracker.period_s

    def health(self, rest_source: str | None, nav_reasons: tuple[str, ...]) -> dict[str, Any]:
        """The still detector as ``/health`` shows it (``detector``)."""
        learning = self.learner.health(
            self.detector is None, self.detector is not None, self._threshold_source()
        )
        if self.detector is None:
            return {"motion": "still", "rest_check": rest_source, "learning_noise_floor": True,
                    "learned_s": round(self.learner.learned_s, 1),
                    "learn_s": self.learner.learn_s, "learning": learning}  # fmt: skip
        rep = self.detector.report
        return {
            "motion": "still",
            "rest_check": rest_source,
            "accel_threshold": rep.accel_threshold,
            "gyro_threshold": rep.gyro_threshold,
            "threshold_source": getattr(rep, "threshold_source", None),
            "windows_kept": rep.windows_kept,
            # the rest check's reasons included, and the underway rule's with [nav]
            "rejected": dict.fromkeys(nav_reasons, 0) | dict(rep.rejected),
            "learning": learning,
        }

    def _threshold_source(self) -> Any:
        return getattr(self.report, "threshold_source", None)
