"""Pure numerics for in-field IMU recalibration: models, solvers, observability, detection.

Nothing in this package performs I/O beyond turning arrays and text already in memory into
objects, so every piece can be used from a notebook.
"""

__version__ = "0.1.0"
