"""HTML and matplotlib reports of the command line and the service (the only part of recal that draws or builds documents; the numerics never import it)."""

from recal._moved import MOVED_INTO_PACKAGE, forward_old_names

# In 0.1.0 recal.report was a module (now recal.report.html): its names still resolve here,
# with a DeprecationWarning naming the new path, until 0.3.0 (docs/api.md).
__getattr__ = forward_old_names(__name__, MOVED_INTO_PACKAGE[__name__], package=True)
