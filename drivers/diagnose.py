"""Plain-words diagnosis of a stream that decodes badly: wrong format, or no valid frame."""

from __future__ import annotations

from .errors import DriverInputError
from .formats import FrameFormat, get_format
from .frames import DecoderCounters

# A few stray headers of another format happen (a BIT reply, noise); a mis-set format shows
# many of them and CRC-checked frames of the configured format are few or none.
MIN_FOREIGN_HEADERS = 3


def diagnose(counters: DecoderCounters, fmt: str | FrameFormat) -> str | None:
    """A one-line explanation when the stream looks like another registered format, else None."""
    target = get_format(fmt)
    foreign = {
        name: count
        for name, count in counters.headers_seen.items()
        if name != target.name and count >= MIN_FOREIGN_HEADERS
    }
    if not foreign:
        return None
    name, count = max(foreign.items(), key=lambda kv: kv[1])
    if count <= counters.frames:
        return None
    other = get_format(name)
    if counters.frames == 0:
        found = f"no {target.label} frames found"
    else:
        found = f"only {counters.frames} {target.label} frames but {count} {other.label} headers"
    return f"{found}; the stream looks like {other.describe()}: check --format"


def require_frames(
    counters: DecoderCounters, fmt: str | FrameFormat, source: str = "the stream"
) -> None:
    """Raise DriverInputError when ``source`` holds no valid frame or looks mis-formatted."""
    target = get_format(fmt)
    reason = diagnose(counters, target)
    if reason is not None:
        raise DriverInputError(f"{source}: {reason}")
    if counters.frames == 0:
        if counters.bytes_in == 0:
            raise DriverInputError(f"{source} is empty (0 bytes)")
        raise DriverInputError(
            f"{source} holds no valid {target.family} {target.label} frame "
            f"({target.name}): {counters.summary()}"
        )
