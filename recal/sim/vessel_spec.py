"""What a simulated vessel does: its segments, its sea and its unit's output filter.

A :class:`VesselSpec` is a list of :class:`Segment` s (``hold``, ``turn``, ``index``,
``transit``), the sea that moves the hull in each of them (:class:`SeaState`), the IMU's mount in
the hull and, optionally, the unit's own low-pass (:class:`OutputFilter`).
:class:`VesselSpec.berth` and :class:`VesselSpec.indexing` build the two usual schedules. The
meaning of each is in :mod:`recal.sim.vessel`, which simulates them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.signal import butter, lfilter, lfilter_zi

from recal.errors import RecalInputError

SegmentKind = Literal["hold", "turn", "index", "transit"]


@dataclass(frozen=True)
class SeaState:
    """Hull motion (``shared/spec/vessel.md``): peak amplitudes in deg and m, periods in s.

    ``lever_arm_m`` is the IMU's position from the hull's centre of rotation in the vessel frame
    (forward, right, down), m. ``yaw_swing_deg`` is the slow heading swing at a berth.
    """

    roll_deg: float = 0.3
    roll_period_s: float = 8.0
    pitch_deg: float = 0.15
    pitch_period_s: float = 6.0
    yaw_swing_deg: float = 0.1
    yaw_period_s: float = 180.0
    heave_m: float = 0.0
    heave_period_s: float = 8.0
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    components: int = 3
    period_spread: float = 0.15
    #: heading creep at a berth or anchor, deg/h (mooring lines stretching, tide turning the
    #: ship): a steady rate about the vertical, which the yaw swing above never has (it averages
    #: to zero)
    creep_dph: float = 0.0
    #: the swing round a single anchor: heading amplitude (deg) of a sinusoid of
    #: ``anchor_period_s`` (a tide, 12.42 h), zero at the start and turning fastest there
    anchor_swing_deg: float = 0.0
    anchor_period_s: float = 12.42 * 3600.0

    @classmethod
    def calm(cls) -> SeaState:
        """A perfectly still hull (the laboratory case)."""
        return cls(roll_deg=0.0, pitch_deg=0.0, yaw_swing_deg=0.0, heave_m=0.0)

    @classmethod
    def berth(cls, roll_deg: float, yaw_swing_deg: float | None = None, **kw: float) -> SeaState:
        """A moored hull: pitch half the roll, yaw swing a third of it unless given."""
        yaw = roll_deg / 3.0 if yaw_swing_deg is None else yaw_swing_deg
        return cls(roll_deg=roll_deg, pitch_deg=roll_deg / 2.0, yaw_swing_deg=yaw, **kw)

    def __post_init__(self) -> None:
        for name in ("roll_period_s", "pitch_period_s", "yaw_period_s", "heave_period_s",
                     "anchor_period_s"):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise RecalInputError(f"sea state {name} must be a positive number, not {v}")
        if self.components < 1 or not 0 <= self.period_spread < 0.9:
            raise RecalInputError("sea state needs components >= 1 and 0 <= period_spread < 0.9")


@dataclass(frozen=True)
class Segment:
    """One stretch of the schedule (see the module docstring)."""

    kind: SegmentKind
    duration_s: float
    heading_change_deg: float = 0.0
    mount_rpy_deg: tuple[float, float, float] | None = None
    sea_scale: float = 1.0
    #: a transit's speed over ground, kn (its ramps in and out included in ``duration_s``)
    speed_kn: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("hold", "turn", "index", "transit"):
            raise RecalInputError(
                f"segment kind must be hold, turn, index or transit, not {self.kind!r}"
            )
        if not (math.isfinite(self.speed_kn) and self.speed_kn >= 0):
            raise RecalInputError(f"a transit's speed must be >= 0 kn, not {self.speed_kn}")
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise RecalInputError(f"segment duration must be positive, not {self.duration_s}")
        if self.kind == "index" and self.mount_rpy_deg is None:
            raise RecalInputError("an index segment needs the mount_rpy_deg it turns the IMU to")
        if self.sea_scale < 0:
            raise RecalInputError("sea_scale must be >= 0")


@dataclass(frozen=True)
class OutputFilter:
    """The unit's own output low-pass: a digital Butterworth of ``order`` (default 2) at
    ``cutoff_hz``, unit gain at zero frequency, run at the output rate (a FOG's electronics
    filter its 1 kHz output so).

    It filters the whole output of both triads, signal and noise alike, as the sensor does. Its
    noise is then no longer white: neighbouring samples are correlated over about
    1 / (2 pi cutoff_hz), and their variance is a fraction of the white level (41 %, 21 % and
    5.5 % at 200, 100 and 25 Hz for order 2 at 1 kHz), while a long mean's is the white level's
    (the filter passes zero frequency whole). The signal is delayed by the group delay,
    sqrt(2) / (2 pi cutoff_hz) at order 2 (2.3 ms at 100 Hz), and the truth (``gyro_in_dph``,
    ``accel_in_g``) is not: a window's mean then differs from the truth's by the delay times the
    signal's change across the window over its length, nothing against the noise at a berth. The
    filter starts settled on the first output (a unit that has been running) and keeps its state
    from chunk to chunk.
    """

    cutoff_hz: float
    order: int = 2

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cutoff_hz) and self.cutoff_hz > 0):
            raise RecalInputError(f"output filter cutoff must be positive, not {self.cutoff_hz}")
        if self.order < 1:
            raise RecalInputError(f"output filter order must be at least 1, not {self.order}")

    def coefficients(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """(b, a) of the filter at ``rate_hz``."""
        if not self.cutoff_hz < 0.5 * rate_hz:
            raise RecalInputError(
                f"output filter cutoff {self.cutoff_hz:g} Hz must lie below half the rate "
                f"({0.5 * rate_hz:g} Hz)"
            )
        b, a = butter(self.order, self.cutoff_hz, fs=rate_hz)
        return np.asarray(b), np.asarray(a)

    def apply(
        self, x: np.ndarray, rate_hz: float, state: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """x (n, k) filtered along time, and the state to continue with; ``state`` None: the
        filter settled on x[0]."""
        b, a = self.coefficients(rate_hz)
        if state is None:
            state = lfilter_zi(b, a)[:, None] * x[:1]
        y, state = lfilter(b, a, x, axis=0, zi=state)
        return y, state


@dataclass(frozen=True)
class VesselSpec:
    """The schedule, the starting heading and mount, and the sea; ``output_filter``: the unit's
    own low-pass on its outputs (None, the default: white noise as drawn)."""

    segments: tuple[Segment, ...]
    heading0_deg: float = 0.0
    mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sea: SeaState = field(default_factory=SeaState)
    turn_ramp_s: float = 5.0
    sea_ramp_s: float = 60.0
    #: a transit's speed rises from and falls to a standstill over this, s
    speed_ramp_s: float = 60.0
    output_filter: OutputFilter | None = None

    def __post_init__(self) -> None:
        if not self.segments:
            raise RecalInputError("a vessel schedule needs at least one segment")
        for s in self.segments:
            if s.kind == "turn" and s.duration_s <= 2.0 * self.turn_ramp_s:
                raise RecalInputError(
                    f"a {s.duration_s:g} s turn is shorter than its two {self.turn_ramp_s:g} s ramps"
                )
            if s.kind == "transit" and s.duration_s <= 2.0 * self.speed_ramp_s:
                raise RecalInputError(
                    f"a {s.duration_s:g} s transit is shorter than its two {self.speed_ramp_s:g} s "
                    "speed ramps"
                )

    @property
    def duration_s(self) -> float:
        return float(sum(s.duration_s for s in self.segments))

    @classmethod
    def berth(
        cls,
        holds: int = 12,
        hold_s: float = 600.0,
        turn_s: float = 60.0,
        turn_deg: float = 30.0,
        sea: SeaState | None = None,
        heading0_deg: float = 0.0,
        mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
        transit_s: float = 0.0,
        transit_kn: float = 12.0,
    ) -> VesselSpec:
        """``holds`` holds of ``hold_s`` joined by steady ``turn_deg`` turns of ``turn_s``; with
        ``transit_s``, the ship sails that long at ``transit_kn`` on its heading after the first
        half of the holds (ceil(holds / 2)), to another berth where the rest are held."""
        if holds < 1:
            raise RecalInputError("a berth schedule needs at least one hold")
        segs: list[Segment] = []
        for k in range(holds):
            if k:
                segs.append(Segment("turn", turn_s, heading_change_deg=turn_deg))
            segs.append(Segment("hold", hold_s))
            if transit_s and k == (holds + 1) // 2 - 1:
                segs.append(Segment("transit", transit_s, speed_kn=transit_kn))
        return cls(tuple(segs), heading0_deg, mount_rpy_deg, sea or SeaState())

    @classmethod
    def indexing(
        cls,
        stops: Sequence[tuple[float, float, float]],
        hold_s: float = 600.0,
        index_s: float = 20.0,
        sea: SeaState | None = None,
        heading0_deg: float = 0.0,
    ) -> VesselSpec:
        """An IMU on an indexing mechanism: held at each mount attitude of ``stops`` (roll,
        pitch, yaw of the IMU in the hull, deg) for ``hold_s``, indexed between them in
        ``index_s``; the hull keeps its heading."""
        if not stops:
            raise RecalInputError("an indexing schedule needs at least one stop")
        segs: list[Segment] = [Segment("hold", hold_s)]
        for stop in stops[1:]:
            segs.append(Segment("index", index_s, mount_rpy_deg=tuple(stop)))
            segs.append(Segment("hold", hold_s))
        return cls(tuple(segs), heading0_deg, tuple(stops[0]), sea or SeaState())
