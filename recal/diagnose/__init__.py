"""Checking a calibration: which physical effect is missing (effects), whether the unit has drifted (drift), what new windows would gain (information)."""
