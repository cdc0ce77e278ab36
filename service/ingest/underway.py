"""The ship over each window, with ``[nav]`` (:class:`ShipState`): the underway rule keeps the
windows of a ship (nearly) at rest, and the ship's columns and the transport rate go into the
windows' table (recal.detect.underway)."""

from __future__ import annotations

from typing import Any

import numpy as np

from recal.detect.windows import Window


class ShipState:
    """The ship's sensors (service.nav.ShipSensors, ``nav``; None: no ``[nav]``) over the
    windows."""

    def __init__(self, nav: Any = None) -> None:
        self.nav = nav

    @property
    def reasons(self) -> tuple[str, ...]:
        """The underway rule's reason with ``[nav]``, else none."""
        return () if self.nav is None else ("underway",)

    def keep(self, windows: list[Window], report: Any) -> tuple[list[Window], list[Any] | None]:
        """The windows the underway rule keeps, with the ship over each (None without
        ``[nav]``); those it rejects are counted in the detector's ``report``."""
        if self.nav is None or not windows:
            return windows, None
        from recal.detect.underway import count_rejections, underway_rule

        ships = self.nav.over(windows)
        rule = underway_rule(ships, self.nav.max_sog_kn)
        if not rule.kept.all():
            count_rejections(report, windows, list(rule.reasons))
            keep = np.flatnonzero(rule.kept)
            windows, ships = [windows[i] for i in keep], [ships[i] for i in keep]
        return windows, ships

    def columns(
        self, columns: dict[str, Any], ships: list[Any], gyro_scale: float
    ) -> dict[str, Any]:
        """The ship's columns, and the transport rate of each window's net displacement added to
        its gyro sigma in the gyro's output units (``gyro_scale``: the rest reference's; 0
        without one, when the outputs' units are not known)."""
        from recal.detect.underway import ship_columns, underway_rule

        return ship_columns(columns, ships, underway_rule(ships, self.nav.max_sog_kn, gyro_scale))
