"""Checking a calibration: which physical effect is missing (effects), whether the unit has drifted (drift), what new windows would gain (information)."""

from recal._moved import MOVED_INTO_PACKAGE, forward_old_names

# In 0.1.0 recal.diagnose was a module (now recal.diagnose.effects): its names still resolve here,
# with a DeprecationWarning naming the new path, until 0.3.0 (docs/api.md).
__getattr__ = forward_old_names(__name__, MOVED_INTO_PACKAGE[__name__], package=True)
