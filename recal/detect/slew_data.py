"""The slews of one recording as data: :class:`Slews` (the downsampled gyro increments between
consecutive windows) and its side file ``POSITIONS.slews.npz``.

What the arrays hold and why they suffice to integrate the gyro exactly for every parameter
vector is in :mod:`recal.detect.slew_groups`. Everything here is numpy on arrays in memory: no I/O (the
npz is produced and parsed as bytes).
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from recal.errors import RecalInputError

#: Groups (integration steps) per slew; a power of two for the pairwise quaternion product.
DEFAULT_GROUPS = 64
#: Reasons a slew is dropped, as keys of :attr:`Slews.dropped`.
DROP_REASONS = ("lost_frames", "invalid_frames", "saturated", "too_long")
#: Longest motion between two windows taken as a slew, s. An indexing or fixture rotation lasts
#: seconds; hours of hull motion between two port calls is no slew (the integrated gyro noise and
#: every unmodelled term grow with it), and holding it would make memory grow with the recording.
MAX_SLEW_S = 300.0
_NPZ_VERSION = 1


@dataclass(frozen=True, eq=False)
class Slews:
    """The slews of one recording, as downsampled gyro increments (see the module docstring).

    first / second: (S,) row indices of the windows before and after each slew in the positions.
    period_s: gyro sample period, s. samples: (S,) samples integrated (the slew spans from the
    last frame of window ``first`` to the first frame of window ``second``: ``samples * period_s``
    seconds). reference: (S, 3) window-``first`` mean gyro output, output units.
    group_samples: (S, G) samples per group (0 for padding). sums, weighted, cross: (S, G, 3)
    the sums S_g, W_g (output units x s) and C_g ((output units x s)^2).
    window_start_s / window_end_s: (S, 2) times of the two windows, to check the side file
    against the positions CSV. dropped: reason -> slews dropped (lost or invalid frames, a
    saturated gyro sample): they cannot be integrated; their windows still serve as positions.
    """

    first: np.ndarray
    second: np.ndarray
    period_s: float
    samples: np.ndarray
    reference: np.ndarray
    group_samples: np.ndarray
    sums: np.ndarray
    weighted: np.ndarray
    cross: np.ndarray
    window_start_s: np.ndarray
    window_end_s: np.ndarray
    dropped: Mapping[str, int] = field(default_factory=lambda: dict.fromkeys(DROP_REASONS, 0))

    def __len__(self) -> int:
        return int(self.first.shape[0])

    @property
    def duration_s(self) -> np.ndarray:
        """(S,) time integrated over each slew, s."""
        return self.samples * self.period_s

    @property
    def n_dropped(self) -> int:
        return int(sum(self.dropped.values()))

    def subset(self, keep: np.ndarray) -> Slews:
        keep = np.asarray(keep)
        names = ("first", "second", "samples", "reference", "group_samples", "sums", "weighted")
        arrays = {n: getattr(self, n)[keep] for n in names + ("cross",)}
        return Slews(
            period_s=self.period_s,
            window_start_s=self.window_start_s[keep],
            window_end_s=self.window_end_s[keep],
            dropped=dict(self.dropped),
            **arrays,
        )

    # ---- the side file ---------------------------------------------------------------------
    def to_npz_bytes(self) -> bytes:
        """The side file ``POSITIONS.slews.npz`` (compressed), as bytes."""
        buf = io.BytesIO()
        np.savez_compressed(
            buf,
            version=np.array(_NPZ_VERSION),
            first=self.first.astype(np.int64),
            second=self.second.astype(np.int64),
            period_s=np.array(self.period_s),
            samples=self.samples.astype(np.int64),
            reference=self.reference,
            group_samples=self.group_samples.astype(np.int64),
            sums=self.sums,
            weighted=self.weighted,
            cross=self.cross,
            window_start_s=self.window_start_s,
            window_end_s=self.window_end_s,
            dropped_reasons=np.array(list(self.dropped), dtype=str),
            dropped_counts=np.array(list(self.dropped.values()), dtype=np.int64),
        )
        return buf.getvalue()

    @classmethod
    def from_npz_bytes(cls, data: bytes, source: str = "<slews>") -> Slews:
        try:
            z = np.load(io.BytesIO(data), allow_pickle=False)
            version = int(z["version"])
            if version != _NPZ_VERSION:
                raise RecalInputError(f"{source}: slews file version {version} is not supported")
            out = cls(
                first=z["first"],
                second=z["second"],
                period_s=float(z["period_s"]),
                samples=z["samples"],
                reference=z["reference"],
                group_samples=z["group_samples"],
                sums=z["sums"],
                weighted=z["weighted"],
                cross=z["cross"],
                window_start_s=z["window_start_s"],
                window_end_s=z["window_end_s"],
                dropped=dict(
                    zip(
                        [str(r) for r in z["dropped_reasons"]],
                        [int(c) for c in z["dropped_counts"]],
                        strict=True,
                    )
                ),
            )
        except (OSError, ValueError, KeyError) as exc:
            raise RecalInputError(f"{source}: not a slews file ({exc})") from None
        return out

    def mismatch(self, start_s: np.ndarray, end_s: np.ndarray) -> str | None:
        """Why these slews do not belong to positions with these window times, or None."""
        M = start_s.shape[0]
        if len(self) == 0:
            return None
        if self.first.min() < 0 or self.second.max() >= M:
            return f"the slews refer to window {int(self.second.max())}, the positions have {M}"
        rows = np.stack([self.first, self.second], axis=1)
        tol = 0.5 * self.period_s + 1e-9
        if not (
            np.allclose(start_s[rows], self.window_start_s, rtol=0, atol=tol)
            and np.allclose(end_s[rows], self.window_end_s, rtol=0, atol=tol)
        ):
            return "the window times of the slews file differ from the positions file's"
        return None
