"""KVH binary frames as a registered input format: drivers.StreamDecoder behind the
:class:`drivers.registry.StreamParser` interface."""

from __future__ import annotations

from .config import DEFAULT_CONFIG, DecoderConfig
from .decoder import StreamDecoder
from .diagnose import diagnose, require_frames
from .formats import FrameFormat
from .frames import FrameBatch

#: The formats are declared (frame layouts) in drivers.kvh.
FAMILY_MODULE = "drivers.kvh"


class KvhParser(StreamDecoder):
    """Bytes of one KVH stream in, frames out (``part`` is ignored: parts are consecutive)."""

    #: Gyro deg/h and accel g, with status, sequence numbers and temperature.
    triads = ("gyro", "accel")
    sample_rate_hz = None  # the detector takes the rate from the frames' time
    gyro_limits = None
    has_temperature = True

    def __init__(self, fmt: str | FrameFormat, config: DecoderConfig, source: str) -> None:
        super().__init__(fmt, config)
        self.source = source

    @property
    def byte_rate(self) -> float:
        """Bytes per second at the configured data rate."""
        return self.config.rate_hz * self.format.length

    def feed(self, data, host_time: float | None = None, part: int = 0) -> FrameBatch:
        return super().feed(data, host_time)

    def finish(self) -> None:
        """End of a recording: DriverInputError when nothing of this format was in it."""
        require_frames(self.counters, self.format.name, source=self.source)

    def diagnosis(self) -> str | None:
        return diagnose(self.counters, self.format)

    def notes(self) -> list[str]:
        c = self.counters
        return [
            f"{self.format.name}: {c.frames} frames decoded, {c.crc_failures} CRC failures, "
            f"{c.sequence_gaps} sequence gaps ({c.frames_lost} frames lost), "
            f"{c.invalid_status} invalid status; gyro deg/h, accel g"
        ]


def kvh_parser(
    name: str,
    source: str = "<stream>",
    config: DecoderConfig | None = None,
    rate_hz: float | None = None,
    gyro_output: str | None = None,
    gyro_units: str | None = None,
    temperature_units: str | None = None,
) -> KvhParser:
    """The registry's factory: a ready DecoderConfig, or its settings one by one."""
    if config is None:
        given = {
            "rate_hz": rate_hz,
            "gyro_output": gyro_output,
            "gyro_units": gyro_units,
            "temperature_units": temperature_units,
        }
        config = DecoderConfig(**{k: v for k, v in given.items() if v is not None})
    return KvhParser(name, config or DEFAULT_CONFIG, source)
