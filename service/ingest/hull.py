"""The hull detector's stage of the ingest (:class:`HullStage`): frames in, the quasi-static
windows of a hull that rolls, pitches and swings at berth out (recal.detect.hull)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from recal.detect.hull import HullDetector
from recal.detect.rest import REST_REASONS, RestReference
from recal.detect.windows import Window
from recal.errors import RecalInputError


class HullStage:
    """The hull detector on the frames, judged against the rest reference ``rest`` (Earth's
    rate and gravity, so it is required): no noise floor is learned and no slews are kept (a
    rocking hull's window ends are off its mean attitude by the wave's angle)."""

    def __init__(self, rest: RestReference | None, config: Any, rate_hz: float) -> None:
        if rest is None:
            raise RecalInputError(
                '[detector] motion = "hull" judges windows by Earth\'s rate and gravity: the '
                "unit must output deg/h and g (a KVH format), or set prior_path to convert "
                "its outputs"
            )
        self.detector = HullDetector(rest, config, rate_hz=rate_hz)

    @property
    def report(self) -> Any:
        return self.detector.report

    def reference(self, rest: RestReference) -> None:
        """Judge from now on against ``rest`` (rebuilt at the ship's latitude)."""
        self.detector.ref = rest

    def run(
        self,
        batches: list[Any],
        flush: bool,
        heading_of: Callable[[Any], Any] | None = None,
    ) -> list[Window]:
        """The windows the hull detector has decided on the frames of ``batches``
        (drivers.FrameBatch) and, with ``flush``, on what it still holds; ``heading_of`` maps
        the frames' device times to the ship's heading per frame ([nav] HDT/THS: the hull's
        creep measured, not guessed, recal.detect.creep)."""
        found = []
        if batches:
            from drivers import FrameBatch

            b = FrameBatch.concat(batches)
            psi = None if heading_of is None else heading_of(b.time_s)
            found += self.detector.feed(b.time_s, b.gyro_dph, b.accel_g, b.temperature_c,
                                        b.valid, heading_deg=psi)  # fmt: skip
        if flush:
            found += self.detector.flush()
        return [hw.window for hw in found]

    def health(self, rest_source: str | None, nav_reasons: tuple[str, ...]) -> dict[str, Any]:
        """The hull detector as ``/health`` shows it (``detector``): windows kept, ``rejected``
        by reason and its ``blocks`` by state."""
        rep = self.detector.report
        return {
            "motion": "hull",
            "rest_check": rest_source,
            "windows_kept": rep.kept,
            # every reason, counted or not (an operator sees what is looked for)
            "rejected": {r: 0 for r in ("too_short", *REST_REASONS, *nav_reasons)}
            | dict(rep.rejected),
            "blocks": {
                "total": rep.blocks,
                "turning": rep.blocks_turning,
                "accelerating": rep.blocks_accelerating,
                "fault": rep.blocks_fault,
            },
            "block_s": self.detector.cfg.block_s,
        }
