"""The error models, their coefficients and files: terms, triad models, coefficient sets (versioned), reference magnitudes, effect plug-ins, static positions."""

from recal._moved import MOVED_INTO_PACKAGE, forward_old_names

# In 0.1.0 recal.model was a module (now recal.model.error_model): its names still resolve here,
# with a DeprecationWarning naming the new path, until 0.3.0 (docs/api.md).
__getattr__ = forward_old_names(__name__, MOVED_INTO_PACKAGE[__name__], package=True)
