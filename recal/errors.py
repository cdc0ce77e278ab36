"""Exceptions raised by the numerical engine.

:class:`InputError` is the project's one input-error base (defined in ``drivers.errors``, the
lowest layer, so the drivers' errors are instances of it too); it is re-exported here so engine
users need not know where it lives.
"""

from drivers.errors import InputError

__all__ = ["InputError", "RecalInputError"]


class RecalInputError(InputError):
    """Bad input or an unusable design; the message is one line a user can act on.

    The command line maps it (as any :class:`InputError`) to exit code 2 with the message on
    stderr and no traceback.
    """
