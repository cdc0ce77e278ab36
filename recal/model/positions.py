"""Static positions: the table of window means the engine calibrates from
(docs/reference.md#positions).

A :class:`Positions` holds one row per static window as named numpy columns. It is parsed from
and formatted to CSV *text*; the caller does the file I/O, so this stays usable from a notebook.

Column names (any order; extra columns are kept and round-trip unchanged):

``start_s, end_s, samples``; ``gyro_x, gyro_y, gyro_z`` (sensor output units, N_g);
``accel_x, accel_y, accel_z`` (output units, N_a); ``temperature_c``;
``temperature_rate_c_per_h``; optional ``*_std`` per-sample standard deviations and ``*_sem``
standard errors of the window means (correlated noise included), which take precedence over
std/sqrt(samples) wherever present. Where the ship's sensors are known (NMEA 0183, conventions
section 12) a window also carries :data:`SHIP_COLUMNS`: ``latitude_deg``, ``sog_kn`` and
``heading_deg``, means over the window; they are extra columns (kept, NaN where unknown).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from recal.errors import RecalInputError

AXES = ("x", "y", "z")
GYRO_COLUMNS = tuple(f"gyro_{a}" for a in AXES)
ACCEL_COLUMNS = tuple(f"accel_{a}" for a in AXES)
GYRO_STD_COLUMNS = tuple(f"gyro_{a}_std" for a in AXES)
ACCEL_STD_COLUMNS = tuple(f"accel_{a}_std" for a in AXES)
GYRO_SEM_COLUMNS = tuple(f"gyro_{a}_sem" for a in AXES)
ACCEL_SEM_COLUMNS = tuple(f"accel_{a}_sem" for a in AXES)
TIME_COLUMNS = ("start_s", "end_s", "samples")
TEMPERATURE_COLUMNS = ("temperature_c", "temperature_rate_c_per_h")
#: The ship's state over a window (means; NaN where the ship's sensors did not cover it).
SHIP_COLUMNS = ("latitude_deg", "sog_kn", "heading_deg")
#: Preferred column order when writing; extra columns follow in their original order.
CANONICAL_ORDER = (
    TIME_COLUMNS
    + GYRO_COLUMNS
    + ACCEL_COLUMNS
    + TEMPERATURE_COLUMNS
    + GYRO_STD_COLUMNS
    + ACCEL_STD_COLUMNS
    + GYRO_SEM_COLUMNS
    + ACCEL_SEM_COLUMNS
)


@dataclass
class Positions:
    """One row per static window; ``columns`` maps a column name to a float array of shape (M,)."""

    columns: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = "<memory>"

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_columns(cls, columns: Mapping[str, np.ndarray], source: str = "<memory>") -> Positions:
        cols = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in columns.items()}
        lengths = {len(v) for v in cols.values()}
        if len(lengths) > 1:
            raise RecalInputError(f"{source}: columns have different lengths {sorted(lengths)}")
        pos = cls(columns=cols, source=source)
        pos.validate()
        return pos

    @classmethod
    def from_csv_text(cls, text: str, source: str = "<text>") -> Positions:
        """Parse CSV text; every cell of the known columns must be a finite number."""
        reader = csv.reader(io.StringIO(text))
        try:
            header = next(reader)
        except StopIteration:
            raise RecalInputError(f"{source}: file is empty (expected a CSV header row)") from None
        header = [h.strip() for h in header]
        if len(set(header)) != len(header):
            dup = sorted({h for h in header if header.count(h) > 1})
            raise RecalInputError(f"{source}: duplicate column(s) {', '.join(dup)}")
        rows = [r for r in reader if any(c.strip() for c in r)]
        if not rows:
            raise RecalInputError(f"{source}: no data rows after the header")
        cols: dict[str, np.ndarray] = {}
        for j, name in enumerate(header):
            values = np.empty(len(rows))
            for i, row in enumerate(rows):
                if len(row) != len(header):
                    raise RecalInputError(
                        f"{source}: row {i + 2} has {len(row)} cells, header has {len(header)}"
                    )
                cell = row[j].strip()
                try:
                    values[i] = float(cell)
                except ValueError:
                    if name in CANONICAL_ORDER:
                        raise RecalInputError(
                            f"{source}: row {i + 2}, column '{name}': '{cell}' is not a number"
                        ) from None
                    values[i] = math.nan  # extra non-numeric columns are kept as NaN
            cols[name] = values
        return cls.from_columns(cols, source=source)

    # ---- checks -------------------------------------------------------------------------
    def validate(self) -> None:
        """Raise :class:`RecalInputError` for partial triads and non-finite known cells."""
        for group in (
            GYRO_COLUMNS,
            ACCEL_COLUMNS,
            GYRO_STD_COLUMNS,
            ACCEL_STD_COLUMNS,
            GYRO_SEM_COLUMNS,
            ACCEL_SEM_COLUMNS,
        ):
            present = [c for c in group if c in self.columns]
            if present and len(present) != 3:
                missing = [c for c in group if c not in self.columns]
                raise RecalInputError(f"{self.source}: missing column(s) {', '.join(missing)}")
        if not (self.has_gyro or self.has_accel):
            raise RecalInputError(
                f"{self.source}: no gyro_x/y/z or accel_x/y/z columns; "
                f"found {', '.join(self.columns) or 'none'}"
            )
        for name in CANONICAL_ORDER:
            if name in self.columns:
                bad = ~np.isfinite(self.columns[name])
                if bad.any():
                    row = int(np.argmax(bad)) + 2
                    raise RecalInputError(
                        f"{self.source}: row {row}, column '{name}' is NaN or infinite"
                    )
        for std_group in (GYRO_STD_COLUMNS, ACCEL_STD_COLUMNS, GYRO_SEM_COLUMNS, ACCEL_SEM_COLUMNS):
            if std_group[0] in self.columns and (self.stack(std_group) < 0).any():
                raise RecalInputError(
                    f"{self.source}: negative standard deviation in {', '.join(std_group)}"
                )

    # ---- access -------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    @property
    def has_gyro(self) -> bool:
        return all(c in self.columns for c in GYRO_COLUMNS)

    @property
    def has_accel(self) -> bool:
        return all(c in self.columns for c in ACCEL_COLUMNS)

    @property
    def has_temperature(self) -> bool:
        return "temperature_c" in self.columns

    def stack(self, names: tuple[str, ...]) -> np.ndarray:
        """Columns ``names`` as an (M, len(names)) array."""
        return np.column_stack([self.columns[n] for n in names])

    @property
    def gyro(self) -> np.ndarray:
        """Mean gyro outputs N_g, shape (M, 3), output units."""
        return self.stack(GYRO_COLUMNS)

    @property
    def accel(self) -> np.ndarray:
        """Mean accel outputs N_a, shape (M, 3), output units."""
        return self.stack(ACCEL_COLUMNS)

    def optional(self, name: str) -> np.ndarray | None:
        return self.columns.get(name)

    def noise_source(self, sensor: str) -> str | None:
        """Where :meth:`std_of_mean` comes from: "sem columns", "std columns" or None."""
        sem = GYRO_SEM_COLUMNS if sensor == "gyro" else ACCEL_SEM_COLUMNS
        std = GYRO_STD_COLUMNS if sensor == "gyro" else ACCEL_STD_COLUMNS
        if all(n in self.columns for n in sem):
            return "sem columns"
        if all(n in self.columns for n in std):
            return "std columns"
        return None

    def gyro_contrast(self) -> tuple[float, int] | None:
        """(contrast, axis): the largest spread of the gyro window means between positions, per
        axis, over that axis's typical (median) window-mean noise; None without gyro noise
        columns or with fewer than 3 positions. Earth rate shows as a large contrast (a FOG:
        hundreds to thousands), a MEMS gyro's window means differ by its noise (tens at most)."""
        noise = self.std_of_mean("gyro")
        if noise is None or len(self) < 3:
            return None
        spread = np.ptp(self.gyro, axis=0)
        sem = np.maximum(np.median(noise, axis=0), 1e-300)
        axis = int(np.argmax(spread / sem))
        return float(spread[axis] / sem[axis]), axis

    def std_of_mean(self, sensor: str) -> np.ndarray | None:
        """Standard error of each window mean, (M, 3) output units, or None without noise columns.

        The ``*_sem`` columns (correlated noise included) when present, else std/sqrt(samples),
        which is right for white noise only.
        """
        source = self.noise_source(sensor)
        if source is None:
            return None
        if source == "sem columns":
            return self.stack(GYRO_SEM_COLUMNS if sensor == "gyro" else ACCEL_SEM_COLUMNS)
        names = GYRO_STD_COLUMNS if sensor == "gyro" else ACCEL_STD_COLUMNS
        if not all(n in self.columns for n in names):
            return None
        n = self.columns.get("samples")
        count = np.maximum(n, 1.0) if n is not None else np.ones(len(self))
        return self.stack(names) / np.sqrt(count)[:, None]

    def subset(self, rows: np.ndarray) -> Positions:
        return Positions({k: v[rows] for k, v in self.columns.items()}, source=self.source)

    # ---- output -------------------------------------------------------------------------
    def to_csv_text(self) -> str:
        names = [c for c in CANONICAL_ORDER if c in self.columns]
        names += [c for c in self.columns if c not in names]
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(names)
        data = [self.columns[n] for n in names]
        for i in range(len(self)):
            writer.writerow([_fmt(names[j], data[j][i]) for j in range(len(names))])
        return buf.getvalue()


def _fmt(name: str, value: float) -> str:
    if name == "samples" and float(value).is_integer():
        return str(int(value))
    return repr(float(value))
